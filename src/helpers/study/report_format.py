"""Markdown pieces the report's sections share: tables, claim lines, numbers and the ablation section.

Every section of ``REPORT.md`` (one per experiment, :mod:`helpers.study.experiments`) is written from
these, so numbers, intervals and verdicts read the same everywhere.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd


def load_json(path: Path) -> Any:
    """The JSON document at ``path``, or None when the file is absent (a notebook that did not run)."""
    return json.loads(path.read_text()) if path.exists() else None


_LABEL_COLUMNS = ("split", "method", "variant", "setting")


def md_table(df: pd.DataFrame) -> str:
    """Markdown table: label columns first; per numeric column whole numbers as integers, values
    below 1 with 3 decimals (seconds per query), others with 1 (accuracies in %)."""
    df = df[[c for c in _LABEL_COLUMNS if c in df.columns] + [c for c in df.columns if c not in _LABEL_COLUMNS]]
    out = df.copy().astype(object)
    align = []
    for c in df.columns:
        col = pd.to_numeric(df[c], errors="coerce")
        numeric = not (df[c].dtype == bool or col.isna().all() or col.notna().sum() != df[c].notna().sum())
        align.append("right" if numeric else "left")
        if not numeric:
            continue
        finite = col.dropna()
        whole = bool(((finite - finite.round()).abs() < 1e-9).all())
        nd = 0 if whole else (1 if finite.abs().max() >= 1 else 3)
        out[c] = [("" if pd.isna(v) else f"{v:,.0f}" if nd == 0 else f"{v:.{nd}f}") for v in col]
    return out.to_markdown(index=False, disable_numparse=True, colalign=align)


def claim_line(claims: dict[str, dict], cid: str, text: str, unit: str = "points") -> list[str]:
    """"- text: +3.1 points, 95 % CI [-2.0, 8.1] — **within noise**" from claim ``cid`` (nothing if absent)."""
    c = claims.get(cid)
    if c is None:
        return []
    f = "+.2f" if unit == "points" else ".2f"  # differences carry their sign; ratios do not
    ci = "" if c["ci95"] is None else f", 95 % CI [{c['ci95'][0]:{f}}, {c['ci95'][1]:{f}}]"
    paper_part = "" if c["paper"] is None else f" (paper: {c['paper']:{f}})"
    return [f"- {text}: {c['ours']:{f}} {unit}{ci}{paper_part} — **{c['verdict']}**"]


def fmt(x: Any, nd: int = 1) -> str:
    """``x`` with ``nd`` decimals, or "n/a" when it is not a number."""
    try:
        return f"{float(x):.{nd}f}"
    except (TypeError, ValueError):
        return "n/a"


def ablation_section(d: Path, title: str, fig: str, claim: str) -> list[str]:
    """An ablation notebook's section: its table, the paper's trend, each trend's verdict with its interval and
    seed spread, the training-noise rows and the figure ``fig`` in folder ``d``."""
    m = load_json(d / "metrics.json")
    if not m:
        return [f"## {title}", "", "_not run_", ""]
    df = pd.DataFrame(m["table"])
    out = [f"## {title}", "", md_table(df.drop(columns=[c for c in ("run",) if c in df.columns])), "",
           f"Paper: {claim}.", ""]
    for k, v in m.get("trend", {}).items():
        if isinstance(v, dict) and "verdict" in v:
            agrees = "agrees" if v["point_estimate_agrees"] else "disagrees"
            out.append(f"- {k.replace('_', ' ')}: the point estimate {agrees}{_noise(v)}")
    for label, c in (m.get("seeds") or {}).items():
        out.append(f"- training noise, {c['compare']}: {c['diff_pts']:+.1f} pts, 95 % CI "
                   f"[{c['ci'][0]:+.1f}, {c['ci'][1]:+.1f}]")
    if m.get("noise"):
        out += ["", f"_Noise: {m['noise']}._"]
    out += ["", f"![{title}]({d.name}/{fig})", ""]
    return out


def _seeds(p: dict) -> str:
    """"; per seed +2.0/+4.1, seed spread 3.0" where a pair carries seed information."""
    if p.get("seed_spread_pts") is None:
        return ""
    per = "/".join(f"{d:+.1f}" for d in p.get("per_seed_diff_pts") or [])
    return f"; per seed {per}, seed spread {p['seed_spread_pts']:.1f}"


def _noise(v: dict) -> str:
    """", +3.1 pts, 95 % CI [-2.0, 8.1]: within noise" for a claim dict (or its pairs)."""
    if "pairs" in v:
        parts = [f"{p['compare']} {p['diff_pts']:+.1f} [{p['ci'][0]:+.1f}, {p['ci'][1]:+.1f}]{_seeds(p)}"
                 for p in v["pairs"]]
        return f" ({'; '.join(parts)} pts, 95 % CI): **{v['verdict']}**"
    return (f" ({v['compare']}: {v['diff_pts']:+.1f} pts, 95 % CI [{v['ci'][0]:+.1f}, {v['ci'][1]:+.1f}]"
            f"{_seeds(v)}): **{v['verdict']}**")
