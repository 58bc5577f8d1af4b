"""Sections 5 and 6 of the CPU benchmark: retrieval speed and cache size.

* ``retrieval_synthetic``: seconds/query of the authors' fast search, its
  batched anchor stage, the coarse-to-fine variant ("c2f") and greedy search,
  over K objects x R references of rotation-smooth synthetic float16 features
  in memory-mapped files (:func:`write_synthetic_bank`);
* ``cache_bytes_13x10000``: float16 reference-cache bytes from the feature shapes.

Section 5b (``retrieval_real``) lives in ``bench_retrieval_real.py``, above this
module: it shares the paper's search constants and :func:`_search_timed`.
Called by ``benchmarks/bench.py``.
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from bench_train import _model
from timing import Probe, gate, log, memory_snapshot, wait_quiet

if TYPE_CHECKING:
    from bench_config import BenchConfig

# Paper setting the targets refer to.
PAPER_OBJECTS = 13
PAPER_REFS = 10_000
PAPER_K_AC = 1024
PAPER_FPS_K = 256
# Coarse-to-fine category stage (helpers.search.retrieval.fast_search coarse_k / refine_objects) at the paper's k_ac.
C2F_COARSE_K = 64
C2F_REFINE_OBJECTS = 3
# Its successive-halving variant (halving=True) halves the objects down to this many (notebook 07's default).
C2F_HALVING_REFINE_OBJECTS = 1


# =========================================================================== 5. retrieval (synthetic)

def _smooth_bases(n_objects: int, c: int, length: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.standard_normal((10, c * length), dtype=np.float32) for _ in range(n_objects)]


def _smooth_features(basis: np.ndarray, rots: np.ndarray, c: int, length: int, noise: float = 0.0,
                     rng: np.random.Generator | None = None) -> np.ndarray:
    """Features that vary smoothly with rotation: unit-over-C of reshape([vec9(R), 1] @ basis)."""
    v = np.concatenate([rots.reshape(len(rots), 9), np.ones((len(rots), 1))], axis=1).astype(np.float32)
    x = (v @ basis).reshape(len(rots), c, length)
    if noise:
        x += noise * rng.standard_normal(x.shape, dtype=np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return x


def write_synthetic_bank(folder: Path, n_objects: int, n_refs: int, c: int, length: int, rots: np.ndarray,
                         seed: int, chunk: int = 500) -> dict:
    """Write K raw float16 files (R, C, L) of rotation-smooth synthetic features, chunk by chunk.

    Plain sequential writes (not a writable memmap) so the dirty pages never
    count in this process's RSS; the files are then opened as read-only
    ``np.memmap`` like the feature cache's.
    """
    bases = _smooth_bases(n_objects, c, length, seed)
    paths = []
    t0 = time.perf_counter()
    for o in range(n_objects):
        p = folder / f"obj{o:02d}.f16"
        with open(p, "wb") as f:
            for s in range(0, n_refs, chunk):
                f.write(_smooth_features(bases[o], rots[s:s + chunk], c, length).astype(np.float16).tobytes())
        paths.append(p)
    dt = time.perf_counter() - t0
    nbytes = sum(p.stat().st_size for p in paths)
    return {"paths": [str(p) for p in paths], "bases": bases, "write_s": dt, "bytes_on_disk": nbytes,
            "bytes_from_shape": n_objects * n_refs * c * length * 2, "write_gb_per_s": nbytes / dt / 1e9,
            "generate_and_write": "features generated in numpy and written in chunks of %d references" % chunk}


def _read_through(paths: list[str], bufsize: int = 64 << 20) -> dict:
    """Read every file once (plain reads, so the page cache is warm without touching our mappings)."""
    buf = bytearray(bufsize)
    n = 0
    t0 = time.perf_counter()
    for p in paths:
        with open(p, "rb", buffering=0) as f:
            while (k := f.readinto(buf)):
                n += k
    dt = time.perf_counter() - t0
    return {"bytes": n, "seconds": dt, "gb_per_s": n / dt / 1e9}


def _same(a, b) -> bool:
    """Two predictions name the same (object, reference)."""
    return a.obj_index == b.obj_index and a.ref_index == b.ref_index


def _search_timed(fn, queries, bank, scorer, *args, **kw) -> tuple[list, dict]:
    preds, secs, others = [], [], []
    for q in queries:
        with Probe() as p:
            preds.append(fn(q, bank, scorer, *args, **kw))
        secs.append(p.wall)
        others.append(p.others)
    known = [o for o in others if o is not None]
    comps = [pr.n_comparisons for pr in preds]
    return preds, {"n_queries": len(queries), "s_per_query_median": statistics.median(secs),
                   "s_per_query_all": secs, "comparisons_per_query_median": statistics.median(comps),
                   "comparisons_per_query_all": comps,
                   "pair_scores_per_s": sum(comps) / sum(secs),
                   "others_cpu_fraction": statistics.median(known) if known else None,
                   "contended_queries": sum(1 for o in known if o >= gate().threshold)}


def _synthetic_header(cfg: BenchConfig, model) -> tuple[dict, int, int]:
    """(out, C, L): the retrieval_synthetic result's fixed part, with ``model``'s feature shape (C channels,
    L locations) checked against one encode, and an empty ``banks``."""
    import torch

    c, length = model.cfg.channels, model.feature_length
    with torch.inference_mode():
        enc_shape = tuple(model.encode(torch.rand(1, 3, cfg.retr_size, cfg.retr_size)).shape)
    expected_l = sum(h * w for h, w in model.scale_shapes.values())
    out: dict[str, Any] = {
        "image_size": cfg.retr_size, "n_objects": cfg.retr_objects, "C": c, "L": length,
        "encode_output_shape": list(enc_shape), "L_matches_encode": enc_shape[1:] == (c, length) == (c, expected_l),
        "features": "synthetic, rotation-smooth: unit-over-C of [vec9(R),1] @ B_object (random B per object), "
                    "float16 np.memmap files; queries: same for a random rotation of a random object plus noise",
        "model": "random-init OrientationNet (seed %d), fusion MLP set to a monotone readout "
                 "(score = tanh(3 * mean fused cosine)); same operations and cost as a trained model" % cfg.seed,
        "fast_params": {"k_ac": PAPER_K_AC, "fps_k": PAPER_FPS_K, "schedule": "converge", "top_anchors": 3},
        "c2f_halving_params": {"refine_objects": C2F_HALVING_REFINE_OBJECTS, "halving": True,
                               "rest": "as c2f_params"},
        "c2f_params": {"k_ac": PAPER_K_AC, "fps_k": PAPER_FPS_K, "coarse_k": C2F_COARSE_K,
                       "refine_objects": C2F_REFINE_OBJECTS, "schedule": "converge", "top_anchors": 3,
                       "what": "fast_search with the coarse-to-fine category stage: the first coarse_k anchors "
                               "of every object, then the other k_ac - coarse_k anchors of the refine_objects "
                               "best objects only; rotation stage as fast"},
        "greedy_params": {"group": 1024}, "scorer_chunk": 1024,
        "banks": {}}
    return out, c, length


def _bank_sizes_that_fit(cfg: BenchConfig, out: dict, folder: Path, c: int, length: int, need: int) -> list[int]:
    """The bank sizes R (ascending) whose float16 files fit on ``folder``'s disk with ``disk_margin_bytes`` to spare.

    ``need`` is the bytes of the largest bank. Records the free space in
    ``out["disk"]`` and each bank that does not fit in ``out["banks"]`` as skipped.
    """
    free = shutil.disk_usage(folder).free
    out["disk"] = {"folder": str(folder), "free_bytes": free, "needed_bytes": need,
                   "margin_bytes": cfg.disk_margin_bytes}
    r_list = sorted(cfg.retr_refs)
    if free < need + cfg.disk_margin_bytes:
        ok = [r for r in r_list if cfg.retr_objects * r * c * length * 2 + cfg.disk_margin_bytes <= free]
        for r in r_list:
            if r not in ok:
                out["banks"][f"{cfg.retr_objects}x{r}"] = {
                    "skipped": True, "reason": f"needs {cfg.retr_objects * r * c * length * 2} bytes + "
                                               f"{cfg.disk_margin_bytes} margin, only {free} free"}
        r_list = ok
    return r_list


def _write_and_map_bank(cfg: BenchConfig, out: dict, folder: Path, r_max: int, c: int,
                        length: int) -> tuple[np.ndarray, list[np.ndarray], list[np.memmap]]:
    """(rotations (r_max, 3, 3), per-object bases (10, C*L), read-only float16 memmaps (r_max, C, L) per object).

    Writes the ``retr_objects`` x ``r_max`` bank under ``folder`` and reads it
    through once, recording both in ``out["write"]`` and ``out["read_through"]``.
    """
    from helpers.core.rotations import haar_uniform

    all_rots = haar_uniform(r_max, seed=cfg.seed)
    log(f"writing synthetic bank {cfg.retr_objects} x {r_max} "
        f"({cfg.retr_objects * r_max * c * length * 2 / 1e9:.2f} GB)")
    w = write_synthetic_bank(folder, cfg.retr_objects, r_max, c, length, all_rots, cfg.seed)
    bases = w.pop("bases")
    out["write"] = {k: v for k, v in w.items() if k != "paths"}
    out["read_through"] = _read_through(w["paths"])
    log(f"bank written in {w['write_s']:.0f} s, read back at {out['read_through']['gb_per_s']:.2f} GB/s")
    mms = [np.memmap(p, dtype=np.float16, mode="r", shape=(r_max, c, length)) for p in w["paths"]]
    return all_rots, bases, mms


def _synthetic_queries(cfg: BenchConfig, bases: list[np.ndarray], c: int, length: int) -> tuple[np.ndarray, list, Any]:
    """(q_obj (n,), queries: n float32 tensors (C, L), warm-up query (C, L)) with noise 1.0, for
    n = the most queries any search of this section uses."""
    import torch

    from helpers.core.rotations import haar_uniform

    rng = np.random.default_rng(cfg.seed + 5)
    n_q = max(cfg.retr_fast_queries, cfg.retr_greedy_queries, cfg.retr_batch_queries)
    q_obj = rng.integers(0, cfg.retr_objects, n_q)
    q_rot = haar_uniform(n_q, seed=cfg.seed + 6)
    queries = [torch.from_numpy(_smooth_features(bases[o], q_rot[i:i + 1], c, length, 1.0, rng)[0])
               for i, o in enumerate(q_obj)]
    warm = torch.from_numpy(_smooth_features(bases[0], haar_uniform(1, seed=99), c, length, 1.0, rng)[0])
    return q_obj, queries, warm


def _build_bank(mms: list[np.memmap], all_rots: np.ndarray, names: list[str], r: int) -> tuple[Any, float, float]:
    """(bank, build seconds, anchor gather seconds): a ReferenceBank over the first ``r`` references of each object,
    with its PAPER_K_AC anchors gathered into RAM."""
    from helpers.search.retrieval import ReferenceBank

    t0 = time.perf_counter()
    bank = ReferenceBank([m[:r] for m in mms], all_rots[:r], names, k_ac=PAPER_K_AC)
    anchors_s = time.perf_counter() - t0
    wait_quiet()
    t0 = time.perf_counter()
    bank.anchor_feats(PAPER_K_AC)  # once per bank: anchors gathered into RAM
    anchor_gather_s = time.perf_counter() - t0
    return bank, anchors_s, anchor_gather_s


def _warm_and_time(warm, queries: list, bank, scorer, search_cfg) -> tuple[list, dict]:
    """(predictions, timings) of ``fast_search`` with ``search_cfg`` after one untimed query ``warm``."""
    from helpers.search.retrieval import fast_search

    fast_search(warm, bank, scorer, search_cfg)  # warm-up
    return _search_timed(fast_search, queries, bank, scorer, search_cfg)


def _time_fast_batched(cfg: BenchConfig, queries: list, bank, scorer, fast_cfg, fp: list) -> dict:
    """Seconds/query of ``search_all`` with ``retr_query_batch`` queries per anchor pass over the first
    ``retr_batch_queries`` queries, and the share of its answers equal to the single-query ones ``fp``."""
    import torch

    from helpers.search.retrieval import search_all

    qb = torch.stack(queries[:cfg.retr_batch_queries])
    with Probe() as pb:
        bp = search_all(qb, bank, scorer, replace(fast_cfg, query_batch=cfg.retr_query_batch), progress=False)
    return {"n_queries": len(bp), "query_batch": cfg.retr_query_batch,
            "wall_s": pb.wall, "s_per_query_mean": pb.wall / len(bp),
            "s_per_query_median": statistics.median(p.seconds for p in bp),
            "comparisons_per_query_median": statistics.median(p.n_comparisons for p in bp),
            "others_cpu_fraction": pb.others,
            "same_predictions_as_single_query": float(np.mean(
                [a.obj_index == b.obj_index and a.ref_index == b.ref_index
                 for a, b in zip(bp, fp)])),
            "note": "search_all(method='fast', query_batch): the anchors of query_batch queries "
                    "are scored in one many-query pass; each query's seconds = its refinement + "
                    "an equal share of its batch's anchor pass; s_per_query_mean = wall / n"}


def _time_bank_searches(cfg: BenchConfig, key: str, bank, scorer, queries: list, warm) -> tuple[dict, dict]:
    """(timings, predictions), each keyed "fast", "fast_batched" (timings only), "c2f", "c2f_halving", "greedy":
    every search of the synthetic section over one bank, in that order, each after waiting for quiet."""
    from helpers.core.configs import SearchConfig
    from helpers.search.retrieval import greedy_search

    fast_cfg = SearchConfig("fast", k_ac=PAPER_K_AC, fps_k=PAPER_FPS_K)
    fp, fast = _warm_and_time(warm, queries[:cfg.retr_fast_queries], bank, scorer, fast_cfg)
    log(f"{key}: fast {fast['s_per_query_median']:.2f} s/query, "
        f"{fast['comparisons_per_query_median']:.0f} comparisons")
    wait_quiet()
    fast_batched = _time_fast_batched(cfg, queries, bank, scorer, fast_cfg, fp)
    log(f"{key}: fast batched {fast_batched['s_per_query_mean']:.2f} s/query")
    wait_quiet()
    c2f_cfg = replace(fast_cfg, method="c2f", coarse_k=C2F_COARSE_K, refine_objects=C2F_REFINE_OBJECTS)
    cp, c2f = _warm_and_time(warm, queries[:cfg.retr_fast_queries], bank, scorer, c2f_cfg)
    log(f"{key}: c2f {c2f['s_per_query_median']:.3f} s/query, "
        f"{c2f['comparisons_per_query_median']:.0f} comparisons")
    wait_quiet()
    halving_cfg = replace(c2f_cfg, refine_objects=C2F_HALVING_REFINE_OBJECTS, halving=True)
    hp, c2fh = _warm_and_time(warm, queries[:cfg.retr_fast_queries], bank, scorer, halving_cfg)
    log(f"{key}: c2f halving {c2fh['s_per_query_median']:.3f} s/query, "
        f"{c2fh['comparisons_per_query_median']:.0f} comparisons")
    wait_quiet()
    gp, greedy = _search_timed(greedy_search, queries[:cfg.retr_greedy_queries], bank, scorer, group=1024)
    log(f"{key}: greedy {greedy['s_per_query_median']:.2f} s/query")
    timings = {"fast": fast, "fast_batched": fast_batched, "c2f": c2f, "c2f_halving": c2fh, "greedy": greedy}
    return timings, {"fast": fp, "c2f": cp, "c2f_halving": hp, "greedy": gp}


def _bank_entry(cfg: BenchConfig, r: int, bank, anchors_s: float, anchor_gather_s: float, timings: dict,
                preds: dict, q_obj: np.ndarray) -> dict:
    """One bank's result: the timings of :func:`_time_bank_searches`, speed-ups (ratios of seconds/query),
    comparison ratios and the agreements between the searches' predictions (fractions of queries)."""
    fast, fast_batched, greedy = timings["fast"], timings["fast_batched"], timings["greedy"]
    c2f, c2fh = timings["c2f"], timings["c2f_halving"]
    fp, gp, cp, hp = preds["fast"], preds["greedy"], preds["c2f"], preds["c2f_halving"]
    n_common = min(len(fp), len(gp))
    agree = [fp[i].obj_index == gp[i].obj_index and fp[i].ref_index == gp[i].ref_index
             for i in range(n_common)]
    correct_obj = [gp[i].obj_index == q_obj[i] for i in range(n_common)]
    c2f_fast = [_same(a, b) for a, b in zip(cp, fp)]
    c2f_greedy = [_same(a, b) for a, b in zip(cp, gp)]  # the first len(gp) queries
    return {
        "n_objects": cfg.retr_objects, "R": r, "pairs_total": cfg.retr_objects * r,
        "anchors_k": int(len(bank.anchors(PAPER_K_AC))), "bank_build_s": anchors_s,
        "anchor_gather_s": anchor_gather_s,
        "fast": fast, "fast_batched": fast_batched, "greedy": greedy,
        "speedup_greedy_over_fast": greedy["s_per_query_median"] / fast["s_per_query_median"],
        "speedup_greedy_over_fast_batched": greedy["s_per_query_median"] / fast_batched["s_per_query_mean"],
        "comparison_ratio_greedy_over_fast": (cfg.retr_objects * r) / fast["comparisons_per_query_median"],
        "synthetic_agreement_fast_greedy": float(np.mean(agree)) if agree else None,
        "synthetic_greedy_object_correct": float(np.mean(correct_obj)) if correct_obj else None,
        "c2f": c2f,
        "speedup_greedy_over_c2f": greedy["s_per_query_median"] / c2f["s_per_query_median"],
        "speedup_fast_over_c2f": fast["s_per_query_median"] / c2f["s_per_query_median"],
        "comparison_ratio_greedy_over_c2f": (cfg.retr_objects * r) / c2f["comparisons_per_query_median"],
        "synthetic_agreement_c2f_fast": float(np.mean(c2f_fast)) if c2f_fast else None,
        "synthetic_agreement_c2f_fast_object": float(np.mean([a.obj_index == b.obj_index
                                                              for a, b in zip(cp, fp)])) if cp else None,
        "synthetic_agreement_c2f_greedy": float(np.mean(c2f_greedy)) if c2f_greedy else None,
        "c2f_agreement_queries": {"fast": len(c2f_fast), "greedy": len(c2f_greedy)},
        "c2f_halving": c2fh,
        "speedup_greedy_over_c2f_halving": greedy["s_per_query_median"] / c2fh["s_per_query_median"],
        "comparison_ratio_greedy_over_c2f_halving": (cfg.retr_objects * r)
        / c2fh["comparisons_per_query_median"],
        "synthetic_agreement_c2f_halving_fast": float(np.mean([_same(a, b) for a, b in zip(hp, fp)])),
        "synthetic_agreement_c2f_halving_greedy": float(np.mean([_same(a, b) for a, b in zip(hp, gp)])),
        "warmup": "one untimed query before each of fast, c2f and c2f halving (c2f on the "
                  "same queries as fast); greedy has no separate warm-up "
                  "(the model is warm from the fast queries, the page cache from read_through)",
        "memory_after": memory_snapshot()}


