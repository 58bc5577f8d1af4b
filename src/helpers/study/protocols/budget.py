"""The training budget compared on test queries (notebook 13): each split's shorter- and longer-budget zoo models
answer the same unseen and seen test queries with the same references and search, paired per query.

It reports, it does not select: the zoo's budget was chosen on held-out views of seen objects before this ran.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from ...core.configs import SearchConfig
from ...core.fileio import atomic_write_text, write_table
from ..pipeline import StudyData
from ..zoo import entry, load
from .linemod import evaluate_split, split_tables

#: The files :func:`write_budget` writes (and removes when no pair ran, so an earlier run's cannot enter the claims).
BUDGET_FILES = ("per_query_budget.csv", "budget_splits.csv", "budget_splits.md")


@dataclass
class BudgetPair:
    """One split's two zoo models: the shorter budget first. ``steps``: optimiser steps of each."""

    split: int
    names: tuple[str, str]
    steps: tuple[int, int]
    models: tuple[Any, Any]


def budget_models(budgets: list[list[str]], device: str = "auto") -> list[BudgetPair]:
    """Load each [shorter, longer] pair of zoo models (sha256 checked) with its split and steps from zoo.yaml."""
    pairs = []
    for short, long in budgets:
        e = (entry(short), entry(long))
        pairs.append(BudgetPair(int(e[0]["split"]), (short, long), (int(e[0]["steps"]), int(e[1]["steps"])),
                                (load(short, device=device)[0], load(long, device=device)[0])))
    return pairs


def pairs_table(pairs: list[BudgetPair]) -> pd.DataFrame:
    """One row per split: the two models and their steps."""
    return pd.DataFrame([{"split": f"#{p.split}", "shorter": p.names[0], "shorter steps": p.steps[0],
                          "longer": p.names[1], "longer steps": p.steps[1]} for p in pairs])


def budget_per_query(pairs: list[BudgetPair], data: StudyData, search: SearchConfig, seen_queries: int = 0,
                     device: str = "auto") -> pd.DataFrame:
    """Both budgets of every pair on the split's unseen and seen test queries (``seen_queries`` per seen object,
    0: all): the per-query table of :func:`helpers.study.protocols.linemod.split_tables` with ``budget``
    ("shorter" / "longer"), ``steps``, ``model`` and ``search`` columns."""
    tables = []
    for p in pairs:
        for which, name, steps, model in zip(("shorter", "longer"), p.names, p.steps, p.models):
            res = evaluate_split(model, data, p.split, search, seen_queries=seen_queries, parts=("unseen", "seen"),
                                 device=device)
            tables.append(split_tables({p.split: res})[1].assign(budget=which, steps=steps, model=name,
                                                                 search=search.method))
    return pd.concat(tables, ignore_index=True)


def budget_table(per_query: pd.DataFrame) -> pd.DataFrame:
    """Rota. Acc. (%, per object then over objects) per split, part and budget: one row per split."""
    rows = []
    for s, g in per_query.groupby("split", sort=True):
        row: dict[str, Any] = {"split": f"#{s}"}
        for part in ("unseen", "seen"):
            for which in ("shorter", "longer"):
                q = g[(g["part"] == part) & (g["budget"] == which)]
                if len(q):
                    steps = int(q["steps"].iloc[0])
                    row[f"{part} rot_acc, {steps} steps"] = 100.0 * q.groupby("obj")["rot_ok"].mean().mean()
        rows.append(row)
    return pd.DataFrame(rows)


def write_budget(out: str | os.PathLike, per_query: pd.DataFrame | None) -> pd.DataFrame | None:
    """Write ``per_query_budget.csv`` and ``budget_splits.csv/.md`` under ``out`` (their table returned); with
    no pairs (``per_query`` None) remove an earlier run's files instead and return None."""
    out = Path(out)
    if per_query is None:
        for f in BUDGET_FILES:
            (out / f).unlink(missing_ok=True)
        return None
    atomic_write_text(out / "per_query_budget.csv", per_query.to_csv(index=False))
    table = budget_table(per_query)
    write_table(table, out / "budget_splits")
    return table
