"""Notebook 08: local normalisation and the weighted loss, each switched off and both (paper Table 5)."""

from __future__ import annotations

from ...evaluation import paper
from ...evaluation.claims import ablation_claims
from ..report_format import ablation_section
from .base import Experiment

#: The paper's trend, as its Table 5 reports it.
PAPER_TREND = "neither 85.91 < weighted loss 87.14 < local norm 89.25 < both 89.55 (split #1 unseen)"

EXPERIMENT = Experiment(
    "08_components", "ablation: local normalisation and the weighted loss (paper Table 5)",
    claims=lambda d: ablation_claims(
        d, "components", {paper.component_label(ln, wl): v for (ln, wl), v in paper.COMPONENTS_SPLIT1.items()}),
    section=lambda d, claims: ablation_section(d, "Components (paper Table 5)", "components.png", PAPER_TREND),
    headline=(("components:both_beats_neither",
               "Local normalisation and weighted loss, both minus neither (split #1)"),))