def bench_retrieval_synthetic(cfg: BenchConfig, tmp_root: str | None = None) -> dict:
    """Fast vs greedy seconds/query over K objects x R references of float16 memmapped features."""
    from helpers.search.retrieval import model_scorer

    model = _model(cfg.retr_size, cfg.seed, monotone=True).eval()
    out, c, length = _synthetic_header(cfg, model)
    need = cfg.retr_objects * max(cfg.retr_refs) * c * length * 2
    folder = Path(tempfile.mkdtemp(prefix="bench_bank_", dir=tmp_root))
    try:
        r_list = _bank_sizes_that_fit(cfg, out, folder, c, length, need)
        if not r_list:
            return out
        all_rots, bases, mms = _write_and_map_bank(cfg, out, folder, max(r_list), c, length)
        names = [f"obj{o:02d}" for o in range(cfg.retr_objects)]
        scorer = model_scorer(model, "cpu")
        q_obj, queries, warm = _synthetic_queries(cfg, bases, c, length)
        for r in r_list:
            key = f"{cfg.retr_objects}x{r}"
            bank, anchors_s, anchor_gather_s = _build_bank(mms, all_rots, names, r)
            timings, preds = _time_bank_searches(cfg, key, bank, scorer, queries, warm)
            out["banks"][key] = _bank_entry(cfg, r, bank, anchors_s, anchor_gather_s, timings, preds, q_obj)
            del bank
        del mms
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return out



# =========================================================================== 6. cache size

def cache_bytes(n_objects: int = PAPER_OBJECTS, n_refs: int = PAPER_REFS, sizes=(64, 128), channels: int = 128) -> dict:
    """float16 reference-cache bytes for n_objects x n_refs at each input size (from the feature shapes)."""
    from helpers.core.configs import level_shapes

    out = {}
    for s in sizes:
        length = sum(h * w for h, w in level_shapes(s).values())
        b = n_objects * n_refs * channels * length * 2
        out[str(s)] = {"n_objects": n_objects, "n_refs": n_refs, "C": channels, "L": length,
                       "bytes": b, "GB": b / 1e9, "GiB": b / 2 ** 30, "per_reference_bytes": channels * length * 2}
    return out

