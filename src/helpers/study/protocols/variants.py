"""Train variants of the method and compare them on the same queries, with paired intervals.

The one helper behind every ablation notebook (scales, fusion, components):

    configs = {label: variant_config(train_cfg, scales="13") ...}       # what changes
    runs = with_seeds(configs, ["32,16,13"], n_seeds=2)                   # training seeds per variant
    trained = train_variants(runs, data, split, val_refs=val_refs)       # train or load each
    results = evaluate_unseen(trained, data, split, eval_refs=eval_refs) # same unseen queries
    table = variant_table(trained, results)                               # one row per variant
    spread = seed_spread(seed_accuracies(results))                        # training noise (stats)
    claim(per_query(results), "global", "32,16,13", spread)               # paired bootstrap + seeds (stats)

Every variant uses the same data and training budget on the seen objects of one
split; evaluation retrieves the split's unseen test queries among the 13
benchmark objects with greedy search, so two variants' per-query results are
paired and their difference gets a paired bootstrap interval
(:func:`helpers.evaluation.stats.paired_difference`; claims: :func:`helpers.evaluation.stats.claim`).

Two sources of noise, reported side by side:

- query resampling: the paired bootstrap interval ``ci`` of the difference of the
  accuracies averaged over the training seeds both variants have (seed i against
  seed i: same initialisation draw, batches and augmentation);
- training noise: variants in ``seeded`` are trained with several seeds
  (``seed``, ``seed + 1``, ...); the *seed spread* is the largest
  seed-to-seed range of Rota. Acc. (points, same queries) among them.

A claim "holds" only if its interval excludes 0 AND the difference is larger
than the seed spread ("within seed spread" when only the first is true), so a
claim must hold beyond both (:func:`helpers.evaluation.stats.direction_verdict`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...core.configs import GREEDY, parse_scales
from ...core.fileio import atomic_write_json, write_table
from ...core.views import ObjectViews
from ...evaluation.stats import accuracy_ci, seed_mean
from ..pipeline import StudyData
from ..zoo import model_for
from .eval_cache import cached_evaluate, evals_folder

NOISE_NOTE = ("claims compare object-averaged Rota. Acc. of two variants on the same queries; ci is a paired "
              "bootstrap 95 % interval (queries resampled within objects) of the difference of accuracies averaged "
              "over matched training seeds; seed_spread is the largest seed-to-seed range of a variant trained with "
              "several seeds; a claim holds only beyond both")


def variant_config(base: Any, *, fusion: str | None = None, scales: str | None = None,
                   local_norm: bool | None = None, weighted_loss: bool | None = None) -> Any:
    """A copy of the TrainConfig ``base`` with one or more of the paper's ablation switches changed."""
    model = replace(base.model, **{k: v for k, v in (("fusion", fusion), ("local_norm", local_norm),
                                                     ("scales", None if scales is None else parse_scales(scales)))
                                   if v is not None})
    return replace(base, model=model, **({} if weighted_loss is None else {"weighted_loss": weighted_loss}))


@dataclass
class Trained:
    """A trained (or loaded) model: the model in eval mode, its run folder and training info."""

    model: Any
    run: Path
    info: dict


def _as_list(v: Any) -> list:
    return list(v) if isinstance(v, (list, tuple)) else [v]


def with_seeds(configs: dict[str, Any], seeded: list[str], n_seeds: int) -> dict[str, list[Any]]:
    """label -> list of TrainConfigs, one per training seed.

    Labels in ``seeded`` get ``n_seeds`` copies with seeds ``cfg.seed``, ``cfg.seed + 1``, ...;
    the others keep their one config (its seed), so their runs are the same (cached) runs as
    without seeds. Only the training seed changes (initialisation, batches, augmentation);
    the rendered data stay the same.
    """
    unknown = [k for k in seeded if k not in configs]
    if unknown:
        raise ValueError(f"seeded_variants: {unknown} are not among the variants {list(configs)}")
    if n_seeds < 1:
        raise ValueError(f"n_seeds: expected an int >= 1, got {n_seeds!r}")
    return {k: [replace(c, seed=c.seed + i) for i in range(n_seeds if k in seeded else 1)]
            for k, c in configs.items()}


