"""The README's headline block, written from the reports' ``claims.json`` so its numbers cannot go stale.

``python -m helpers.study.cli.readme [--check]`` rewrites (or checks) the block between the markers in README.md from
``reports/quick/claims.json`` and ``reports/screens/claims.json`` (the training-regime screens, their own job);
``tests/test_experiments.py`` fails when they differ. Each experiment names the
claims it puts in the headline (:attr:`helpers.study.experiments.base.Experiment.headline`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ...core.fileio import atomic_write_text
from ...core.paths import REPO_ROOT
from ..experiments import REGISTRY

README = REPO_ROOT / "README.md"
#: The claims the headline is written from: the quick study's, then the screens' (a missing file adds none).
CLAIMS = (REPO_ROOT / "reports" / "quick" / "claims.json", REPO_ROOT / "reports" / "screens" / "claims.json")
BEGIN = ("<!-- headline: written by `python -m helpers.study.cli.readme` from reports/{quick,screens}/claims.json; "
         "do not edit -->")
END = "<!-- end of headline -->"
#: Claims whose values are fractions or ratios, not percentages or points.
_UNITS = {"fast_speedup": "x", "fast_greedy_agreement": ""}


def _number(c: dict) -> str:
    """"+22.6 pts [19.9, 25.0]; paper 48.4": the value with its unit, interval and the paper's number."""
    diff = _is_difference(c)
    unit = _UNITS.get(c["id"], " pts" if diff else " %")
    f = ".2f" if unit in ("x", "") else "+.1f" if diff else ".1f"
    ci = "" if c["ci95"] is None else f" [{c['ci95'][0]:{f.lstrip('+')}}, {c['ci95'][1]:{f.lstrip('+')}}]"
    paper = "" if c["paper"] is None else f"; paper {c['paper']:{f}}"
    return f"{c['ours']:{f}}{unit}{ci}{paper}"


def _is_difference(c: dict) -> bool:
    return c["id"] not in _UNITS and ("minus" in c["claim"] or "beats" in c["claim"] or "points" in c["claim"])


def headline_lines(claims: list[dict]) -> list[str]:
    """One Markdown bullet per headline claim of every experiment (registry order): label, value, 95 % interval,
    the paper's number and the verdict, with the claim id to find it in claims.json and REPORT.md."""
    by_id = {c["id"]: c for c in claims}
    out = []
    for e in REGISTRY:
        for cid, label in e.headline:
            if cid.endswith("*"):  # every claim with this prefix, named by the rest of its id
                found = [(c, f"{label} {c['id'][len(cid) - 1:].replace('_beats_', ' against ')}") for c in claims
                         if c["id"].startswith(cid[:-1]) and ":seed_noise:" not in c["id"]]
            else:
                found = [(by_id[cid], label)] if cid in by_id else []
            out += [f"- {lab}: {_number(c)} — **{c['verdict']}** (`{c['id']}`, {e.notebook})" for c, lab in found]
    return out


def block(claims: list[dict]) -> str:
    """The README block: markers around the headline lines."""
    return "\n".join([BEGIN, *headline_lines(claims), END])


def current_block(text: str) -> str | None:
    """The block as it stands in README text (None when the markers are missing)."""
    if BEGIN not in text or END not in text:
        return None
    return text[text.index(BEGIN):text.index(END) + len(END)]


def load_claims(paths: tuple[Path, ...] = CLAIMS) -> list[dict]:
    """The claim records of every existing file of ``paths``, in order."""
    return [c for p in paths if p.exists() for c in json.loads(p.read_text())]


def update(readme: Path = README, claims_paths: tuple[Path, ...] = CLAIMS) -> bool:
    """Rewrite the block of ``readme`` from ``claims_paths``; True when it changed (ValueError without markers)."""
    text = readme.read_text()
    old = current_block(text)
    if old is None:
        raise ValueError(f"{readme}: no headline markers ({BEGIN!r} ... {END!r})")
    new = block(load_claims(claims_paths))
    if new != old:
        atomic_write_text(readme, text.replace(old, new))
    return new != old


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when the block differs from the claims")
    a = ap.parse_args(argv)
    if a.check:
        same = current_block(README.read_text()) == block(load_claims())
        print("README headline matches the reports' claims.json" if same else
              "README headline differs from the reports' claims.json: run `python -m helpers.study.cli.readme`")
        return 0 if same else 1
    print("README headline rewritten" if update() else "README headline already current")
    return 0


if __name__ == "__main__":
    sys.exit(main())
