"""Evaluation metrics: symmetry-aware rotation error, class / rotation accuracy.

Protocol (the method's): per object, Class. Acc. = % of its queries whose
predicted object is right; Rota. Acc. = % whose predicted object is right AND
whose rotation error is below a threshold (30 degrees). Per-object numbers are
then averaged over objects without weighting by query count.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from ..core.rotations import Symmetries, symmetric_geodesic_deg
from .stats import share_ci

#: Columns of the per-object table, in order.
PER_OBJECT_COLUMNS = ("n", "class_acc", "rot_acc", "median_err_deg", "mean_err_deg")


@dataclass
class Record:
    """One query's prediction.

    Attributes:
        obj: true object name.
        pred_obj: predicted object name.
        R_gt, R_est: (3, 3) ``R_m2c``.
        symmetries: optional (K, 3, 3) symmetries of the TRUE object.
        query_id: optional free-form identifier (kept in per-query tables).
    """

    obj: str
    pred_obj: str
    R_gt: np.ndarray
    R_est: np.ndarray
    symmetries: np.ndarray | None = None
    query_id: Any = None


def rotation_errors_deg(R_est: np.ndarray, R_gt: np.ndarray, symmetries: np.ndarray | None = None) -> np.ndarray:
    """Geodesic errors (N,) in degrees, minimised over ``symmetries`` (K,3,3) of the object.

    Accepts single (3,3) matrices or (N,3,3) stacks.
    """
    R_est = np.asarray(R_est, dtype=np.float64)
    R_gt = np.asarray(R_gt, dtype=np.float64)
    if R_est.shape[-2:] != (3, 3) or R_gt.shape[-2:] != (3, 3):
        raise ValueError(f"rotation_errors_deg: expected (N,3,3) or (3,3) arrays, got R_est {R_est.shape}, "
                         f"R_gt {R_gt.shape}")
    R_est, R_gt = R_est.reshape(-1, 3, 3), R_gt.reshape(-1, 3, 3)
    if len(R_est) != len(R_gt):
        raise ValueError(f"rotation_errors_deg: R_est has {len(R_est)} rotations, R_gt has {len(R_gt)}")
    if symmetries is not None and not isinstance(symmetries, Symmetries):
        symmetries = np.asarray(symmetries, dtype=np.float64).reshape(-1, 3, 3)
    return symmetric_geodesic_deg(R_est, R_gt, symmetries)


def _as_record(r: Any, i: int) -> Record:
    if isinstance(r, Record):
        return r
    if isinstance(r, Mapping):
        missing = [k for k in ("obj", "pred_obj", "R_gt", "R_est") if k not in r]
        if missing:
            raise ValueError(f"record {i}: missing keys {missing} (expected obj, pred_obj, R_gt, R_est "
                             "and optionally symmetries, query_id)")
        return Record(str(r["obj"]), str(r["pred_obj"]), np.asarray(r["R_gt"]), np.asarray(r["R_est"]),
                      r.get("symmetries"), r.get("query_id"))
    raise TypeError(f"record {i}: expected a Record or a mapping, got {type(r).__name__}")


def rotation_text(R: np.ndarray) -> str:
    """A (3, 3) rotation as 9 space-separated numbers, row-major (a per-query CSV cell)."""
    return " ".join(f"{x:.6f}" for x in np.asarray(R, dtype=np.float64).reshape(-1))


def rotations_from_text(cells: Iterable[str]) -> np.ndarray:
    """(N, 3, 3) rotations from :func:`rotation_text` cells."""
    out = [np.array(str(c).split(), dtype=np.float64) for c in cells]
    bad = [i for i, r in enumerate(out) if r.size != 9]
    if bad:
        raise ValueError(f"rotations_from_text: rows {bad[:5]} do not hold 9 numbers")
    return np.stack(out).reshape(-1, 3, 3) if out else np.zeros((0, 3, 3))


def per_query_table(records: Iterable[Record | Mapping], threshold_deg: float = 30.0) -> pd.DataFrame:
    """One row per query: obj, pred_obj, query_id, class_ok, err_deg, rot_ok, R_est, R_gt.

    ``err_deg`` compares R_est with R_gt under the TRUE object's symmetries,
    whether or not the predicted object is right. ``R_est`` and ``R_gt`` keep both
    rotations (:func:`rotation_text`), so a table can be scored again under other
    symmetries without a new search (:func:`rescore`).
    """
    recs = [_as_record(r, i) for i, r in enumerate(records)]
    if not recs:
        raise ValueError("evaluate: no records given")
    errs = np.empty(len(recs))
    # Group by symmetry set so each group is one vectorised call.
    groups: dict[int, list[int]] = {}
    for i, r in enumerate(recs):
        groups.setdefault(id(r.symmetries) if r.symmetries is not None else 0, []).append(i)
    for idx in groups.values():
        sym = recs[idx[0]].symmetries
        errs[idx] = rotation_errors_deg(np.stack([recs[i].R_est for i in idx]),
                                        np.stack([recs[i].R_gt for i in idx]), sym)
    df = pd.DataFrame({"obj": [r.obj for r in recs], "pred_obj": [r.pred_obj for r in recs],
                       "query_id": [r.query_id for r in recs]})
    df["class_ok"] = df["obj"] == df["pred_obj"]
    df["err_deg"] = errs
    df["rot_ok"] = df["class_ok"] & (df["err_deg"] < threshold_deg)
    df["R_est"] = [rotation_text(r.R_est) for r in recs]
    df["R_gt"] = [rotation_text(r.R_gt) for r in recs]
    return df


def rescore(per_query: pd.DataFrame, groups: Mapping[str, Any], threshold_deg: float = 30.0) -> pd.DataFrame:
    """A per-query table scored again from its own R_est / R_gt columns under ``groups``
    (true object name -> its symmetry group, as :attr:`ObjectViews.symmetries`; absent: none).

    Returns a copy with ``err_deg`` and ``rot_ok`` recomputed; ``class_ok`` is kept.
    """
    missing = [c for c in ("obj", "class_ok", "R_est", "R_gt") if c not in per_query.columns]
    if missing:
        raise ValueError(f"rescore: the table lacks columns {missing} (tables written before the rotations "
                         "were kept need a new search)")
    out = per_query.copy()
    R_est, R_gt = rotations_from_text(out["R_est"]), rotations_from_text(out["R_gt"])
    err = np.empty(len(out))
    for obj, idx in out.groupby("obj", sort=False).indices.items():
        err[idx] = rotation_errors_deg(R_est[idx], R_gt[idx], groups.get(obj))
    out["err_deg"] = err
    out["rot_ok"] = out["class_ok"].astype(bool) & (out["err_deg"] < threshold_deg)
    return out


def evaluate_predictions(records: Iterable[Record | Mapping], threshold_deg: float = 30.0
                         ) -> tuple[pd.DataFrame, dict[str, float]]:
    """Per-object accuracies and their unweighted means.

    Args:
        records: :class:`Record` objects or mappings with the same keys.
        threshold_deg: rotation-accuracy threshold, degrees (strict ``<``).

    Returns:
        per_object: DataFrame indexed by object name (sorted) with columns
            n (queries), class_acc (%), rot_acc (%: class right AND error <
            threshold), median_err_deg and mean_err_deg. The error statistics
            are over ALL queries of the object, using R_est even when the
            predicted class is wrong (then it is the rotation of the wrong
            object's reference, compared with the true object's pose under the
            true object's symmetries): they describe pose quality
            independently of classification.
        means: the same quantities averaged over objects (unweighted), plus
            n_objects and n_queries.
    """
    return summarise_queries(per_query_table(records, threshold_deg))


def summarise_queries(per_query: pd.DataFrame) -> tuple[pd.DataFrame, dict[str, float]]:
    """Per-object table and unweighted means from a :func:`per_query_table` frame."""
    g = per_query.groupby("obj", sort=True)
    per_object = pd.DataFrame({
        "n": g.size(),
        "class_acc": 100.0 * g["class_ok"].mean(),
        "rot_acc": 100.0 * g["rot_ok"].mean(),
        "median_err_deg": g["err_deg"].median(),
        "mean_err_deg": g["err_deg"].mean(),
    })[list(PER_OBJECT_COLUMNS)]
    per_object.index.name = "obj"
    return per_object, _means(per_object)


def _means(per_object: pd.DataFrame) -> dict[str, float]:
    means = {c: float(per_object[c].mean()) for c in PER_OBJECT_COLUMNS if c != "n"}
    means["n_objects"] = int(len(per_object))
    means["n_queries"] = int(per_object["n"].sum())
    return means


def group_by_split(per_object: pd.DataFrame, split_of: Mapping[str, str]) -> pd.DataFrame:
    """Unweighted means of the per-object table within each split.

    Args:
        per_object: output of :func:`evaluate_predictions`.
        split_of: object name -> split label (e.g. ``"seen"``/``"unseen"`` or
            ``"split1"``). Every object in the table must be mapped.

    Returns:
        DataFrame indexed by split label (sorted) with the mean class_acc,
        rot_acc, median_err_deg, mean_err_deg over that split's objects, plus
        n_objects and n_queries.
    """
    missing = sorted(set(per_object.index) - set(split_of))
    if missing:
        raise ValueError(f"group_by_split: split_of has no entry for objects {missing}")
    rows = {}
    labels = per_object.index.map(lambda o: split_of[o])
    for label, sub in per_object.groupby(labels, sort=True):
        rows[label] = _means(sub)
    out = pd.DataFrame.from_dict(rows, orient="index")
    out.index.name = "split"
    return out


def chance_levels(n_objects: int, threshold_deg: float = 30.0) -> dict[str, float]:
    """Accuracy (%) of guessing: class uniformly, rotation Haar-uniformly.

    P(angle < t) for a Haar rotation is (t - sin t) / pi.
    """
    t = np.radians(threshold_deg)
    p_rot = (t - np.sin(t)) / np.pi
    return {"class_acc": 100.0 / n_objects, "rot_acc": 100.0 * p_rot / n_objects}


def agreement_within(greedy: list, fast: list, threshold_deg: float = 30.0, seed: int = 0) -> dict:
    """Share of queries on which ``fast`` predicts greedy's object and a rotation within
    ``threshold_deg`` of greedy's (symmetry-aware), with a bootstrap 95 % interval over queries.

    Both are lists of :class:`helpers.evaluation.metrics.Record` for the same queries, in order.
    """
    ok = np.array([a.pred_obj == b.pred_obj and
                   float(symmetric_geodesic_deg(a.R_est[None], b.R_est[None], a.symmetries if a.pred_obj == a.obj
                                                else None)[0]) < threshold_deg
                   for a, b in zip(greedy, fast)], dtype=float)
    return share_ci(ok, seed)
