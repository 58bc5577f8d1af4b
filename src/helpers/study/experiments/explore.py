"""Notebook 10: the explorer (one query, its top references, the per-level similarity maps) and bring your own
object: a held-out object's test photos answered from its mesh file alone."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ...data.manifest import load_manifest
from ...evaluation.claims import UNNAMED_MODEL, byo_claims
from ..parameter_rules import check_model_choice, param_error
from ..report_format import fmt, load_json
from .base import Experiment


def check(notebook: str, P: dict[str, Any]) -> None:
    """The bring-your-own and explorer models (zoo names or checkpoint files), first object and query."""
    if P["byo_model"]:
        check_model_choice(notebook, "byo_model", P["byo_model"], P["image_size"])
    check_model_choice(notebook, "model", P["model"], P["image_size"])
    objects = load_manifest().seen_objects(0)
    if P["object_name"] and P["object_name"] not in objects:
        raise param_error(notebook, "object_name", f"'' or a benchmark object among {objects}", P["object_name"])
    if P["query"] >= P["n_test_queries"]:
        raise param_error(notebook, "query", f"an index below n_test_queries={P['n_test_queries']}", P["query"])


def byo_line(byo: dict, claim: dict | None) -> str:
    """The bring-your-own line: the photos' accuracy with its interval, the median error and the drawn photo's."""
    ci = byo.get("ci95") or (claim or {}).get("ci95")
    ci = "" if not ci else f" [{ci[0]:.1f}, {ci[1]:.1f}]"
    return (f"Bring your own object ({byo.get('model', UNNAMED_MODEL)}): `{byo['object']}` from its mesh file, "
            f"{byo['n_refs']} references: {fmt(byo['rot_acc'])} %{ci} of its {byo['n_queries']} test photos within "
            f"{fmt(byo.get('threshold_deg', 30.0), 0)}°, median error {fmt(byo['median_err_deg'])}°; the photo "
            f"drawn below: error {fmt(byo['error_deg'])}°.")


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    """The bring-your-own answers (the explorer itself leaves ``explore.json`` and a figure, no claim)."""
    byo = load_json(d / "byo.json")
    if not byo or "n_queries" not in byo:  # not run, or written before the photos' accuracy moved here
        return []
    return ["## 10 · Bring your own object", "", byo_line(byo, claims.get("byo_rot_acc")), "",
            "![byo](10_explore/byo_overlay.png)", ""]


EXPERIMENT = Experiment("10_explore", "the explorer: one query, its nearest references and similarity maps; bring "
                        "your own object (a held-out object's photos answered from its mesh file)",
                        claims=byo_claims, section=section, check=check,
                        headline=(("byo_rot_acc", "Bring your own: a held-out object's photos answered from its "
                                                  "mesh file"),))
