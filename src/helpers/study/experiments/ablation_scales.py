"""Notebook 04: which feature levels (global, single levels, all three) carry the accuracy (paper Fig. 5a)."""

from __future__ import annotations

from typing import Any

from ...evaluation import paper
from ...evaluation.claims import ablation_claims
from ..parameter_rules import param_error, scales_ok
from ..report_format import ablation_section
from .base import Experiment


def check(notebook: str, P: dict[str, Any]) -> None:
    """Every variant is a scale set."""
    bad = [v for v in P.get("variants", []) if not scales_ok(v)]
    if bad:
        raise param_error(notebook, "variants", f"scale sets ('global' or comma lists of 32/16/13); bad: {bad}",
                          P["variants"])


EXPERIMENT = Experiment(
    "04_ablation_scales", "ablation: global vs single feature levels vs all three (paper Fig. 5a)",
    claims=lambda d: ablation_claims(d, "scales"),
    section=lambda d, claims: ablation_section(d, "Scales (paper Fig. 5a)", "scales.png", paper.SCALES_CLAIM),
    check=check,
    headline=(("scales:multi_scale_beats_global", "Multi-scale minus a global descriptor (split #1)"),
              ("scales:multi_scale_beats_32", "Multi-scale minus the finest level alone (split #1)")))
