"""Notebook 10: the explorer (one query, its top references, the per-level similarity maps); no claims."""

from __future__ import annotations

from typing import Any

from ...data.manifest import load_manifest
from ..parameter_rules import check_model_choice, param_error
from .base import Experiment


def check(notebook: str, P: dict[str, Any]) -> None:
    """The explorer's model (zoo name or checkpoint file), first object and query."""
    check_model_choice(notebook, "model", P["model"], P["image_size"])
    objects = load_manifest().seen_objects(0)
    if P["object_name"] and P["object_name"] not in objects:
        raise param_error(notebook, "object_name", f"'' or a benchmark object among {objects}", P["object_name"])
    if P["query"] >= P["n_test_queries"]:
        raise param_error(notebook, "query", f"an index below n_test_queries={P['n_test_queries']}", P["query"])


EXPERIMENT = Experiment("10_explore", "the explorer: one query, its nearest references and similarity maps",
                        check=check)
