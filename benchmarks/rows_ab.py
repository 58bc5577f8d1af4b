#!/usr/bin/env python
"""A/B of the fast searches' scoring path: per-level kernel calls on gathered copies (A) vs one
all-level kernel call per query reading the bank's rows in place (B).

A is the code before git 387f782, rebuilt here by monkeypatching (nothing in src/ changes):
``OrientationNet._score_chunk`` calls the kernel's one-level ``fuse`` once per level and query,
and ``ReferenceBank.ref_feats`` gathers every scored reference into a new array (two copies)
before scoring. B is the working tree: ``fuse_levels`` (every level of a reference in one pass,
rows read by index from the memory-mapped bank, no gathered copy).

Bank: 13 objects x 10,000 references at 64 px, float16 memmaps (3 distinct files of synthetic
rotation-smooth features, reused cyclically, so the 2.6 GB fit the page cache of a small VM;
the 13 x 10,000 bank of ``bench.py`` is 11.5 GB). Model: random-init OrientationNet with the
monotone readout of ``bench_train`` (cost of a trained one). For each query A and B run
back to back (interleaved, so machine drift hits both), for the authors' fast search, the
one-cut coarse-to-fine search and its halving variant (the parameters of ``bench.py``), then
greedy on a few queries. Predictions of A and B must be identical (checked, recorded).

Run: ``.venv/bin/python benchmarks/rows_ab.py [--queries 30]`` (about 4 minutes; writes
``benchmarks/results/rows_ab.json``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _old_score_chunk(fusion_kernel):
    """A: the kernel path as it was (one ``fuse`` call per level and query, rows gathered first)."""
    import torch

    def score_chunk(self, q, r, rows=None):
        if rows is not None:
            r = r[rows]
        kernel = self._kernel(q, r)
        r = r.contiguous()
        mode = fusion_kernel.MODES[self.cfg.fusion]
        vs = []
        for lv, sl in self.scale_slices.items():
            w, b = (t.detach().float().contiguous() for t in self._fusion_params(lv))
            vs.append(torch.stack([kernel.fuse(q[i, :, sl].contiguous(), r, sl.start, sl.stop - sl.start, w, b, mode)
                                   for i in range(q.shape[0])], 0))
        return self.fusion.head(torch.cat(vs, dim=-1))
    return score_chunk


def _old_ref_feats(self, obj, idx):
    """A: gather in sorted order into a new array, then place (two copies of every row)."""
    import torch

    idx = np.asarray(idx, dtype=np.int64)
    src = self.feats[obj]
    order = np.argsort(idx)
    out = np.empty((len(idx), *src.shape[1:]), dtype=np.float16 if src.dtype == np.float16 else np.float32)
    out[order] = src[idx[order]]
    return torch.from_numpy(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries", type=int, default=30, help="queries per method (the first 2 are warm-up)")
    ap.add_argument("--greedy-queries", type=int, default=3)
    ap.add_argument("--out", default=str(HERE / "results" / "rows_ab.json"))
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    import torch
    from bench_retrieval import (
        C2F_COARSE_K,
        C2F_HALVING_REFINE_OBJECTS,
        C2F_REFINE_OBJECTS,
        PAPER_FPS_K,
        PAPER_K_AC,
        PAPER_OBJECTS,
        PAPER_REFS,
        _smooth_features,
        write_synthetic_bank,
    )
    from bench_train import _model
    from timing import Probe, log, source_hashes

    import helpers.net.model as hm
    import helpers.search.retrieval as hr
    from helpers.core.configs import SearchConfig
    from helpers.core.rotations import haar_uniform
    from helpers.net import fusion_kernel

    if fusion_kernel.get() is None:
        raise SystemExit(f"rows_ab: the fusion kernel is unavailable ({fusion_kernel.status()['reason']})")
    torch.manual_seed(0)
    model = _model(64, 0, monotone=True).eval()
    c, length = model.cfg.channels, model.feature_length
    rots = haar_uniform(PAPER_REFS, seed=0)
    tmp = Path(tempfile.mkdtemp(prefix="rows_ab_"))
    t0 = time.perf_counter()
    w = write_synthetic_bank(tmp, 3, PAPER_REFS, c, length, rots, 0)
    log(f"bank written in {time.perf_counter() - t0:.0f} s")
    mms = [np.memmap(p, dtype=np.float16, mode="r", shape=(PAPER_REFS, c, length)) for p in w["paths"]]
    bank = hr.ReferenceBank([mms[o % 3] for o in range(PAPER_OBJECTS)], rots,
                            [f"obj{o:02d}" for o in range(PAPER_OBJECTS)], k_ac=PAPER_K_AC)
    bank.anchor_feats(PAPER_K_AC)
    rng = np.random.default_rng(5)
    objs = rng.integers(0, 3, args.queries)
    queries = [torch.from_numpy(_smooth_features(w["bases"][o], haar_uniform(1, seed=100 + i), c, length, 1.0, rng)[0])
               for i, o in enumerate(objs)]
    scorer = hr.model_scorer(model)
    base = SearchConfig("fast", k_ac=PAPER_K_AC, fps_k=PAPER_FPS_K)
    c2f = replace(base, method="c2f", coarse_k=C2F_COARSE_K, refine_objects=C2F_REFINE_OBJECTS)
    methods = {"fast": base, "c2f": c2f,
               "c2f_halving": replace(c2f, refine_objects=C2F_HALVING_REFINE_OBJECTS, halving=True)}
    new_chunk, new_rf = hm.OrientationNet._score_chunk, hr.ReferenceBank.ref_feats
    variants = {"A": (_old_score_chunk(fusion_kernel), _old_ref_feats, False), "B": (new_chunk, new_rf, True)}

    def use(v: str) -> None:
        hm.OrientationNet._score_chunk, hr.ReferenceBank.ref_feats, scorer.rows = variants[v]

    secs = {m: {"A": [], "B": []} for m in [*methods, "greedy"]}
    preds = {m: {"A": [], "B": []} for m in [*methods, "greedy"]}
    try:
        with Probe() as probe:
            for i, q in enumerate(queries):
                for m, cfg in methods.items():
                    for v in ("A", "B") if i % 2 == 0 else ("B", "A"):  # alternate who goes first
                        use(v)
                        t = time.perf_counter()
                        p = hr.fast_search(q, bank, scorer, cfg)
                        secs[m][v].append(time.perf_counter() - t)
                        preds[m][v].append((p.obj_index, p.ref_index, p.n_comparisons))
            for i, q in enumerate(queries[:args.greedy_queries]):
                for v in ("A", "B") if i % 2 == 0 else ("B", "A"):
                    use(v)
                    t = time.perf_counter()
                    p = hr.greedy_search(q, bank, scorer)
                    secs["greedy"][v].append(time.perf_counter() - t)
                    preds["greedy"][v].append((p.obj_index, p.ref_index, p.n_comparisons))
    finally:
        use("B")
        for p in w["paths"]:
            Path(p).unlink(missing_ok=True)
        tmp.rmdir()
    out = {"what": __doc__.split("\n\n")[0], "bank": f"{PAPER_OBJECTS} x {PAPER_REFS} (3 distinct files), 64 px",
           "params": methods, "torch_threads": torch.get_num_threads(), "others_cpu_fraction": probe.others,
           "wall_s": probe.wall, "sources": source_hashes(), "methods": {}}
    for m in secs:
        skip = 0 if m == "greedy" else 2  # warm-up queries
        a, b = secs[m]["A"][skip:], secs[m]["B"][skip:]
        out["methods"][m] = {
            "n_queries": len(a), "A_s_per_query_median": statistics.median(a),
            "B_s_per_query_median": statistics.median(b),
            "A_over_B_median_of_ratios": statistics.median(x / y for x, y in zip(a, b)),
            "pairs_per_query_median": statistics.median(p[2] for p in preds[m]["B"]),
            "identical_predictions": preds[m]["A"] == preds[m]["B"]}
        log(f"{m}: A {out['methods'][m]['A_s_per_query_median']:.3f} s, B {out['methods'][m]['B_s_per_query_median']:.3f} s,"
            f" A/B {out['methods'][m]['A_over_B_median_of_ratios']:.2f}, same answers {out['methods'][m]['identical_predictions']}")
    g = out["methods"]["greedy"]
    for m in methods:
        out["methods"][m]["greedy_over_B"] = g["B_s_per_query_median"] / out["methods"][m]["B_s_per_query_median"]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    from helpers.core.paths import portable_obj

    Path(args.out).write_text(json.dumps(portable_obj(out), indent=2) + "\n")
    log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
