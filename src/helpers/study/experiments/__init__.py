"""The study's experiments: one module per notebook, listed here in notebook order.

Each module holds what is specific to its notebook besides its cells: the parameter checks only it
needs, the claims it contributes (readers of its result files, :mod:`helpers.evaluation.claims`) and its
REPORT.md section. The runner, the parameter checks, the claims and the report loop over
:data:`REGISTRY`; a new experiment is one notebook, one module here (added to the list) and its presets.
"""

from __future__ import annotations

import json
from pathlib import Path

from ...core.fileio import atomic_write_text
from ...evaluation.claims import StaleResults
from . import (ablation_fusion, ablation_scales, budget, components, evaluate, explore, extra_objects, fast_vs_greedy,
               gap, reference_count, render, tless, train, training_screens)
from .base import Experiment

REGISTRY: tuple[Experiment, ...] = tuple(m.EXPERIMENT for m in (
    render, train, evaluate, ablation_scales, ablation_fusion, reference_count, fast_vs_greedy, components, tless,
    explore, gap, training_screens, budget, extra_objects))


def experiment(notebook: str) -> Experiment | None:
    """The experiment of ``notebook`` (its name without ``.ipynb``), or None when none is registered."""
    return next((e for e in REGISTRY if e.notebook == notebook), None)


def claims_by_section(base: Path) -> tuple[list[dict], dict[str, str]]:
    """(claims of every notebook folder under ``base`` whose files this code reads, {folder: why not} for the
    folders written by another version of the code: rerun those notebooks)."""
    out: list[dict] = []
    stale: dict[str, str] = {}
    for e in REGISTRY:
        if e.claims is None:
            continue
        try:
            out += e.claims(Path(base) / e.notebook)
        except (KeyError, TypeError, ValueError) as err:  # a missing key, an old verdict word, an old layout
            stale[e.notebook] = (f"{Path(base) / e.notebook}: its files were written by another version of the code "
                                 f"({type(err).__name__}: {err}); rerun notebook {e.notebook}")
    return out, stale


def build_claims(base: Path) -> list[dict]:
    """Every claim computable from the notebook outputs under ``base`` (reports/<preset>); a folder this code
    cannot read is a :class:`helpers.evaluation.claims.StaleResults` error naming it and the notebook to rerun."""
    claims, stale = claims_by_section(base)
    if stale:
        raise StaleResults("; ".join(stale.values()))
    return claims


def write_claims(base: Path, claims: list[dict] | None = None) -> Path:
    """Write ``base/claims.json`` (a JSON list of claim records: ``claims`` or :func:`build_claims`)."""
    path = Path(base) / "claims.json"
    atomic_write_text(path, json.dumps(build_claims(base) if claims is None else claims, indent=1) + "\n")
    return path
