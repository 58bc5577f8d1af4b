"""Train variants of the method and compare them on the same queries, with paired intervals.

The one helper behind every ablation notebook (scales, fusion, components):

    configs = {label: variant_config(train_cfg, scales="13") ...}       # what changes
    trained = train_variants(configs, data, split, val_refs=val_refs)    # train or load each
    results = evaluate_unseen(trained, data, split, eval_refs=eval_refs) # same unseen queries
    table = variant_table(trained, results)                               # one row per variant
    claim(per_query(results), "global", "32,16,13")                       # paired bootstrap

Every variant uses the same data, seed and training budget on the seen objects of
one split; evaluation retrieves the split's unseen test queries among the 13
benchmark objects with greedy search, so two variants' per-query results are
paired and their difference gets a paired bootstrap interval
(:func:`helpers.metrics.paired_difference`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .fileio import atomic_write_json
from .metrics import paired_difference
from .model import LEVELS
from .study import StudyData, evaluate, reference_bank, train_or_load
from .tables import write_table

NOISE_NOTE = ("claims compare object-averaged Rota. Acc. of two variants on the same queries; ci is a "
              "paired bootstrap 95 % interval (queries resampled within objects)")


def parse_scales(scales: str) -> tuple[int, ...] | str:
    """Notebook form of the scales -> ModelConfig form: "global" or "32,16,13" -> (32, 16, 13)."""
    if scales == "global":
        return "global"
    try:
        out = tuple(int(s) for s in str(scales).split(","))
    except ValueError:
        out = ()
    if not out or not set(out) <= set(LEVELS):
        raise ValueError(f"scales: expected 'global' or a comma list of 32/16/13, got {scales!r}")
    return out


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


def train_variants(configs: dict[str, Any], data: StudyData, split: int, val_refs: int) -> dict[str, Trained]:
    """Train (or load from the cache) one model per labelled TrainConfig on split ``split``'s seen
    objects; validation uses ``val_refs`` references per seen object. Progress bars per epoch."""
    out = {}
    for label, cfg in configs.items():
        print(f"variant {label!r}", flush=True)
        model, run, info = train_or_load(split, cfg, data, val_refs_per_object=val_refs)
        out[label] = Trained(model, run, info)
    return out


def evaluate_unseen(trained: dict[str, Trained], data: StudyData, split: int, eval_refs: int = 0,
                    device: str = "auto") -> dict[str, dict]:
    """Greedy retrieval of split ``split``'s unseen test queries among the 13 benchmark objects,
    with the first ``eval_refs`` references per object (0: all), for every variant."""
    bench = data.manifest.object_names("train")
    queries = {n: data.test_q[n] for n in data.manifest.split_objects(split)}
    out = {}
    for label, t in trained.items():
        bank = reference_bank(t.model, data, bench, device=device, n_refs=eval_refs or None)
        out[label] = evaluate(t.model, bank, queries, "greedy", device)
    return out


def per_query(results: dict[str, dict]) -> dict[str, pd.DataFrame]:
    """label -> per-query table (the input of :func:`claim`)."""
    return {label: r["per_query"] for label, r in results.items()}


def variant_table(trained: dict[str, Trained], results: dict[str, dict],
                  extra: dict[str, dict] | None = None) -> pd.DataFrame:
    """One row per variant: unseen Rota./Class. Acc. (%), median error, queries, run folder, extras."""
    rows = []
    for label, r in results.items():
        m = r["means"]
        rows.append({"variant": label, "unseen rot_acc": m["rot_acc"], "unseen class_acc": m["class_acc"],
                     "unseen median_err_deg": m["median_err_deg"], "n_queries": m["n_queries"],
                     "run": Path(trained[label].run).name, **((extra or {}).get(label) or {})})
    return pd.DataFrame(rows)


def claim(per_query: dict[str, pd.DataFrame], worse: str, better: str) -> dict | None:
    """Paper claim "``better`` beats ``worse``" on our queries: point estimate and paired 95 % interval.

    ``holds`` is the point estimate (better > worse); ``verdict`` says whether
    the paired bootstrap interval of the difference excludes 0. None when a
    variant was not run.
    """
    if worse not in per_query or better not in per_query:
        return None
    c = paired_difference(per_query[worse], per_query[better])
    return {"holds": bool(c["diff_pts"] > 0), "compare": f"{better} vs {worse}", **c,
            "verdict": {"b > a": "significant", "b < a": "significantly reversed"}.get(c["verdict"], "within noise")}


def chain(per_query: dict[str, pd.DataFrame], order: list[str]) -> dict | None:
    """Claim that accuracy rises along ``order``: every consecutive pair as in :func:`claim`."""
    present = [k for k in order if k in per_query]
    if len(present) < 2:
        return None
    pairs = [claim(per_query, a, b) for a, b in zip(present, present[1:])]
    verdicts = {p["verdict"] for p in pairs}
    return {"holds": all(p["holds"] for p in pairs), "pairs": pairs,
            "verdict": "significant" if verdicts == {"significant"} else
            "partly reversed beyond noise" if "significantly reversed" in verdicts else "within noise"}


def claims_table(trend: dict) -> pd.DataFrame:
    """The claims of a trend dict as a readable table (one row per compared pair)."""
    rows = []
    for key, v in trend.items():
        if not isinstance(v, dict):
            continue
        for p in v.get("pairs") or [v]:
            if "diff_pts" in p:
                rows.append({"claim": key, "compare": p["compare"], "diff (pts)": p["diff_pts"],
                             "ci95": f"[{p['ci'][0]:.1f}, {p['ci'][1]:.1f}]", "verdict": p["verdict"]})
    return pd.DataFrame(rows)


def save_study(out_dir: Path, stem: str, table: pd.DataFrame, trend: dict) -> dict:
    """Write ``<stem>.csv/.md`` and ``metrics.json`` ({table, trend, noise}) into ``out_dir``."""
    write_table(table, Path(out_dir) / stem)
    out = {"table": table.to_dict(orient="records"), "trend": {k: v for k, v in trend.items() if v is not None},
           "noise": NOISE_NOTE}
    atomic_write_json(Path(out_dir) / "metrics.json", out)
    return out


def validation_curves(trained: dict[str, Trained]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """label -> (optimiser steps, validation Rota. Acc. %) of each variant's training history."""
    out = {}
    for label, t in trained.items():
        hist = (t.info.get("history") or {}).get("history") or []
        pts = [(h["global_step"], 100 * h["val"]["rot_acc"]) for h in hist if h.get("val")]
        out[label] = (np.array([p[0] for p in pts]), np.array([p[1] for p in pts]))
    return out
