"""Sections 5, 5b and 6 of the CPU benchmark: retrieval speed and agreement, and cache size.

* ``retrieval_synthetic``: seconds/query of the authors' fast search, its
  batched anchor stage, the coarse-to-fine variant ("c2f") and greedy search,
  over K objects x R references of rotation-smooth synthetic float16 features
  in memory-mapped files (:func:`write_synthetic_bank`);
* ``retrieval_real``: fast, c2f and greedy on a small rendered set (agreement
  and Rota. Acc.);
* ``cache_bytes_13x10000``: float16 reference-cache bytes from the feature shapes.

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


def bench_retrieval_synthetic(cfg: BenchConfig, tmp_root: str | None = None) -> dict:
    """Fast vs greedy seconds/query over K objects x R references of float16 memmapped features."""
    import torch

    from helpers.core.configs import SearchConfig
    from helpers.core.rotations import haar_uniform
    from helpers.search.retrieval import ReferenceBank, fast_search, greedy_search, model_scorer, search_all

    model = _model(cfg.retr_size, cfg.seed, monotone=True).eval()
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
    r_max = max(cfg.retr_refs)
    need = cfg.retr_objects * r_max * c * length * 2
    folder = Path(tempfile.mkdtemp(prefix="bench_bank_", dir=tmp_root))
    try:
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
            if not ok:
                return out
            r_max = max(ok)
        all_rots = haar_uniform(r_max, seed=cfg.seed)
        log(f"writing synthetic bank {cfg.retr_objects} x {r_max} "
            f"({cfg.retr_objects * r_max * c * length * 2 / 1e9:.2f} GB)")
        w = write_synthetic_bank(folder, cfg.retr_objects, r_max, c, length, all_rots, cfg.seed)
        bases = w.pop("bases")
        out["write"] = {k: v for k, v in w.items() if k != "paths"}
        out["read_through"] = _read_through(w["paths"])
        log(f"bank written in {w['write_s']:.0f} s, read back at {out['read_through']['gb_per_s']:.2f} GB/s")
        mms = [np.memmap(p, dtype=np.float16, mode="r", shape=(r_max, c, length)) for p in w["paths"]]
        names = [f"obj{o:02d}" for o in range(cfg.retr_objects)]
        scorer = model_scorer(model, "cpu")
        rng = np.random.default_rng(cfg.seed + 5)
        n_q = max(cfg.retr_fast_queries, cfg.retr_greedy_queries, cfg.retr_batch_queries)
        q_obj = rng.integers(0, cfg.retr_objects, n_q)
        q_rot = haar_uniform(n_q, seed=cfg.seed + 6)
        queries = [torch.from_numpy(_smooth_features(bases[o], q_rot[i:i + 1], c, length, 1.0, rng)[0])
                   for i, o in enumerate(q_obj)]
        warm = torch.from_numpy(_smooth_features(bases[0], haar_uniform(1, seed=99), c, length, 1.0, rng)[0])
        for r in r_list:
            key = f"{cfg.retr_objects}x{r}"
            t0 = time.perf_counter()
            bank = ReferenceBank([m[:r] for m in mms], all_rots[:r], names, k_ac=PAPER_K_AC)
            anchors_s = time.perf_counter() - t0
            wait_quiet()
            t0 = time.perf_counter()
            bank.anchor_feats(PAPER_K_AC)  # once per bank: anchors gathered into RAM
            anchor_gather_s = time.perf_counter() - t0
            fast_cfg = SearchConfig("fast", k_ac=PAPER_K_AC, fps_k=PAPER_FPS_K)
            fast_search(warm, bank, scorer, fast_cfg)  # warm-up
            fp, fast = _search_timed(fast_search, queries[:cfg.retr_fast_queries], bank, scorer, fast_cfg)
            log(f"{key}: fast {fast['s_per_query_median']:.2f} s/query, "
                f"{fast['comparisons_per_query_median']:.0f} comparisons")
            wait_quiet()
            qb = torch.stack(queries[:cfg.retr_batch_queries])
            with Probe() as pb:
                bp = search_all(qb, bank, scorer, replace(fast_cfg, query_batch=cfg.retr_query_batch), progress=False)
            fast_batched = {"n_queries": len(bp), "query_batch": cfg.retr_query_batch,
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
            log(f"{key}: fast batched {fast_batched['s_per_query_mean']:.2f} s/query")
            wait_quiet()
            c2f_cfg = replace(fast_cfg, method="c2f", coarse_k=C2F_COARSE_K, refine_objects=C2F_REFINE_OBJECTS)
            fast_search(warm, bank, scorer, c2f_cfg)  # warm-up
            cp, c2f = _search_timed(fast_search, queries[:cfg.retr_fast_queries], bank, scorer, c2f_cfg)
            log(f"{key}: c2f {c2f['s_per_query_median']:.3f} s/query, "
                f"{c2f['comparisons_per_query_median']:.0f} comparisons")
            wait_quiet()
            halving_cfg = replace(c2f_cfg, refine_objects=C2F_HALVING_REFINE_OBJECTS, halving=True)
            fast_search(warm, bank, scorer, halving_cfg)  # warm-up
            hp, c2fh = _search_timed(fast_search, queries[:cfg.retr_fast_queries], bank, scorer, halving_cfg)
            log(f"{key}: c2f halving {c2fh['s_per_query_median']:.3f} s/query, "
                f"{c2fh['comparisons_per_query_median']:.0f} comparisons")
            wait_quiet()
            gp, greedy = _search_timed(greedy_search, queries[:cfg.retr_greedy_queries], bank, scorer, group=1024)
            log(f"{key}: greedy {greedy['s_per_query_median']:.2f} s/query")
            n_common = min(len(fp), len(gp))
            agree = [fp[i].obj_index == gp[i].obj_index and fp[i].ref_index == gp[i].ref_index
                     for i in range(n_common)]
            correct_obj = [gp[i].obj_index == q_obj[i] for i in range(n_common)]
            c2f_fast = [_same(a, b) for a, b in zip(cp, fp)]
            c2f_greedy = [_same(a, b) for a, b in zip(cp, gp)]  # the first len(gp) queries
            out["banks"][key] = {
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
            del bank
        del mms
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return out


# =========================================================================== 5b. real set

def scaled_fast_params(n_refs: int) -> dict:
    """k_ac and fps_k at the paper's ratios to R (1024 and 256 of 10,000), at least 16 and 8."""
    return {"k_ac": max(16, round(PAPER_K_AC * n_refs / PAPER_REFS)),
            "fps_k": max(8, round(PAPER_FPS_K * n_refs / PAPER_REFS))}


