"""Section 5b of the CPU benchmark: fast, coarse-to-fine and greedy retrieval on a small rendered set.

* ``retrieval_real``: agreement between the searches and their Rota. Acc. on
  rendered references and real-like queries, with k_ac, fps_k and coarse_k at
  the paper's ratios to the number of references.

Called by ``benchmarks/bench.py``.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from bench_retrieval import (
    C2F_COARSE_K,
    C2F_HALVING_REFINE_OBJECTS,
    C2F_REFINE_OBJECTS,
    PAPER_FPS_K,
    PAPER_K_AC,
    PAPER_REFS,
    _same,
    _search_timed,
)
from bench_train import _model
from timing import log, wait_quiet

if TYPE_CHECKING:
    from bench_config import BenchConfig


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


def _real_model(cfg: BenchConfig, checkpoint: str | None) -> tuple[Any, int, str]:
    """(model in eval mode, its input size in pixels, a description): the checkpoint's network if given,
    else a random-init one with the monotone fusion readout at ``retr_size``."""
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
    return model, size, model_desc


def _render_and_encode(cfg: BenchConfig, model, objects: list[str], size: int,
                       tmp_root: str | None) -> tuple[list, list, list[np.ndarray], list, float, float]:
    """(reference views, query views, reference features, query features, render seconds, encode seconds).

    One entry per object: ``real_refs`` rendered references encoded to float16
    arrays (real_refs, C, L), and ``real_queries`` real-like queries (test
    backgrounds) encoded to float32 tensors (real_queries, C, L). The render
    cache is a temporary folder under ``tmp_root``, removed afterwards.
    """
    import torch

    from helpers.core.configs import QueryStyle, RenderConfig
    from helpers.data.datasets import ViewSetSpec, render_sets
    from helpers.search.features import encode_views

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
    return refs, queries, feats, q_feats, render_s, encode_s


def _time_real_searches(flat: list[tuple], bank, scorer, fast_cfg, c2f_cfg) -> tuple[dict, dict]:
    """(timings, predictions), each keyed "greedy", "fast", "c2f", "c2f_halving", over every query of ``flat``
    ((object index, query views, features (C, L)) per query), after one untimed fast query."""
    from helpers.search.retrieval import fast_search, greedy_search

    fast_search(flat[0][2], bank, scorer, fast_cfg)  # warm-up
    wait_quiet()
    q_list = [f for _, _, f in flat]
    gp, greedy = _search_timed(greedy_search, q_list, bank, scorer, group=1024)
    fp, fast = _search_timed(fast_search, q_list, bank, scorer, fast_cfg)
    cp, c2f = _search_timed(fast_search, q_list, bank, scorer, c2f_cfg)
    hp, c2fh = _search_timed(fast_search, q_list, bank, scorer,
                             replace(c2f_cfg, refine_objects=C2F_HALVING_REFINE_OBJECTS, halving=True))
    return ({"greedy": greedy, "fast": fast, "c2f": c2f, "c2f_halving": c2fh},
            {"greedy": gp, "fast": fp, "c2f": cp, "c2f_halving": hp})


def _evaluate_real(objects: list[str], flat: list[tuple], preds: list) -> dict:
    """Rota. Acc. and category accuracy (percent) and median geodesic error (degrees) of ``preds``,
    one prediction per query of ``flat``."""
    from helpers.evaluation.metrics import Record, evaluate_predictions

    # Records need each query's index within its object.
    idx_in_obj, seen = [], {}
    for o, _, _ in flat:
        idx_in_obj.append(seen.get(o, 0))
        seen[o] = seen.get(o, 0) + 1
    recs = [Record(objects[o], p.obj_name, np.asarray(qv.rotations[i], np.float64), p.R_est, qv.symmetries,
                   f"{objects[o]}:{i}")
            for (o, qv, _), i, p in zip(flat, idx_in_obj, preds)]
    _, means = evaluate_predictions(recs, 30.0)
    return {"rot_acc_pct": means["rot_acc"], "class_acc_pct": means["class_acc"],
            "median_err_deg": means["median_err_deg"]}


def _agreement(xs: list, ys: list, same_object_only: bool = False) -> float:
    """Share of queries on which two searches name the same (object, reference), or the same object only."""
    if same_object_only:
        return float(np.mean([a.obj_index == b.obj_index for a, b in zip(xs, ys)]))
    return float(np.mean([_same(a, b) for a, b in zip(xs, ys)]))


def bench_real_agreement(cfg: BenchConfig, checkpoint: str | None = None, tmp_root: str | None = None) -> dict:
    """Fast, coarse-to-fine fast (c2f) and greedy on rendered references and real-like queries:
    agreement and Rota. Acc."""
    from helpers.core.configs import SearchConfig
    from helpers.data.manifest import load_manifest
    from helpers.search.retrieval import ReferenceBank, model_scorer

    model, size, model_desc = _real_model(cfg, checkpoint)
    objects = load_manifest().object_names("train")[:cfg.real_objects]
    refs, queries, feats, q_feats, render_s, encode_s = _render_and_encode(cfg, model, objects, size, tmp_root)
    rots = np.asarray(refs[0].rotations, dtype=np.float64)
    if not all(np.array_equal(v.rotations, refs[0].rotations) for v in refs):
        raise RuntimeError("reference rotations differ between objects")
    scaled = scaled_fast_params(cfg.real_refs)
    bank = ReferenceBank(feats, rots, objects, k_ac=scaled["k_ac"])
    scorer = model_scorer(model, "cpu")
    flat = [(o, qv, qf[i]) for o, (qv, qf) in enumerate(zip(queries, q_feats)) for i in range(len(qf))]
    scaled_c2f = scaled_c2f_params(cfg.real_refs)
    fast_cfg, c2f_cfg = SearchConfig("fast", **scaled), SearchConfig("c2f", **scaled_c2f)
    t, p = _time_real_searches(flat, bank, scorer, fast_cfg, c2f_cfg)
    greedy, fast, c2f, c2fh = t["greedy"], t["fast"], t["c2f"], t["c2f_halving"]
    gp, fp, cp, hp = p["greedy"], p["fast"], p["c2f"], p["c2f_halving"]
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
            "greedy": {**greedy, **_evaluate_real(objects, flat, gp)},
            "fast": {**fast, **_evaluate_real(objects, flat, fp)},
            "c2f": {**c2f, **_evaluate_real(objects, flat, cp)},
            "agreement_c2f_fast_same_reference": _agreement(cp, fp),
            "agreement_c2f_greedy_same_reference": _agreement(cp, gp),
            "agreement_c2f_greedy_same_object": _agreement(cp, gp, same_object_only=True),
            "speedup_greedy_over_c2f": greedy["s_per_query_median"] / c2f["s_per_query_median"],
            "c2f_halving": {**c2fh, **_evaluate_real(objects, flat, hp)},
            "agreement_c2f_halving_fast_same_reference": _agreement(hp, fp),
            "agreement_c2f_halving_greedy_same_reference": _agreement(hp, gp),
            "speedup_greedy_over_c2f_halving": greedy["s_per_query_median"] / c2fh["s_per_query_median"],
            "agreement_same_reference": _agreement(fp, gp),
            "agreement_same_object": _agreement(fp, gp, same_object_only=True),
            "speedup_greedy_over_fast": greedy["s_per_query_median"] / fast["s_per_query_median"],
            "rot_acc_note": "Rota. Acc. = category right and symmetry-aware geodesic error < 30 deg, "
                            "averaged per object then over objects (helpers.evaluation.metrics)"}
