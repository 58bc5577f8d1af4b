"""Greedy search with queries sharing reference tiles (``SearchConfig.query_batch`` / ``group``) against one query at
a time, over a bank the size of the quick preset's (13 objects x 512 float16 references in memory-mapped files).

    .venv/bin/python benchmarks/bench_greedy_tiles.py [--out benchmarks/results/greedy_tiles.json] [--queries 32]

The model is the study's network at 64 px with random weights (the speed depends on shapes, not on weights), once
with the learned adaptive fusion (the fused CPU kernel) and once with "avg" (a matmul). Each variant answers the
same queries; the JSON records the median seconds per query over ``--repeats`` passes (variants interleaved, so
background load hits all alike), each variant's ratio to one query at a time measured in the same run, and
whether its answers equal the one-query-at-a-time answers (they must: each query is scored alone on each tile).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from helpers.core.configs import ModelConfig, SearchConfig
from helpers.core.paths import portable_obj
from helpers.core.precision import cpu_flags
from helpers.core.rotations import haar_uniform
from helpers.net.model import OrientationNet
from helpers.search.retrieval import ReferenceBank, model_scorer, search_all
from helpers.study.provenance import device_info, git_revision

#: (query_batch, group): one query at a time over 1,024-reference groups (today's greedy) first.
VARIANTS = ((1, 1024), (16, 512), (16, 128), (16, 64), (32, 64))


def _bank(model: OrientationNet, folder: Path, n_objects: int, n_refs: int) -> ReferenceBank:
    g = torch.Generator().manual_seed(1)
    feats = []
    for o in range(n_objects):
        f = torch.nn.functional.normalize(torch.randn(n_refs, model.cfg.channels, model.feature_length, generator=g),
                                          dim=1).half().numpy()
        f.tofile(folder / f"obj{o}.f16")
        feats.append(np.memmap(folder / f"obj{o}.f16", dtype=np.float16, mode="r", shape=f.shape))
    return ReferenceBank(feats, haar_uniform(n_refs, seed=2), [f"obj{o}" for o in range(n_objects)], k_ac=64)


def measure(fusion: str, n_queries: int, repeats: int, n_objects: int, n_refs: int) -> dict:
    torch.manual_seed(0)
    model = OrientationNet(ModelConfig(image_size=64, fusion=fusion)).eval()
    q = torch.nn.functional.normalize(torch.randn(n_queries, model.cfg.channels, model.feature_length), dim=1)
    scorer = model_scorer(model)
    with tempfile.TemporaryDirectory() as tmp:
        bank = _bank(model, Path(tmp), n_objects, n_refs)
        search_all(q[:2], bank, scorer, SearchConfig("greedy"), progress=False)  # warm-up (kernel build, page cache)
        secs: dict[tuple, list[float]] = {v: [] for v in VARIANTS}
        answers: dict[tuple, list] = {}
        for _ in range(repeats):
            for qb, group in VARIANTS:
                t0 = time.perf_counter()
                preds = search_all(q, bank, scorer, SearchConfig("greedy", group=group, query_batch=qb),
                                   progress=False)
                secs[(qb, group)].append((time.perf_counter() - t0) / n_queries)
                answers[(qb, group)] = [(p.obj_index, p.ref_index, p.score) for p in preds]
    base = statistics.median(secs[VARIANTS[0]])
    return {f"query_batch={qb}, group={g}": {
        "median_s_per_query": statistics.median(secs[(qb, g)]), "all_s_per_query": secs[(qb, g)],
        "speedup_vs_one_query": base / statistics.median(secs[(qb, g)]),
        "same_answers_as_one_query": answers[(qb, g)] == answers[VARIANTS[0]]} for qb, g in VARIANTS}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="benchmarks/results/greedy_tiles.json")
    ap.add_argument("--queries", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--objects", type=int, default=13)
    ap.add_argument("--refs", type=int, default=512)
    a = ap.parse_args(argv)
    res = {"what": "greedy search, queries sharing reference tiles vs one query at a time (seconds per query)",
           "bank": {"objects": a.objects, "refs_per_object": a.refs, "dtype": "float16 memmap", "image_size": 64},
           "queries": a.queries, "repeats": a.repeats, "torch_threads": torch.get_num_threads(),
           "device": device_info("cpu"), "cpu_flags": sorted(cpu_flags() & {"avx2", "avx512f", "avx512_bf16", "amx_tile"}), "git": git_revision(),
           "fusion": {f: measure(f, a.queries, a.repeats, a.objects, a.refs) for f in ("adaptive", "avg")}}
    # paths by their role (<cache>/...), never this machine's
    Path(a.out).write_text(json.dumps(portable_obj(res), indent=2, sort_keys=True, default=str) + "\n")
    for f, rows in res["fusion"].items():
        for k, v in rows.items():
            print(f"{f:9s} {k:28s} {v['median_s_per_query'] * 1e3:8.1f} ms/query  x{v['speedup_vs_one_query']:.2f}"
                  f"  same answers: {v['same_answers_as_one_query']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
