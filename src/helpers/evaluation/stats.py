"""The study's statistics in one place, and its one vocabulary of verdicts.

* Accuracies are object-averaged: per object, then over the objects of a split, then over splits.
  Their 95 % intervals come from a bootstrap that resamples queries within each object, so each
  object keeps its weight (:func:`accuracy_ci`).
* A difference between two methods on the same queries is paired: one resample serves both
  (:func:`paired_difference`); on different queries each side is resampled on its own
  (:func:`unpaired_difference`). Differences are in percentage points.
* Training noise: the seed-to-seed range of one variant's accuracy (:func:`seed_spread`); a
  paired claim between trained variants compares matched seeds (:func:`claim`, :func:`chain`).
* Verdicts (:data:`VERDICTS`): the only words notebooks, ``claims.json`` and ``REPORT.md`` use.

Per-query tables hold ``obj``, ``query_id``, 0/1 outcome columns (``rot_ok``, ``class_ok``,
``vsd_ok``) and, when several splits are pooled, ``split`` (queries are then matched on
``split`` and ``query_id``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

N_BOOT = 2000
LEVEL = 0.95

#: A directional claim "b beats a" (paired difference b - a): its 95 % interval lies above 0 and, where the
#: training-seed spread is measured, the difference exceeds it.
HOLDS = "holds"
#: The interval lies below 0 (and beyond the seed spread): the opposite of the claim is measured.
REVERSED = "reversed"
#: The interval contains 0 (an equivalence claim: the interval is too wide to tell).
WITHIN_NOISE = "within noise"
#: The interval excludes 0, but the difference is no larger than one variant's seed-to-seed range.
WITHIN_SEED_SPREAD = "within seed spread"
#: A number reported with its interval, no comparison made.
MEASURED = "measured"
#: A calibration number (HOG's accuracy) inside / outside its target band.
CALIBRATED = "calibrated"
OUTSIDE_BAND = "outside the calibration band"
VERDICTS = (HOLDS, REVERSED, WITHIN_NOISE, WITHIN_SEED_SPREAD, MEASURED, CALIBRATED, OUTSIDE_BAND)


# ------------------------------------------------------------------ intervals

def _groups(df: pd.DataFrame) -> tuple[list[np.ndarray], np.ndarray]:
    """Row indices of each (split, obj) group, sorted, and each group's weight: the weighted sum of
    per-object means is the mean over splits of the mean over that split's objects."""
    keys = ["split", "obj"] if "split" in df.columns else ["obj"]
    groups = df[keys].drop_duplicates().sort_values(keys).itertuples(index=False, name=None)
    groups = list(groups)
    split_of = [g[0] if len(keys) == 2 else 0 for g in groups]
    n_splits = len(set(split_of))
    per_split = pd.Series(split_of).value_counts()
    weights = np.array([1.0 / (n_splits * per_split[s]) for s in split_of])
    cols = [df[k].to_numpy() for k in keys]
    idx = [np.flatnonzero(np.logical_and.reduce([c == v for c, v in zip(cols, g)])) for g in groups]
    return idx, weights


def _bootstrap(df: pd.DataFrame, column: str, rng: np.random.Generator) -> tuple[float, np.ndarray]:
    """Object-averaged mean (%) of ``column`` and its (N_BOOT,) bootstrap replicates (%)."""
    if len(df) == 0:
        raise ValueError(f"bootstrap: no queries to average ({column!r})")
    idx, w = _groups(df)
    x = df[column].astype(float).to_numpy()
    point = 100.0 * float(sum(wi * x[g].mean() for g, wi in zip(idx, w)))
    boots = np.zeros(N_BOOT)
    for g, wi in zip(idx, w):
        # Mean of a resample of this object's queries, for every bootstrap draw at once.
        boots += wi * x[g][rng.integers(0, len(g), size=(N_BOOT, len(g)))].mean(axis=1)
    return point, 100.0 * boots


