"""Notebook 11: the gap to the paper, step by step (paired changes on one split's unseen queries)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ...evaluation.claims import gap_claims
from ..report_format import load_json, md_table
from .base import Experiment

#: Column order of the every-split table (its metrics.json stores records with sorted keys).
ALL_SPLITS_COLUMNS = ["answers", "splits", "rot_acc, no symmetries", "rot_acc, declared symmetries", "change_pts",
                      "change_lo", "change_hi", "verdict"]


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    """The gap account's steps, waterfall and the symmetry step on every split."""
    m = load_json(d / "metrics.json")
    title = "## 11 · The gap to the paper, step by step"
    if not m:
        return [title, "", "_not run_", ""]
    steps = pd.DataFrame(m["steps"])[["label", "rot_acc", "ci95_lo", "ci95_hi", "change_pts", "change_lo",
                                      "change_hi", "verdict"]]
    return [title, "", f"Split #{m['split']} unseen queries, one model ({m['setup']['models']}, zoo_steps "
            f"{m['setup']['zoo_steps']}), each step a paired change on the same queries; the last row is the paper's "
            f"number minus the last measured step: **not measured** here. Objects with declared symmetries: "
            f"{', '.join(m['symmetric_objects']) or 'none'}.", "", md_table(steps), "",
            f"![waterfall]({d.name}/gap_waterfall.png)", "", "Notebook 03's answers on every split, without and with "
            "the declared symmetries:", "", md_table(pd.DataFrame(m["all_splits"])[ALL_SPLITS_COLUMNS]), ""]


EXPERIMENT = Experiment("11_gap_to_paper", "the gap to the paper's number, one paired step at a time",
                        claims=gap_claims, section=section,
                        headline=(("gap:dense_references:rot_acc",
                                   "Split #1 after every measured step toward the paper (greedy, 2,048 references)"),))
