"""Notebook 14: extra training objects (issue #44, screen e; an extension beyond the paper). Unseen-object accuracy
against N extra training meshes, decided on extra meshes kept out of training; the split's unseen test accuracy is
reported afterwards."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from ...data.extra_objects import load_extras
from ...data.manifest import ManifestError
from ...evaluation.claims import screen_claims
from ..parameter_rules import param_error
from ..report_format import ablation_section, claim_line, load_json, md_table
from .base import Experiment
from .training_screens import check_arms

TITLE = "Extra training objects (issue #44, screen e; an extension beyond the paper, never in Table 1)"


def check(notebook: str, P: dict[str, Any]) -> None:
    """The arms as notebook 12's; the validation extras exist and are not more than the extras file keeps."""
    check_arms(notebook, P)
    try:
        n_val = len(load_extras().validation)
    except ManifestError as e:
        raise param_error(notebook, "extra_val_objects", f"validation meshes from the extras file ({e})",
                          P["extra_val_objects"]) from None
    if not 1 <= P["extra_val_objects"] <= n_val:
        raise param_error(notebook, "extra_val_objects", f"an int in 1..{n_val} (the extras file's validation "
                          "meshes)", P["extra_val_objects"])
    for name in ("extra_val_references", "extra_val_queries"):
        if P[name] < 1:
            raise param_error(notebook, name, "an int >= 1", P[name])


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    """The curve over N (validation extras, then the unseen test afterwards), each arm's verdict against N = 0."""
    out = ablation_section(d, TITLE, "extra_objects.png", "no such experiment (the paper trains on the split's "
                           "seen LineMOD objects only); an arm adds the first N extra meshes and is kept only where "
                           "it beats N = 0 on the validation extras (meshes never trained on) by more than its "
                           "interval and the seed spread")
    m = load_json(d / "metrics.json")
    if not m or not (d / "curve.csv").exists():
        return out
    out += [f"The curve ({m['measured_on']}; afterwards: {m['afterwards_measured_on']}):", "",
            md_table(pd.read_csv(d / "curve.csv")), ""]  # the CSV keeps the columns in reading order
    for cid in sorted(k for k in claims if k.startswith("extra_unseen:")):
        out += claim_line(claims, cid, claims[cid]["claim"].split(" (")[0])
    return out + [""]


EXPERIMENT = Experiment("14_extra_objects", "unseen-object accuracy against N extra training objects, decided on "
                        "extra meshes kept out of training (not in the paper)",
                        claims=lambda d: screen_claims(d, prefix="extra"), section=section, check=check,
                        headline=(("extra:*", "Extra training objects (validation extras):"),))