def _interval(boots: np.ndarray) -> list[float]:
    lo, hi = np.quantile(boots, [(1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return [float(lo), float(hi)]


def accuracy_ci(df: pd.DataFrame, column: str = "rot_ok", seed: int = 0) -> tuple[float, list[float]]:
    """Object-averaged accuracy (%) of a per-query 0/1 ``column`` and its 95 % bootstrap interval."""
    point, boots = _bootstrap(df, column, np.random.default_rng(seed))
    return point, _interval(boots)


def _paired(a: pd.DataFrame, b: pd.DataFrame, column: str) -> pd.DataFrame:
    keys = ["split", "query_id"] if "split" in a.columns and "split" in b.columns else ["query_id"]
    m = a[keys + (["obj"] if "obj" not in keys else []) + [column]].merge(b[keys + [column]], on=keys,
                                                                          suffixes=("_a", "_b"))
    if len(m) != len(a) or len(m) != len(b):
        raise ValueError(f"paired_difference: the two tables must hold the same queries ({len(a)} vs {len(b)} "
                         f"rows, {len(m)} matched on {keys})")
    m["d"] = m[f"{column}_b"].astype(float) - m[f"{column}_a"].astype(float)
    return m


def paired_difference(a: pd.DataFrame, b: pd.DataFrame, column: str = "rot_ok", seed: int = 0) -> dict[str, Any]:
    """``b - a`` in points (object-averaged) on the same queries, with a paired bootstrap 95 % interval.

    Returns {"diff_pts", "ci": [lo, hi], "level", "n_queries"}."""
    point, boots = _bootstrap(_paired(a, b, column), "d", np.random.default_rng(seed))
    return {"diff_pts": point, "ci": _interval(boots), "level": LEVEL, "n_queries": int(len(a))}


def unpaired_difference(a: pd.DataFrame, b: pd.DataFrame, column: str = "rot_ok", seed: int = 0) -> dict[str, Any]:
    """``b - a`` in points for two different query sets, each resampled on its own (same keys as
    :func:`paired_difference`)."""
    rng = np.random.default_rng(seed)
    pa, ba = _bootstrap(a, column, rng)
    pb, bb = _bootstrap(b, column, rng)
    return {"diff_pts": pb - pa, "ci": _interval(bb - ba), "level": LEVEL, "n_queries": int(len(a) + len(b))}


def share_ci(ok: np.ndarray, seed: int = 0) -> dict[str, Any]:
    """Share of True in a per-query (N,) boolean array with a 95 % bootstrap interval over queries:
    {"share", "ci95", "n"} (NaN share and [0, 0] for N = 0)."""
    ok = np.asarray(ok, dtype=float)
    if not len(ok):
        return {"share": float("nan"), "ci95": [0.0, 0.0], "n": 0}
    boots = ok[np.random.default_rng(seed).integers(0, len(ok), size=(N_BOOT, len(ok)))].mean(axis=1)
    return {"share": float(ok.mean()), "ci95": _interval(boots), "n": int(len(ok))}


def ratio_of_medians_ci(a: np.ndarray, b: np.ndarray, seed: int = 0) -> dict[str, Any]:
    """median(a) / median(b) of paired per-query values (e.g. seconds of two searches on the same
    queries) with a paired bootstrap 95 % interval: {"ratio", "ci"}."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if len(a) != len(b) or not len(a):
        raise ValueError(f"ratio_of_medians_ci: expected two non-empty arrays of one length, got {len(a)}, {len(b)}")
    i = np.random.default_rng(seed).integers(0, len(a), size=(N_BOOT, len(a)))
    return {"ratio": float(np.median(a) / np.median(b)),
            "ci": _interval(np.median(a[i], axis=1) / np.median(b[i], axis=1))}


# ------------------------------------------------------------------ verdicts

def direction_verdict(ci: list[float], diff: float | None = None, seed_spread: float | None = None,
                      sign: int = 1) -> str:
    """Verdict on "the difference has sign ``sign``" (+1: b beats a; -1: b loses to a) from its
    95 % interval and, where measured, the seed spread (points)."""
    lo, hi = (ci[0], ci[1]) if sign > 0 else (-ci[1], -ci[0])
    if lo <= 0 <= hi:
        return WITHIN_NOISE
    if seed_spread is not None and diff is not None and abs(diff) <= seed_spread:
        return WITHIN_SEED_SPREAD
    return HOLDS if lo > 0 else REVERSED


def equivalence_verdict(ci: list[float], margin: float) -> str:
    """Verdict on "the difference lies within +-``margin`` points": the whole interval inside the
    margin holds, wholly outside it is reversed, otherwise the interval is too wide to tell."""
    lo, hi = ci
    if -margin <= lo and hi <= margin:
        return HOLDS
    if lo > margin or hi < -margin:
        return REVERSED
    return WITHIN_NOISE


def calibration_verdict(value: float, band: tuple[float, float]) -> str:
    return CALIBRATED if band[0] <= value <= band[1] else OUTSIDE_BAND


# ------------------------------------------------------------------ trained variants and seeds

def seed_spread(accs: dict[str, list[float]]) -> float | None:
    """Largest seed-to-seed range (points) among variants with several seeds' accuracies (None if none)."""
    ranges = [max(a) - min(a) for a in accs.values() if len(a) > 1]
    return float(max(ranges)) if ranges else None


def _as_list(x: Any) -> list:
    return list(x) if isinstance(x, (list, tuple)) else [x]


def seed_mean(tables: list[pd.DataFrame]) -> pd.DataFrame:
    """Per-query table whose 0/1 columns are averaged over training seeds (same queries in each)."""
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
    """The claim "``better`` beats ``worse``" on the same queries: paired difference, its 95 %
    interval over queries, and the training-seed spread.

    ``per_query`` maps labels to one per-query table or a list (one per training seed, in seed
    order). Seeds are matched: seed i of one variant against seed i of the other (same
    initialisation draw, batches and augmentation), over the seeds both have; the difference is
    that of the accuracies averaged over those matched seeds, so a variant's extra seeds never
    enter a comparison with a one-seed variant. ``verdict`` is :func:`direction_verdict` with the
    seed spread (the largest seed-to-seed range of one variant, points; None: not measured, the
    interval alone). ``point_estimate_agrees``: better > worse in the point estimate.
    None when a variant was not run.
    """
    if worse not in per_query or better not in per_query:
        return None
    a, b = _as_list(per_query[worse]), _as_list(per_query[better])
    n = min(len(a), len(b))
    c = paired_difference(seed_mean(a[:n]), seed_mean(b[:n]))
    per_seed = [paired_difference(a[i], b[i])["diff_pts"] for i in range(n)]
    return {"compare": f"{better} vs {worse}", **c, "point_estimate_agrees": bool(c["diff_pts"] > 0),
            "seeds": [len(a), len(b)], "matched_seeds": n, "per_seed_diff_pts": per_seed,
            "seed_spread_pts": seed_spread, "verdict": direction_verdict(c["ci"], c["diff_pts"], seed_spread)}


def chain(per_query: dict[str, Any], order: list[str], seed_spread: float | None = None) -> dict | None:
    """The claim that accuracy rises along ``order``: each consecutive pair as in :func:`claim`.
    Verdict: holds when every pair holds, reversed when any pair is reversed, else within the
    seed spread when any pair is, else within noise."""
    present = [k for k in order if k in per_query]
    if len(present) < 2:
        return None
    pairs = [claim(per_query, a, b, seed_spread) for a, b in zip(present, present[1:])]
    verdicts = {p["verdict"] for p in pairs}
    verdict = HOLDS if verdicts == {HOLDS} else REVERSED if REVERSED in verdicts else \
        WITHIN_SEED_SPREAD if WITHIN_SEED_SPREAD in verdicts else WITHIN_NOISE
    return {"point_estimate_agrees": all(p["point_estimate_agrees"] for p in pairs), "pairs": pairs,
            "verdict": verdict}


def seed_differences(per_query: dict[str, Any]) -> dict[str, dict]:
    """label -> paired difference (points) between its second and first training seed, for every
    variant with several seeds: the training noise, with its own query interval."""
    out = {}
    for label, tables in per_query.items():
        tables = _as_list(tables)
        if len(tables) > 1:
            out[label] = {"compare": f"{label} seed 2 vs seed 1", **paired_difference(tables[0], tables[1])}
    return out
