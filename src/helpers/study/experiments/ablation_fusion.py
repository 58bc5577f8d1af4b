"""Notebook 05: how the per-level similarities are fused (Avg, Sigmoid, Softmax, adaptive; paper Fig. 6a)."""

from __future__ import annotations

from typing import Any

from ...evaluation import paper
from ...evaluation.claims import ablation_claims
from ..parameter_rules import FUSIONS, param_error
from ..report_format import ablation_section
from .base import Experiment

#: The paper's trend, as its Fig. 6a reports it.
PAPER_TREND = "Avg 80.9 < Sigmoid 88.57 < Softmax 89.03 < adaptive 89.55 (split #1 unseen)"


def check(notebook: str, P: dict[str, Any]) -> None:
    """Every variant is a fusion."""
    bad = [v for v in P.get("variants", []) if v not in FUSIONS]
    if bad:
        raise param_error(notebook, "variants", f"fusions among {list(FUSIONS)}; bad: {bad}", P["variants"])


EXPERIMENT = Experiment(
    "05_ablation_fusion", "ablation: Avg / Sigmoid / Softmax / adaptive fusion (paper Fig. 6a)",
    claims=lambda d: ablation_claims(d, "fusion", paper.FUSION_SPLIT1),
    section=lambda d, claims: ablation_section(d, "Fusion (paper Fig. 6a)", "fusion.png", PAPER_TREND),
    check=check,
    headline=(("fusion:adaptive_beats_avg", "Adaptive minus Avg fusion (split #1)"),))
