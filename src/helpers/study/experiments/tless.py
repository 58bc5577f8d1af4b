"""Notebook 09: the T-LESS-like set (or a BOP T-LESS folder) scored with VSD (paper Table 3)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from ...core.paths import repo_path
from ...evaluation import paper
from ...evaluation.claims import TLESS_HOG_BAND, tless_claims
from ..parameter_rules import check_model_choice, param_error
from ..report_format import claim_line, fmt, load_json, md_table
from .base import Experiment


def check(notebook: str, P: dict[str, Any]) -> None:
    """The T-LESS-like notebook's models and set sizes, and the BOP folder when one is given."""
    check_model_choice(notebook, "model", P["model"], P["image_size"])
    if P["global_model"]:
        check_model_choice(notebook, "global_model", P["global_model"], P["image_size"])
    if not 0.0 < P["min_visible"] <= 1.0:
        raise param_error(notebook, "min_visible", "a share in (0, 1]", P["min_visible"])
    if P["bop_root"]:
        root = repo_path(P["bop_root"])
        if not (root / P["bop_split"]).is_dir() or not any((root / "models").glob("models_info.json")):
            raise param_error(notebook, "bop_root", f"'' or a BOP dataset folder with models/models_info.json and a "
                              f"{P['bop_split']!r} split folder (bop_split)", P["bop_root"])


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    m = load_json(d / "metrics.json")
    if not m:
        return ["## 9 · T-LESS-like set", "", "_not run_", ""]
    t = pd.DataFrame(m["table"])
    lo, hi = TLESS_HOG_BAND
    hog = claims.get("tless_hog_vsd_acc")
    out = ["## 9 · T-LESS-like set (paper Table 3)", "", m["protocol"]["summary"], "", md_table(t), "",
           "Paper (T-LESS, err_vsd <= 0.3): " + ", ".join(f"{k} {v}" for k, v in paper.TLESS_TABLE3.items()) + ".", ""]
    if hog:
        out += [f"**Calibration** (a method nobody trains): HOG scores {fmt(hog['ours'])} % VSD accuracy "
                f"[{fmt(hog['ci95'][0])}, {fmt(hog['ci95'][1])}] (paper's HOG on T-LESS: {paper.TLESS_TABLE3['HOG']}); "
                f"target band {lo:.0f}-{hi:.0f} %: **{hog['verdict']}**.", ""]
    out += claim_line(claims, "tless_ours_minus_hog", "ours beats HOG (VSD accuracy, paired)")
    out += claim_line(claims, "tless_ours_minus_global", "ours beats the Global descriptor (VSD accuracy, paired)")
    return out + ["", "![T-LESS-like bars](09_tless/tless_bars.png)", "", "![examples](09_tless/examples.png)", ""]


EXPERIMENT = Experiment("09_tless", "the T-LESS-like set (or a BOP T-LESS folder) scored with VSD (paper Table 3)",
                        claims=tless_claims, section=section, check=check,
                        headline=(("tless_vsd_acc", "T-LESS-like parts never trained on, VSD accuracy"),
                                  ("tless_ours_minus_hog", "T-LESS-like, ours minus HOG")))