def scaled_c2f_params(n_refs: int) -> dict:
    """:func:`scaled_fast_params` plus coarse_k at the ratio 64 / 10,000 to R (at least 8, so the
    coarse stage still ranks objects by a top-3 mean of several anchors; always < k_ac, whose
    minimum is 16) and refine_objects = 3 (a number of objects, not of references: not scaled)."""
    return {**scaled_fast_params(n_refs), "coarse_k": max(8, round(C2F_COARSE_K * n_refs / PAPER_REFS)),
            "refine_objects": C2F_REFINE_OBJECTS}


def bench_real_agreement(cfg: BenchConfig, checkpoint: str | None = None, tmp_root: str | None = None) -> dict:
    """Fast, coarse-to-fine fast (c2f) and greedy on rendered references and real-like queries:
    agreement and Rota. Acc."""
    import torch

    from helpers.core.configs import QueryStyle, RenderConfig, SearchConfig
    from helpers.data.datasets import ViewSetSpec, render_sets
    from helpers.data.manifest import load_manifest
    from helpers.evaluation.metrics import Record, evaluate_predictions
    from helpers.search.features import encode_views
    from helpers.search.retrieval import ReferenceBank, fast_search, greedy_search, model_scorer

    size = cfg.retr_size
    if checkpoint:
        from helpers.training.train import load_model

        model, _ = load_model(checkpoint, device="cpu")
        size = model.cfg.image_size
        model_desc = f"checkpoint {checkpoint}"
    else:
        model = _model(size, cfg.seed, monotone=True)
        model_desc = f"random-init OrientationNet (seed {cfg.seed}) with the monotone fusion readout"
    model.eval()
    objects = load_manifest().object_names("train")[:cfg.real_objects]
    rc = RenderConfig(size=size)
    specs = ([ViewSetSpec(o, "reference", cfg.real_refs, cfg.seed, rc) for o in objects]
             + [ViewSetSpec(o, "query", cfg.real_queries, cfg.seed, rc, QueryStyle(), "test") for o in objects])
    cache = tempfile.mkdtemp(prefix="bench_real_", dir=tmp_root)
    try:
        t0 = time.perf_counter()
        views = render_sets(specs, cache=cache, workers=cfg.real_workers, progress=False)
        render_s = time.perf_counter() - t0
        refs, queries = views[:len(objects)], views[len(objects):]
        log(f"real set rendered in {render_s:.0f} s")
        t0 = time.perf_counter()
        feats = [np.concatenate([f.numpy().astype(np.float16) for f in encode_views(model, v.images, 64)])
                 for v in refs]
        encode_s = time.perf_counter() - t0
        q_feats = [torch.cat(list(encode_views(model, v.images, 64))) for v in queries]
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    rots = np.asarray(refs[0].rotations, dtype=np.float64)
    if not all(np.array_equal(v.rotations, refs[0].rotations) for v in refs):
        raise RuntimeError("reference rotations differ between objects")
    scaled = scaled_fast_params(cfg.real_refs)
    bank = ReferenceBank(feats, rots, objects, k_ac=scaled["k_ac"])
    scorer = model_scorer(model, "cpu")
    flat = [(o, qv, qf[i]) for o, (qv, qf) in enumerate(zip(queries, q_feats)) for i in range(len(qf))]
    scaled_c2f = scaled_c2f_params(cfg.real_refs)
    fast_cfg, c2f_cfg = SearchConfig("fast", **scaled), SearchConfig("c2f", **scaled_c2f)
    fast_search(flat[0][2], bank, scorer, fast_cfg)  # warm-up
    wait_quiet()
    q_list = [f for _, _, f in flat]
    gp, greedy = _search_timed(greedy_search, q_list, bank, scorer, group=1024)
    fp, fast = _search_timed(fast_search, q_list, bank, scorer, fast_cfg)
    cp, c2f = _search_timed(fast_search, q_list, bank, scorer, c2f_cfg)
    hp, c2fh = _search_timed(fast_search, q_list, bank, scorer,
                             replace(c2f_cfg, refine_objects=C2F_HALVING_REFINE_OBJECTS, halving=True))

    # Records need each query's index within its object.
    idx_in_obj, seen = [], {}
    for o, _, _ in flat:
        idx_in_obj.append(seen.get(o, 0))
        seen[o] = seen.get(o, 0) + 1

    def evaluate(preds) -> dict:
        recs = [Record(objects[o], p.obj_name, np.asarray(qv.rotations[i], np.float64), p.R_est, qv.symmetries,
                       f"{objects[o]}:{i}")
                for (o, qv, _), i, p in zip(flat, idx_in_obj, preds)]
        _, means = evaluate_predictions(recs, 30.0)
        return {"rot_acc_pct": means["rot_acc"], "class_acc_pct": means["class_acc"],
                "median_err_deg": means["median_err_deg"]}

    same_ref = [a.obj_index == b.obj_index and a.ref_index == b.ref_index for a, b in zip(fp, gp)]
    same_obj = [a.obj_index == b.obj_index for a, b in zip(fp, gp)]
    n_total = len(objects) * cfg.real_refs
    return {"image_size": size, "objects": objects, "refs_per_object": cfg.real_refs,
            "queries_per_object": cfg.real_queries, "n_queries": len(flat), "model": model_desc,
            "query_style": "QueryStyle() defaults, test background photos",
            "render_s": render_s, "render_workers": cfg.real_workers,
            "encode_s": encode_s, "encode_refs_per_s": n_total / encode_s,
            "fast_params": {**scaled, "schedule": "converge", "top_anchors": 3,
                            "why": "paper ratios k_ac/R = 1024/10000 and fps_k/R = 256/10000; with the "
                                   "default k_ac=1024 >= R every reference would be an anchor and fast "
                                   "would trivially equal greedy"},
            "c2f_params": {**scaled_c2f, "schedule": "converge", "top_anchors": 3,
                           "why": "k_ac and fps_k as fast; coarse_k at the ratio 64/10000 to R, at least 8"},
            "greedy": {**greedy, **evaluate(gp)}, "fast": {**fast, **evaluate(fp)}, "c2f": {**c2f, **evaluate(cp)},
            "agreement_c2f_fast_same_reference": float(np.mean([_same(a, b) for a, b in zip(cp, fp)])),
            "agreement_c2f_greedy_same_reference": float(np.mean([_same(a, b) for a, b in zip(cp, gp)])),
            "agreement_c2f_greedy_same_object": float(np.mean([a.obj_index == b.obj_index for a, b in zip(cp, gp)])),
            "speedup_greedy_over_c2f": greedy["s_per_query_median"] / c2f["s_per_query_median"],
            "c2f_halving": {**c2fh, **evaluate(hp)},
            "agreement_c2f_halving_fast_same_reference": float(np.mean([_same(a, b) for a, b in zip(hp, fp)])),
            "agreement_c2f_halving_greedy_same_reference": float(np.mean([_same(a, b) for a, b in zip(hp, gp)])),
            "speedup_greedy_over_c2f_halving": greedy["s_per_query_median"] / c2fh["s_per_query_median"],
            "agreement_same_reference": float(np.mean(same_ref)),
            "agreement_same_object": float(np.mean(same_obj)),
            "speedup_greedy_over_fast": greedy["s_per_query_median"] / fast["s_per_query_median"],
            "rot_acc_note": "Rota. Acc. = category right and symmetry-aware geodesic error < 30 deg, "
                            "averaged per object then over objects (helpers.evaluation.metrics)"}


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

