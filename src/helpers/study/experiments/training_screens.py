"""Notebook 12: training-regime screens, each arm a changed recipe against the current one (issue #44), decided
on held-out views of the split's SEEN objects; the unseen test accuracy is reported afterwards."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from ...evaluation.claims import screen_claims
from ..parameter_rules import check_model_choice, param_error, zoo_entries
from ..report_format import ablation_section, claim_line, load_json, md_table
from .base import Experiment

TITLE = "Training-regime screens (issue #44; not in the paper)"


def check(notebook: str, P: dict[str, Any]) -> None:
    """Baseline and arms name zoo models of the split (the baseline of the notebook's crop size; an arm may take
    another side: screen c, scored on the same views rendered at its side); arm labels are distinct."""
    check_arms(notebook, P, arms_any_side=True)
    if P["screen_queries"] < 1:
        raise param_error(notebook, "screen_queries", "an int >= 1", P["screen_queries"])


def check_arms(notebook: str, P: dict[str, Any], arms_any_side: bool = False) -> None:
    """``baseline`` and ``arms`` ([label, zoo model per seed...]) name zoo models of ``split`` at ``image_size``
    (``arms_any_side``: the arms' models at any side), with distinct labels other than 'current' (notebooks 12
    and 14)."""
    if not P["baseline"]:
        raise param_error(notebook, "baseline", "a non-empty list of zoo models (one per seed)", P["baseline"])
    labels = []
    for a in P["arms"]:
        if not (isinstance(a, list) and len(a) >= 2 and all(isinstance(x, str) for x in a)):
            raise param_error(notebook, "arms", "a list of [label, zoo model, ...] lists (one model per seed)",
                              P["arms"])
        labels.append(a[0])
    if len(set(labels)) != len(labels) or "current" in labels:
        raise param_error(notebook, "arms", "distinct labels other than 'current'", labels)
    zoo = zoo_entries()
    # (model, the side it must take): the baseline's is the data's; an arm's may be its own (screen c)
    named = [(n, P["image_size"]) for n in P["baseline"]]
    named += [(n, int(zoo[n]["data"]["image_size"]) if arms_any_side and n in zoo else P["image_size"])
              for a in P["arms"] for n in a[1:]]
    for name, side in named:
        check_model_choice(notebook, "baseline/arms", name, side)
        if name not in zoo:  # a checkpoint file: the screens read each model's recipe from its zoo entry
            raise param_error(notebook, "baseline/arms", f"zoo model names (their recipes are compared), among "
                              f"{sorted(zoo)}", name)
        if int(zoo[name]["split"]) != P["split"]:
            raise param_error(notebook, "baseline/arms", f"zoo models trained on split {P['split']} "
                              f"({name} is split {zoo[name]['split']})", name)


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    """The screens' table and verdicts (held-out views of seen objects) and the unseen numbers afterwards."""
    out = ablation_section(d, TITLE, "screens.png", "no such experiment (the paper trains one recipe); each arm "
                           "is one change of the current recipe, kept only where it beats the current one on "
                           "held-out views of SEEN objects by more than its interval and the seed spread")
    m = load_json(d / "metrics.json")
    if not m or "changes" not in m:
        return out
    out += ["What each arm changes:", "", *[f"- `{k}`: {v}" for k, v in m["changes"].items()], ""]
    if (d / "afterwards.csv").exists():
        out += ["Afterwards, never used to choose: the same models on the split's unseen test objects "
                f"({m['afterwards_measured_on']}):", "", md_table(pd.read_csv(d / "afterwards.csv")), ""]
        for cid in sorted(k for k in claims if k.startswith("screen_unseen:")):
            out += claim_line(claims, cid, claims[cid]["claim"].split(" (")[0])
        out.append("")
    return out


EXPERIMENT = Experiment("12_training_screens", "training-regime screens against the current recipe, decided on "
                        "held-out views of seen objects (not in the paper)", claims=screen_claims, section=section,
                        check=check,
                        headline=(("screen:*", "Training screen (held-out views of seen objects):"),))
