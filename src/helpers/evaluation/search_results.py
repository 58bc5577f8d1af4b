"""Notebook 07's results (fast retrieval vs greedy search), typed: the notebook writes them through
:meth:`SearchComparison.save`, the claims and the report read them through :meth:`SearchComparison.load`.

Files in the notebook's folder: ``metrics.json`` (every field below but the per-query tables),
``fast_vs_greedy.csv/.md`` (the table) and ``per_query_<stem>.csv`` per search (:func:`stem_of`):
``obj``, ``query_id``, ``rot_ok``, ``class_ok``, ``err_deg``... and ``seconds`` (wall seconds of
that query's search, its share of a batched anchor stage included).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..core.fileio import atomic_write_json, atomic_write_text, write_table
from .stats import ratio_of_medians_ci

#: The rows every run has, and the optional coarse-to-fine rows (ours) by file stem.
GREEDY_ROW, FAST_ROW = "greedy", "fast (converge)"
C2F_ROWS = {"c2f": "coarse-to-fine (converge)", "c2f_halving": "coarse-to-fine halving (converge)"}
#: c2f file stem -> its family in the coarse-to-fine selection (helpers.search.c2f_select.FAMILIES).
C2F_FAMILIES = {"c2f": "one cut", "c2f_halving": "halving"}
#: search row -> file stem of its per-query table.
STEMS = {GREEDY_ROW: "greedy", FAST_ROW: "fast", **{row: stem for stem, row in C2F_ROWS.items()}}


def variant_row(k_ac: int, fps_k: int) -> str:
    """Row name of a named fast-retrieval budget (notebook 07's ``fast_variants``)."""
    return f"fast (k_ac {int(k_ac)}, fps_k {int(fps_k)})"


def stem_of(row: str) -> str | None:
    """File stem of a row's per-query table: :data:`STEMS`, ``fast_k<K>_f<F>`` for a named budget, else None."""
    if row in STEMS:
        return STEMS[row]
    parts = row.removeprefix("fast (k_ac ").removesuffix(")").split(", fps_k ")
    if row.startswith("fast (k_ac ") and len(parts) == 2 and all(p.isdigit() for p in parts):
        return f"fast_k{parts[0]}_f{parts[1]}"
    return None


@dataclass
class SearchComparison:
    """What notebook 07 measured on one set of unseen queries.

    Attributes:
        table: one row per search (``method`` is its row name): unseen rot_acc / class_acc (%),
            median and mean s/query, mean comparisons/query, the paper's Table 4 numbers.
        per_query: row name -> per-query table with a ``seconds`` column (rows of :data:`STEMS`).
        agreement_with_greedy: row -> share of queries retrieving greedy's very reference.
        agreement_30deg: row -> {"share", "ci95", "n"}: greedy's object and a rotation within 30 deg.
        c2f_agreement_with_fast: c2f row -> share of queries retrieving fast retrieval's reference.
        c2f_selection: {"rule", "min_agreement", "chosen": family -> settings, "candidates": [...]}.
        bank: {"objects", "refs_per_object", "k_ac"}; device: where it ran; n_queries: queries.
    """

    table: pd.DataFrame
    per_query: dict[str, pd.DataFrame]
    agreement_with_greedy: dict[str, float]
    agreement_30deg: dict[str, dict]
    c2f_agreement_with_fast: dict[str, float] = field(default_factory=dict)
    c2f_selection: dict[str, Any] = field(default_factory=dict)
    bank: dict[str, int] = field(default_factory=dict)
    device: str = "cpu"
    n_queries: int = 0

    def __post_init__(self) -> None:
        rows = list(self.table["method"])
        if rows[:1] != [GREEDY_ROW] or FAST_ROW not in rows:
            raise ValueError(f"SearchComparison: the table's first row must be {GREEDY_ROW!r} and it must hold "
                             f"{FAST_ROW!r}; got {rows}")
        unnamed = [r for r in self.per_query if stem_of(r) is None]
        if unnamed:
            raise ValueError(f"SearchComparison: rows without a per-query file name: {unnamed}")
        missing = [r for r in self.per_query if "seconds" not in self.per_query[r].columns]
        if missing:
            raise ValueError(f"SearchComparison: per-query tables without a 'seconds' column: {missing}")

    def median_seconds(self, row: str) -> float:
        return float(self.table.loc[self.table["method"] == row, "median s/query"].iloc[0])

    def speedup(self, slow: str, fast: str) -> dict[str, Any]:
        """median seconds of ``slow`` / median seconds of ``fast`` on the same queries, with a paired
        bootstrap 95 % interval: {"ratio", "ci"}."""
        m = self.per_query[slow][["query_id", "seconds"]].merge(self.per_query[fast][["query_id", "seconds"]],
                                                                on="query_id", suffixes=("_s", "_f"))
        return ratio_of_medians_ci(m["seconds_s"].to_numpy(), m["seconds_f"].to_numpy())

    def save(self, out_dir: str | Path) -> Path:
        """Write the table, the per-query tables and ``metrics.json`` into ``out_dir``; returns the JSON's path."""
        out = Path(out_dir)
        write_table(self.table, out / "fast_vs_greedy")
        for row, pq in self.per_query.items():
            atomic_write_text(out / f"per_query_{stem_of(row)}.csv", pq.to_csv(index=False))
        meta = {"table": self.table.to_dict(orient="records"), "per_query_files": {r: f"per_query_{stem_of(r)}.csv"
                                                                                  for r in self.per_query},
                "agreement_with_greedy": self.agreement_with_greedy, "agreement_30deg": self.agreement_30deg,
                "c2f_agreement_with_fast": self.c2f_agreement_with_fast, "c2f_selection": self.c2f_selection,
                "bank": self.bank, "device": self.device, "n_queries": self.n_queries}
        return atomic_write_json(out / "metrics.json", meta)

    @classmethod
    def load(cls, d: str | Path) -> SearchComparison | None:
        """The results in folder ``d`` (None when notebook 07 has not written them)."""
        d = Path(d)
        if not (d / "metrics.json").exists():
            return None
        m = json.loads((d / "metrics.json").read_text())
        per_query = {row: pd.read_csv(d / f) for row, f in m["per_query_files"].items()}
        return cls(pd.DataFrame(m["table"]), per_query, m["agreement_with_greedy"], m["agreement_30deg"],
                   m["c2f_agreement_with_fast"], m["c2f_selection"], m["bank"], m["device"], m["n_queries"])


def with_seconds(per_query: pd.DataFrame, preds: list) -> pd.DataFrame:
    """A per-query table with each prediction's wall ``seconds`` (same order) added."""
    if len(per_query) != len(preds):
        raise ValueError(f"with_seconds: {len(per_query)} queries but {len(preds)} predictions")
    return per_query.assign(seconds=np.array([p.seconds for p in preds], dtype=float))
