"""What one experiment (one notebook) contributes to the study besides its cells."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: Reads a notebook's output folder into claim records (:func:`helpers.evaluation.claims.record`).
ClaimsReader = Callable[[Path], list[dict]]
#: Writes the notebook's REPORT.md section (Markdown lines) from its output folder and the claims by id.
SectionWriter = Callable[[Path, dict[str, dict]], list[str]]
#: Checks the notebook's own parameter values (raises :class:`helpers.study.parameter_rules.ParameterError`).
ParameterCheck = Callable[[str, dict[str, Any]], None]


@dataclass(frozen=True)
class Experiment:
    """One notebook's place in the study.

    Attributes:
        notebook: the notebook's name without ``.ipynb`` (its output folder under ``reports/<preset>/``).
        question: what it measures, one line (the README's and the registry test's listing).
        claims: its claims from its output folder, or None (it writes none).
        section: its REPORT.md section, or None (it has none).
        check: checks of parameter values only this notebook has, or None.
        headline: the README's headline lines it contributes, as (claim id, label) pairs
            (:mod:`helpers.study.cli.readme` writes each from ``reports/quick/claims.json``; absent claims are skipped).
    """

    notebook: str
    question: str
    claims: ClaimsReader | None = None
    section: SectionWriter | None = None
    check: ParameterCheck | None = None
    headline: tuple[tuple[str, str], ...] = ()