def train_variants(configs: dict[str, Any], data: StudyData, split: int, val_refs: int,
                   models: str = "train") -> dict[str, list[Trained]]:
    """Train (or load from the cache) every labelled TrainConfig (or list of them, one per seed)
    on split ``split``'s seen objects; validation uses ``val_refs`` references per seen object.
    ``models="zoo"`` loads each variant's committed zoo model instead (:func:`helpers.study.zoo.model_for`).
    Returns label -> [Trained per seed]. Progress bars per epoch."""
    out: dict[str, list[Trained]] = {}
    for label, cfgs in configs.items():
        out[label] = []
        for cfg in _as_list(cfgs):
            print(f"variant {label!r} seed {cfg.seed}", flush=True)
            model, run, info = model_for(split, cfg, data, val_refs, models)
            out[label].append(Trained(model, run, {"seed": cfg.seed, **info}))
            if models == "zoo":  # the notebook's own budget parameters are not used: say what is
                src = model_source(out[label][-1])
                print(f"  zoo model {src['model']}: {src['steps']} steps, evaluated at {src['best_step']}", flush=True)
    if models == "zoo":
        budgets = {label: sorted({model_source(t)["steps"] for t in ts}) for label, ts in out.items()}
        if len({s for v in budgets.values() for s in v}) > 1:
            raise ValueError(f"models='zoo': the variants' zoo models were trained for different numbers of steps "
                             f"{budgets}; an ablation compares equal budgets, so train the others to the same "
                             "budget (`python -m helpers.study.cli.zoo train NAME --publish`) or use models='train'")
    return out


def model_source(t: Trained) -> dict:
    """Where a variant's model came from, for the tables and metrics.json: ``{"source": "zoo", "model":
    name, "sha256", "steps", "best_step"}`` for a committed zoo model, ``{"source": "train", "model": run
    folder name, "steps", "best_step"}`` for a cache run (steps: optimiser steps trained; best_step: those of
    the evaluated checkpoint)."""
    e = t.info.get("zoo_entry")
    if e:
        return {"source": "zoo", "model": t.info["zoo"], "sha256": e["sha256"], "steps": int(e["steps"]),
                "best_step": e.get("best_step")}
    hist = (t.info.get("history") or {}).get("history") or []
    best_epoch = (t.info.get("history") or {}).get("best_epoch")
    return {"source": "train", "model": Path(t.run).name,
            "steps": max((int(h["global_step"]) for h in hist), default=None),
            "best_step": next((int(h["global_step"]) for h in hist if h.get("epoch") == best_epoch), None)}


def _evals_dir(t: Trained, data: StudyData) -> Path:
    """Folder of a model's cached per-query evaluations: its run folder's ``evals/``, or for a zoo model
    (whose "run" is its committed weight file) the cache's ``evals/``, so nothing is written into
    ``models/``; the file names hold the weights' fingerprint either way."""
    run = Path(t.run)
    return run / "evals" if run.is_dir() else evals_folder(data)


def evaluate_unseen(trained: dict[str, Any], data: StudyData, split: int, eval_refs: int = 0,
                    device: str = "auto") -> dict[str, list[dict]]:
    """Greedy retrieval of split ``split``'s unseen test queries among the 13 benchmark objects,
    with the first ``eval_refs`` references per object (0: all), for every variant and seed
    (:func:`evaluate_queries`). Returns label -> [result per seed] (each with "per_query", "per_object", "means")."""
    bench = data.manifest.object_names("train")
    queries = {n: data.test_q[n] for n in data.manifest.split_objects(split)}
    return evaluate_queries(trained, data, queries, bench, eval_refs, device)


def evaluate_queries(trained: dict[str, Any], data: StudyData, queries: dict[str, ObjectViews], bench: list[str],
                     eval_refs: int = 0, device: str = "auto") -> dict[str, list[dict]]:
    """Greedy retrieval of ``queries`` (object name -> views) among the references of the objects ``bench``
    (the first ``eval_refs`` per object, 0: all), for every variant and seed.

    A model's per-query results are kept in its run folder (``evals/<key>.csv``, keyed by the
    weights, bank and queries; a zoo model's in the cache's ``evals/``), so a model shared by several
    notebooks is evaluated once.
    Returns label -> [result per seed] (each with "per_query", "per_object", "means")."""
    out: dict[str, list[dict]] = {}
    for label, ts in trained.items():
        out[label] = [cached_evaluate(t.model, data, bench, queries, GREEDY, _evals_dir(t, data), eval_refs, device)
                      for t in _as_list(ts)]
    return out


def per_query(results: dict[str, Any]) -> dict[str, list[pd.DataFrame]]:
    """label -> per-query tables, one per seed (the input of :func:`claim`)."""
    return {label: [r["per_query"] for r in _as_list(rs)] for label, rs in results.items()}


def seed_accuracies(results: dict[str, Any]) -> dict[str, list[float]]:
    """label -> unseen Rota. Acc. (%) of each of its training seeds (the input of
    :func:`helpers.evaluation.stats.seed_spread`)."""
    return {label: [float(r["means"]["rot_acc"]) for r in _as_list(rs)] for label, rs in results.items()}


