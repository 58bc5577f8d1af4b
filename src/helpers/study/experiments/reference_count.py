"""Notebook 06: accuracy against the number of references per object, greedy and fast (paper Fig. 7)."""

from __future__ import annotations

from pathlib import Path

from ...evaluation import paper
from ...evaluation.claims import reference_count_claims
from ..report_format import ablation_section, claim_line
from .base import Experiment


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    """The reference-count table (greedy and fast), its figure and each step's paired claim."""
    out = ablation_section(d, "Number of references (paper Fig. 7)", "reference_count.png",
                           paper.REFERENCE_COUNT_CLAIM)
    steps = sorted((c for k, c in claims.items() if k.startswith("refcount_step")), key=lambda c: c["id"])
    if steps:
        out += ["Each step up in count, paired on the same queries:", ""]
        for c in steps:
            out += claim_line(claims, c["id"], c["claim"].split(" (")[0])
        out.append("")
    return out


EXPERIMENT = Experiment("06_reference_count", "accuracy against references per object, greedy and fast (paper Fig. 7)",
                        claims=reference_count_claims, section=section,
                        headline=(("refcount_accuracy_rises",
                                   "Greedy accuracy, fewest to most references per object (split #1)"),))
