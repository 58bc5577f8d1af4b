"""What the gap account (notebook 11) reads: the per-query files notebooks 03, 06 and 07 wrote in one report.

Every step of the account must answer the same queries with the same model, so the inputs are checked here:
each file exists (a missing one names the notebook that writes it), and notebooks 06 and 07 ran with the same
model choice, split and queries (their ``run.json`` parameters).
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from ...evaluation.search_results import FAST_ROW, GREEDY_ROW, SearchComparison, variant_row

#: Parameters notebooks 06 and 07 must share for their answers to be steps of one account.
SHARED = ("split", "models", "zoo_steps", "image_size", "render_size", "n_references", "n_test_queries",
          "test_queries", "query_style", "seed", "epochs", "steps_per_epoch", "lr", "batch_size")


class GapInputError(ValueError):
    """An input of the gap account is missing or does not match the others."""


def report_root(report_dir: str, out: Path) -> Path:
    """The report folder to read: ``report_dir``, or the folder holding this notebook's ``out``."""
    root = Path(report_dir) if report_dir else Path(out).parent
    if not root.is_dir():
        raise GapInputError(f"report_dir {root} is not a folder (expected the report folder of notebooks 03, 06, 07)")
    return root


def _read(path: Path, writer: str) -> pd.DataFrame:
    if not path.is_file():
        raise GapInputError(f"{path} is missing: run notebook {writer} into this report folder first")
    return pd.read_csv(path)


def _params(root: Path, nb: str) -> dict:
    path = root / nb / "run.json"
    if not path.is_file():
        raise GapInputError(f"{path} is missing: run notebook {nb} into this report folder first")
    return json.loads(path.read_text()).get("parameters", {})


def check_same_setup(root: Path) -> dict:
    """The parameters of :data:`SHARED` that notebooks 06 and 07 ran with (raises when they differ)."""
    p6, p7 = _params(root, "06_reference_count"), _params(root, "07_fast_vs_greedy")
    differ = {k: (p6.get(k), p7.get(k)) for k in SHARED if p6.get(k) != p7.get(k)}
    if differ:
        raise GapInputError(f"notebooks 06 and 07 in {root} ran with different {sorted(differ)} (06, 07): {differ}; "
                            "the account needs one model and one set of queries")
    return {k: p6.get(k) for k in SHARED}


def split_steps(root: Path, old_k_ac: int, old_fps_k: int) -> dict[str, pd.DataFrame]:
    """Per-query tables of one split's unseen queries: ``old`` (07's named budget ``old_k_ac`` / ``old_fps_k``),
    ``fast`` (07's paper-ratio fast search), ``greedy`` (07's), ``dense`` (06's greedy at its largest count),
    plus ``meta`` facts: the bank size, the paper-ratio budget, the largest count."""
    cmp_ = SearchComparison.load(root / "07_fast_vs_greedy")
    if cmp_ is None:
        raise GapInputError(f"{root / '07_fast_vs_greedy' / 'metrics.json'} is missing: run notebook 07 first")
    old = variant_row(old_k_ac, old_fps_k)
    if old not in cmp_.per_query:
        raise GapInputError(f"notebook 07 in {root} has no row {old!r} (rows with files: {sorted(cmp_.per_query)}); "
                            "add [old_k_ac, old_fps_k] to its fast_variants")
    m6 = json.loads((root / "06_reference_count" / "metrics.json").read_text()) \
        if (root / "06_reference_count" / "metrics.json").is_file() else None
    if m6 is None:
        raise GapInputError(f"{root / '06_reference_count' / 'metrics.json'} is missing: run notebook 06 first")
    most = max(int(r["refs_per_object"]) for r in m6["table"])
    return {"old": cmp_.per_query[old], "fast": cmp_.per_query[FAST_ROW], "greedy": cmp_.per_query[GREEDY_ROW],
            "dense": _read(root / "06_reference_count" / f"per_query_{most}refs.csv", "06_reference_count"),
            "meta": {"refs_per_object": cmp_.bank.get("refs_per_object"), "k_ac": cmp_.bank.get("k_ac"),
                     "fps_k": cmp_.bank.get("fps_k"), "dense_refs": most}}


def three_split_tables(root: Path) -> dict[str, pd.DataFrame]:
    """Notebook 03's unseen per-query tables (every split it ran): ours and HOG, each with both searches."""
    d = root / "03_evaluate"
    ours = _read(d / "per_query_ours.csv", "03_evaluate")
    how = str(ours["search"].iloc[0]) if "search" in ours.columns else "fast"
    other = "greedy" if how == "fast" else "fast"
    out = {f"ours {how}": ours[ours["part"] == "unseen"],
           f"ours {other}": _read(d / f"per_query_ours_{other}.csv", "03_evaluate"),
           f"HOG {how}": _read(d / "per_query_hog.csv", "03_evaluate"),
           f"HOG {other}": _read(d / f"per_query_hog_{other}.csv", "03_evaluate")}
    return out