def variant_table(trained: dict[str, Any], results: dict[str, Any],
                  extra: dict[str, dict] | None = None, part: str = "unseen") -> pd.DataFrame:
    """One row per variant: unseen Rota./Class. Acc. (%, mean over its seeds) with the Rota. Acc.'s 95 %
    bootstrap interval over queries (``ci95 lo`` / ``ci95 hi``, of the seed mean: the seeds answer the same
    queries), median error, queries, seeds with their Rota. Acc. and range, optimiser steps trained, run
    folders (zoo names for zoo models), extras. ``part`` names the queries in the column names."""
    rows = []
    seeded = any(len(_as_list(v)) > 1 for v in results.values())
    for label, rs in results.items():
        rs, ts = _as_list(rs), _as_list(trained[label])
        mean = {k: float(np.mean([r["means"][k] for r in rs])) for k in ("rot_acc", "class_acc", "median_err_deg")}
        accs = [r["means"]["rot_acc"] for r in rs]
        _, ci = accuracy_ci(seed_mean([r["per_query"] for r in rs]))
        row = {"variant": label, f"{part} rot_acc": mean["rot_acc"], "ci95 lo": ci[0], "ci95 hi": ci[1],
               f"{part} class_acc": mean["class_acc"], f"{part} median_err_deg": mean["median_err_deg"],
               "n_queries": rs[0]["means"]["n_queries"]}
        if seeded:
            row.update({"seeds": len(rs), "rot_acc per seed": ", ".join(f"{a:.1f}" for a in accs),
                        "seed range (pts)": float(max(accs) - min(accs)) if len(accs) > 1 else None})
        sources = [model_source(t) for t in ts]
        steps = sorted({x["steps"] for x in sources if x["steps"] is not None})
        row["steps"] = ", ".join(map(str, steps)) or None
        row["run"] = ", ".join(x["model"] for x in sources)
        rows.append({**row, **((extra or {}).get(label) or {})})
    return pd.DataFrame(rows)


def claims_table(trend: dict) -> pd.DataFrame:
    """The claims of a trend dict as a readable table (one row per compared pair)."""
    rows = []
    for key, v in trend.items():
        if not isinstance(v, dict):
            continue
        for p in v.get("pairs") or [v]:
            if "diff_pts" in p:
                row = {"claim": key, "compare": p["compare"], "diff (pts)": p["diff_pts"],
                       "ci95": f"[{p['ci'][0]:.1f}, {p['ci'][1]:.1f}]"}
                if p.get("seed_spread_pts") is not None:
                    row["per-seed diff (pts)"] = ", ".join(f"{d:.1f}" for d in p["per_seed_diff_pts"])
                    row["seed spread (pts)"] = p["seed_spread_pts"]
                rows.append({**row, "verdict": p["verdict"]})
    return pd.DataFrame(rows)


def save_study(out_dir: Path, stem: str, table: pd.DataFrame, trend: dict, seeds: dict | None = None,
               split: int | None = None, trained: dict[str, Any] | None = None, extra: dict | None = None) -> dict:
    """Write ``<stem>.csv/.md`` and ``metrics.json`` ({table, trend, seeds, noise, models} and ``extra``'s keys)
    into ``out_dir``; ``models`` is label -> [:func:`model_source` per seed] of ``trained``."""
    write_table(table, Path(out_dir) / stem)
    out = {"table": table.to_dict(orient="records"), "trend": {k: v for k, v in trend.items() if v is not None},
           "seeds": seeds or {}, "noise": NOISE_NOTE, **({} if split is None else {"split": split}),
           **({} if trained is None else
              {"models": {label: [model_source(t) for t in _as_list(ts)] for label, ts in trained.items()}}),
           **(extra or {})}
    atomic_write_json(Path(out_dir) / "metrics.json", out)
    return out


def validation_curves(trained: dict[str, Any]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """label (with its seed where a variant has several) -> (optimiser steps, validation Rota.
    Acc. %) of each training history."""
    out = {}
    for label, ts in trained.items():
        for t in _as_list(ts):
            name = label if len(_as_list(ts)) == 1 else f"{label} (seed {t.info.get('seed')})"
            out[name] = _curve(t)
    return out


def _curve(t: Trained) -> tuple[np.ndarray, np.ndarray]:
    hist = (t.info.get("history") or {}).get("history") or []
    pts = [(h["global_step"], 100 * h["val"]["rot_acc"]) for h in hist if h.get("val")]
    return np.array([p[0] for p in pts]), np.array([p[1] for p in pts])
