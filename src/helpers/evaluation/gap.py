"""The account of the gap to the paper: measured, paired steps on one set of queries (notebook 11).

Each step is a per-query table of the same unseen queries (same model), one protocol change away from the
previous one; a step's effect is the paired difference of Rota. Acc. (points, 95 % bootstrap interval over
queries, :func:`helpers.evaluation.stats.paired_difference`). What lies between the last measured step and the
paper's number is reported as *not measured*, never guessed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from .stats import accuracy_ci, direction_verdict, paired_difference


@dataclass(frozen=True)
class Step:
    """One protocol change: ``id`` (short, for claims), ``label`` (for the table and chart), ``table``."""

    id: str
    label: str
    table: pd.DataFrame


def check_same_queries(steps: list[Step]) -> None:
    """Raise ValueError naming the step whose queries differ from the first step's (ids and objects)."""
    ref = steps[0].table.sort_values("query_id")[["obj", "query_id"]].reset_index(drop=True)
    for s in steps[1:]:
        got = s.table.sort_values("query_id")[["obj", "query_id"]].reset_index(drop=True)
        if not got.equals(ref):
            raise ValueError(f"gap account: step {s.id!r} holds other queries than step {steps[0].id!r} "
                             f"({len(got)} vs {len(ref)} rows): every step must answer the same queries")


def account(steps: list[Step], paper_value: float | None, seed: int = 0) -> pd.DataFrame:
    """One row per step: Rota. Acc. with its interval, the change from the previous step (paired, points) with
    its interval and verdict, then (with ``paper_value``) a last row for what is not measured.

    Columns: step, label, rot_acc, ci95_lo, ci95_hi, change_pts, change_lo, change_hi, verdict.
    """
    if not steps:
        raise ValueError("gap account: no steps")
    check_same_queries(steps)
    rows: list[dict[str, Any]] = []
    for i, s in enumerate(steps):
        acc, (lo, hi) = accuracy_ci(s.table, seed=seed)
        row = {"step": s.id, "label": s.label, "rot_acc": acc, "ci95_lo": lo, "ci95_hi": hi,
               "change_pts": np.nan, "change_lo": np.nan, "change_hi": np.nan, "verdict": "measured"}
        if i:
            d = paired_difference(steps[i - 1].table, s.table, seed=seed)
            row.update(change_pts=d["diff_pts"], change_lo=d["ci"][0], change_hi=d["ci"][1],
                       verdict=direction_verdict(d["ci"]))
        rows.append(row)
    if paper_value is not None:
        rows.append({"step": "not_measured", "label": "not measured here (to the paper's number)",
                     "rot_acc": paper_value, "ci95_lo": np.nan, "ci95_hi": np.nan,
                     "change_pts": paper_value - rows[-1]["rot_acc"], "change_lo": np.nan, "change_hi": np.nan,
                     "verdict": "not measured"})
    return pd.DataFrame(rows)


def symmetry_groups(names: list[str], group_of: Mapping[str, Any]) -> dict[str, Any]:
    """The groups of ``names`` that declare a symmetry (a group of only the identity is left out)."""
    out = {}
    for n in names:
        g = group_of.get(n)
        if g is not None and (not isinstance(g, np.ndarray) or len(g) > 1):
            out[n] = g
    return out
