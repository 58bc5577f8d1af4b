"""Notebook 13: the training budget, the zoo's shorter- and longer-budget models of each split on the same test
queries (unseen and seen objects), paired. It reports; the budget was chosen on held-out views of seen objects."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from ...evaluation.claims import budget_claims
from ..parameter_rules import check_model_choice, param_error, zoo_entries
from ..report_format import claim_line, md_table
from .base import Experiment


#: The training fields that set a budget; a pair may differ in these and nothing else.
BUDGET_FIELDS = ("epochs", "steps_per_epoch")


def _recipe(e: dict) -> dict:
    """A zoo entry's recipe without its budget: data, seen objects, every training field but :data:`BUDGET_FIELDS`."""
    return {"data": e.get("data"), "seen_objects": e.get("seen_objects"),
            **{f"train.{k}": v for k, v in e.get("train", {}).items() if k not in BUDGET_FIELDS}}


def check(notebook: str, P: dict[str, Any]) -> None:
    """``budgets``: [shorter, longer] pairs of zoo models of the crop size, each pair one split and one recipe at
    two budgets (fewer steps first), one pair per split."""
    zoo, splits = zoo_entries(), []
    for pair in P["budgets"]:
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(x, str) for x in pair)):
            raise param_error(notebook, "budgets", "a list of [shorter, longer] zoo model pairs", P["budgets"])
        for name in pair:
            check_model_choice(notebook, "budgets", name, P["image_size"])
            if name not in zoo:  # a checkpoint file has no budget to read
                raise param_error(notebook, "budgets", f"zoo model names (their steps are compared), among "
                                  f"{sorted(zoo)}", name)
        short, long = (zoo[n] for n in pair)
        if int(short["split"]) != int(long["split"]) or int(short["split"]) == 0:
            raise param_error(notebook, "budgets", "pairs of models of the same split (1-3)", pair)
        if _recipe(short) != _recipe(long):
            diff = sorted(k for k in set(_recipe(short)) | set(_recipe(long))
                          if _recipe(short).get(k) != _recipe(long).get(k))
            raise param_error(notebook, "budgets", f"pairs of one recipe at two budgets ({pair[0]} and {pair[1]} "
                              f"also differ in {diff})", pair)
        if not int(short["steps"]) < int(long["steps"]):
            raise param_error(notebook, "budgets", f"the shorter budget first ({pair[0]}: {short['steps']} steps, "
                              f"{pair[1]}: {long['steps']})", pair)
        splits.append(int(short["split"]))
    if len(set(splits)) != len(splits):
        raise param_error(notebook, "budgets", "one pair per split", P["budgets"])


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    """The budget table (``budget_splits.csv``) with the paired claims; nothing when no pair ran."""
    if not (d / "budget_splits.csv").exists():
        return []
    return ["## 13 · Training budget (the zoo's shorter and longer budget on the same queries)", "",
            md_table(pd.read_csv(d / "budget_splits.csv")), "",
            *claim_line(claims, "longer_budget_unseen", "the longer budget on unseen objects (longer minus shorter)"),
            *claim_line(claims, "longer_budget_seen", "the longer budget on seen objects (longer minus shorter)"),
            ""]


EXPERIMENT = Experiment("13_budget", "the training budget: the zoo's shorter and longer budget of each split on the "
                        "same test queries", claims=budget_claims, section=section, check=check,
                        headline=(("longer_budget_unseen", "The zoo's longer training budget minus the shorter, "
                                                           "unseen objects"),))
