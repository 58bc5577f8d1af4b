"""Train variants of the method and compare them on the same queries, with paired intervals.

The one helper behind every ablation notebook (scales, fusion, components):

    configs = {label: variant_config(train_cfg, scales="13") ...}       # what changes
    runs = with_seeds(configs, ["32,16,13"], n_seeds=2)                   # training seeds per variant
    trained = train_variants(runs, data, split, val_refs=val_refs)       # train or load each
    results = evaluate_unseen(trained, data, split, eval_refs=eval_refs) # same unseen queries
    table = variant_table(trained, results)                               # one row per variant
    claim(per_query(results), "global", "32,16,13", seed_spread(results)) # paired bootstrap + seeds

Every variant uses the same data and training budget on the seen objects of one
split; evaluation retrieves the split's unseen test queries among the 13
benchmark objects with greedy search, so two variants' per-query results are
paired and their difference gets a paired bootstrap interval
(:func:`helpers.evaluation.metrics.paired_difference`).

Two sources of noise, reported side by side:

- query resampling: the paired bootstrap interval ``ci`` of the difference of the
  accuracies averaged over the training seeds both variants have (seed i against
  seed i: same initialisation draw, batches and augmentation);
- training noise: variants in ``seeded`` are trained with several seeds
  (``seed``, ``seed + 1``, ...); the *seed spread* is the largest
  seed-to-seed range of Rota. Acc. (points, same queries) among them.

A claim's verdict is "significant" only if its interval excludes 0 AND the
difference is larger than the seed spread ("within seed spread" when only the
first holds), so a claim must hold beyond both.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..core.configs import parse_scales
from ..core.fileio import atomic_write_json, atomic_write_text, stable_hash
from ..evaluation.metrics import paired_difference, summarise_queries
from ..search.features import model_fingerprint
from .pipeline import StudyData, evaluate, reference_bank
from .tables import write_table
from .zoo import model_for

NOISE_NOTE = ("claims compare object-averaged Rota. Acc. of two variants on the same queries; ci is a "
              "paired bootstrap 95 % interval (queries resampled within objects) of the difference of "
              "accuracies averaged over matched training seeds; seed_spread is the largest seed-to-seed range of a variant trained "
              "with several seeds; a verdict is significant only beyond both")


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
    return out


def _eval_cache_key(t: Trained, data: StudyData, bench: list[str], queries: dict, eval_refs: int) -> str:
    return stable_hash({"model": model_fingerprint(t.model), "bank": [data.key(n) for n in bench],
                        "eval_refs": eval_refs, "queries": {n: [v.meta.get("key"), len(v)] for n, v in queries.items()},
                        "method": "greedy", "threshold_deg": 30.0})


def evaluate_unseen(trained: dict[str, Any], data: StudyData, split: int, eval_refs: int = 0,
                    device: str = "auto") -> dict[str, list[dict]]:
    """Greedy retrieval of split ``split``'s unseen test queries among the 13 benchmark objects,
    with the first ``eval_refs`` references per object (0: all), for every variant and seed.

    A model's per-query results are kept in its run folder (``evals/<key>.csv``, keyed by the
    weights, bank and queries), so a model shared by several notebooks is evaluated once.
    Returns label -> [result per seed] (each with "per_query", "per_object", "means")."""
    bench = data.manifest.object_names("train")
    queries = {n: data.test_q[n] for n in data.manifest.split_objects(split)}
    out: dict[str, list[dict]] = {}
    for label, ts in trained.items():
        out[label] = []
        for t in _as_list(ts):
            f = Path(t.run) / "evals" / f"{_eval_cache_key(t, data, bench, queries, eval_refs)}.csv"
            if f.exists():
                pq = pd.read_csv(f)
                per_object, means = summarise_queries(pq)
                out[label].append({"per_query": pq, "per_object": per_object, "means": means, "cached": str(f)})
                continue
            bank = reference_bank(t.model, data, bench, device=device, n_refs=eval_refs or None)
            r = evaluate(t.model, bank, queries, "greedy", device)
            f.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(f, r["per_query"].to_csv(index=False))
            out[label].append(r)
    return out


def per_query(results: dict[str, Any]) -> dict[str, list[pd.DataFrame]]:
    """label -> per-query tables, one per seed (the input of :func:`claim`)."""
    return {label: [r["per_query"] for r in _as_list(rs)] for label, rs in results.items()}


def _seed_accs(results: dict[str, Any]) -> dict[str, list[float]]:
    return {label: [float(r["means"]["rot_acc"]) for r in _as_list(rs)] for label, rs in results.items()}


def seed_spread(results: dict[str, Any]) -> float | None:
    """Largest seed-to-seed range of unseen Rota. Acc. (points) among variants with several seeds
    (None when no variant has more than one)."""
    ranges = [max(a) - min(a) for a in _seed_accs(results).values() if len(a) > 1]
    return float(max(ranges)) if ranges else None


def variant_table(trained: dict[str, Any], results: dict[str, Any],
                  extra: dict[str, dict] | None = None) -> pd.DataFrame:
    """One row per variant: unseen Rota./Class. Acc. (%, mean over its seeds), median error,
    queries, seeds with their Rota. Acc. and range, run folders, extras."""
    rows = []
    seeded = any(len(_as_list(v)) > 1 for v in results.values())
    for label, rs in results.items():
        rs, ts = _as_list(rs), _as_list(trained[label])
        mean = {k: float(np.mean([r["means"][k] for r in rs])) for k in ("rot_acc", "class_acc", "median_err_deg")}
        accs = [r["means"]["rot_acc"] for r in rs]
        row = {"variant": label, "unseen rot_acc": mean["rot_acc"], "unseen class_acc": mean["class_acc"],
               "unseen median_err_deg": mean["median_err_deg"], "n_queries": rs[0]["means"]["n_queries"]}
        if seeded:
            row.update({"seeds": len(rs), "rot_acc per seed": ", ".join(f"{a:.1f}" for a in accs),
                        "seed range (pts)": float(max(accs) - min(accs)) if len(accs) > 1 else None})
        row["run"] = ", ".join(Path(t.run).name for t in ts)
        rows.append({**row, **((extra or {}).get(label) or {})})
    return pd.DataFrame(rows)


def _seed_mean(tables: list[pd.DataFrame]) -> pd.DataFrame:
    """Per-query table whose 0/1 columns are averaged over the seeds (same queries in each)."""
    if len(tables) == 1:
        return tables[0]
    base = tables[0][["query_id", "obj"]].copy()
    for col in ("rot_ok", "class_ok"):
        stacked = [t.set_index("query_id")[col].astype(float) for t in tables]
        if any(set(s.index) != set(stacked[0].index) for s in stacked):
            raise ValueError("seeds of one variant were evaluated on different queries")
        base[col] = np.mean([s.loc[base["query_id"]].to_numpy() for s in stacked], axis=0)
    return base


def claim(per_query: dict[str, Any], worse: str, better: str, seed_spread: float | None = None) -> dict | None:
    """Paper claim "``better`` beats ``worse``" on our queries: point estimate, paired 95 % interval
    over queries, and the training-seed spread.

    ``per_query`` maps labels to one per-query table or a list of them (one per training seed,
    in seed order). Seeds are matched: seed i of one variant is compared with seed i of the
    other (same initialisation draw, batches and augmentation), over the seeds both have, and
    the difference is that of the accuracies averaged over those matched seeds; a variant's
    extra seeds never enter a comparison with a one-seed variant (that would mix seed luck
    into the difference). ``holds`` is the point estimate (better > worse); ``verdict`` is
    "significant" / "significantly reversed" when the interval excludes 0 and |diff| exceeds
    ``seed_spread`` (the largest seed-to-seed range of one variant's Rota. Acc., points; None:
    not measured, interval only), "within seed spread" when only the interval excludes 0,
    else "within noise". ``per_seed_diff_pts`` lists the matched per-seed differences.
    None when a variant was not run.
    """
    if worse not in per_query or better not in per_query:
        return None
    a, b = _as_list(per_query[worse]), _as_list(per_query[better])
    n = min(len(a), len(b))
    c = paired_difference(_seed_mean(a[:n]), _seed_mean(b[:n]))
    per_seed = [paired_difference(a[i], b[i])["diff_pts"] for i in range(n)]
    beyond_seeds = seed_spread is None or abs(c["diff_pts"]) > seed_spread
    if c["verdict"] == "within noise":
        verdict = "within noise"
    elif not beyond_seeds:
        verdict = "within seed spread"
    else:
        verdict = "significant" if c["verdict"] == "b > a" else "significantly reversed"
    return {"holds": bool(c["diff_pts"] > 0), "compare": f"{better} vs {worse}", **c,
            "seeds": [len(a), len(b)], "matched_seeds": n, "per_seed_diff_pts": per_seed,
            "seed_spread_pts": seed_spread, "verdict": verdict}


def chain(per_query: dict[str, Any], order: list[str], seed_spread: float | None = None) -> dict | None:
    """Claim that accuracy rises along ``order``: every consecutive pair as in :func:`claim`."""
    present = [k for k in order if k in per_query]
    if len(present) < 2:
        return None
    pairs = [claim(per_query, a, b, seed_spread) for a, b in zip(present, present[1:])]
    verdicts = {p["verdict"] for p in pairs}
    return {"holds": all(p["holds"] for p in pairs), "pairs": pairs,
            "verdict": "significant" if verdicts == {"significant"} else
            "partly reversed beyond noise" if "significantly reversed" in verdicts else "within noise"}


def seed_differences(per_query: dict[str, Any]) -> dict[str, dict]:
    """label -> paired difference (points) between its second and first training seed, for
    every variant with several seeds: the training noise, with its own query interval."""
    out = {}
    for label, tables in per_query.items():
        tables = _as_list(tables)
        if len(tables) > 1:
            c = paired_difference(tables[0], tables[1])
            out[label] = {"compare": f"{label} seed 2 vs seed 1", **c}
    return out


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
               split: int | None = None) -> dict:
    """Write ``<stem>.csv/.md`` and ``metrics.json`` ({table, trend, seeds, noise}) into ``out_dir``."""
    write_table(table, Path(out_dir) / stem)
    out = {"table": table.to_dict(orient="records"), "trend": {k: v for k, v in trend.items() if v is not None},
           "seeds": seeds or {}, "noise": NOISE_NOTE, **({} if split is None else {"split": split})}
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
