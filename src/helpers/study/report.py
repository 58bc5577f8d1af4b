"""Assemble ``reports/<preset>/REPORT.md`` from the files the notebooks wrote.

Every number here is read from a metrics JSON/CSV that a notebook computed
in this run; the paper's numbers come from :mod:`helpers.evaluation.paper` and are
labelled as such. Each section states whether the paper's trend holds with the verdict of
its claim in ``claims.json`` (the vocabulary of :mod:`helpers.evaluation.stats`). The sections
are the experiments' (:mod:`helpers.study.experiments`), in notebook order.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from ..core.fileio import atomic_write_text
from ..core.paths import REPO_ROOT
from .experiments import REGISTRY, claims_by_section, write_claims
from .provenance import git_revision
from .report_format import load_json as _load


def _real_data(base: Path) -> bool:
    """Whether this folder's runs read real LineMOD (a notebook run with ``bop_root``)."""
    for run in base.glob("*/run.json"):
        try:
            if json.loads(run.read_text()).get("parameters", {}).get("bop_root"):
                return True
        except (OSError, ValueError):
            continue
    return False


def _intro(base: Path) -> str:
    """The report's first paragraph: what data its numbers come from."""
    head = ("Reproduction of *Fusing Local Similarities for Retrieval-based 3D Orientation Estimation of Unseen "
            "Objects* (Zhao, Hu, Salzmann, ECCV 2022)")
    tail = ("Every number below was computed by this repository's code in this run and read from the files in "
            "this folder.")
    if _real_data(base):
        return (f"{head} on real LineMOD / LineMOD-O photographs in BOP format (`bop_root`). {tail} The paper "
                "trained 200 GPU epochs at 128 px with 10,000 references per object; these models train on a CPU "
                "budget, so the gap to its numbers is the budget's and the density's as much as the method's.")
    return (f"{head} on an embedded rendered benchmark (see `data_manifest.yaml`). {tail} The paper's numbers were "
            "measured on real LineMOD / LineMOD-O photographs with 200-epoch GPU training and 10,000 references per "
            "object; ours come from rendered real-like queries and a CPU budget, so **compare trends, not values**.")


def build_report(preset: str, root: Path | None = None, notebooks: list[str] | None = None) -> Path:
    """Write REPORT.md (and claims.json) for ``preset``: a section per notebook of ``notebooks`` (the preset's,
    :func:`helpers.study.cli.runner.preset_notebooks`; None: every notebook), saying so where it did not run."""
    base = (root or REPO_ROOT / "reports") / preset
    lines: list[str] = [f"# Study report — preset `{preset}`", ""]
    lines += [_intro(base), ""]
    claims, stale = claims_by_section(base)
    write_claims(base, claims)
    by_id = {c["id"]: c for c in claims}
    head = _provenance(base)
    body: list[str] = []
    for e in REGISTRY:
        if e.section is None or (notebooks is not None and e.notebook not in notebooks):
            continue
        sub = e.notebook
        try:
            body += e.section(base / sub, by_id) if sub not in stale else []
        except (KeyError, TypeError, ValueError) as err:  # a file of another layout: that section only
            stale[sub] = f"{base / sub}: its files were written by another version of the code ({err!r}); rerun {sub}"
        if sub in stale:
            body += [f"## {sub}", "", f"_{stale[sub]}_", ""]
    lines += head + _stale(stale) + _claims(claims) + body
    out = base / "REPORT.md"
    atomic_write_text(out, "\n".join(lines) + "\n")
    return out


def _commits_line(runs: list[Path]) -> str:
    """"git commit `abc…`" when every notebook ran at one commit, else each commit with its notebooks
    (a partial rerun with ``--only`` leaves the others' outputs from an earlier commit)."""
    by_commit: dict[str, list[str]] = {}
    for f in runs:
        g = (_load(f) or {}).get("git", {})
        key = f"`{g.get('commit')}`{' (uncommitted changes)' if g.get('dirty') else ''}"
        by_commit.setdefault(key, []).append(f.parent.name)
    if len(by_commit) == 1:
        return f"git commit {next(iter(by_commit))}"
    return "git commits " + "; ".join(f"{k} ({', '.join(v)})" for k, v in by_commit.items())


def _provenance(base: Path) -> list[str]:
    runs = sorted(base.glob("*/run.json"))
    timings = _load(base / "timings.json") or {}
    if not runs:
        return ["_No notebook has run for this preset yet._", ""]
    r = _load(runs[0])
    dev = r.get("device", {})
    gl = (_load(base / "01_render" / "render_summary.json") or {}).get("gl_platform") or r.get("gl_platform")
    fk = dev.get("fusion_kernel") or {}
    fusion_impl = ("" if dev.get("resolved", "cpu") != "cpu" else
                   "; fusion: fused CPU kernel" if fk.get("available") else
                   f"; fusion: eager PyTorch ({fk.get('reason')})" if fk else "")
    built = git_revision()
    out = ["## Provenance", "",
           f"- notebooks ran at {_commits_line(runs)}; "
           f"this file was assembled from their output files at `{built.get('commit')}`"
           f"{' (uncommitted changes)' if built.get('dirty') else ''}",
           f"- device `{dev.get('resolved')}` ({dev.get('cpu_count')} CPUs, torch threads {dev.get('torch_threads')}"
           f"{', GPU ' + dev['gpu'] if dev.get('gpu') else ''}){fusion_impl}; "
           + (f"GL `{gl}`" if gl else "no GL context in the notebook processes (renders cached or made in worker processes)"),
           "- packages: " + ", ".join(f"{k} {v}" for k, v in (r.get("packages") or {}).items() if v),
           f"- seed {r.get('seed')}; each notebook's parameters are in `<notebook>/run.json`", ""]
    rex = _load(base / "reexecuted.json")
    if rex:
        out += [f"- re-executed after the timed run, from its caches (same trained models and renders), at commit "
                f"`{rex.get('commit')}`: {', '.join(rex.get('notebooks', {}))} ({rex.get('reason')}); the table below "
                f"keeps the timed run's wall times, the re-executions took "
                + ", ".join(f"{k} {v:.0f} s" for k, v in rex.get("notebooks", {}).items()), ""]
    if timings:
        out += ["| notebook | seconds |", "|---|---|"]
        out += [f"| {k} | {v:.0f} |" for k, v in timings.items()]
        out += [f"| **total** | **{sum(timings.values()):.0f}** |", ""]
    return out


def _stale(stale: dict[str, str]) -> list[str]:
    """Notebook folders this code cannot read (their sections below say so): rerun those notebooks."""
    for why in stale.values():
        print(f"[report] {why}", file=sys.stderr)
    return ["**Not read** (written by another version of the code; rerun these notebooks): "
            + ", ".join(f"`{k}`" for k in stale) + ".", ""] if stale else []


def _claims(claims: list[dict]) -> list[str]:
    """The claims of ``claims.json`` as a table (with the benchmark's HOG calibration first)."""
    if not claims:
        return []

    def num(v: Any, nd: int | None = None) -> str:
        if v is None:
            return "—"
        return f"{v:.{nd if nd is not None else 2 if abs(v) < 1.5 else 1}f}"

    def row_digits(c: dict) -> int:
        # One precision for a value and its interval (no "[-1.8, 1.25]"): 2 decimals for fractions and
        # differences of a few points, 1 from 10 on.
        vals = [abs(v) for v in [c["ours"], *(c["ci95"] or [])] if v is not None]
        return 2 if vals and max(vals) < 10 else 1

    seeded = any(c.get("seed_spread_pts") is not None for c in claims)
    out = ["## Claims (`claims.json`)", "",
           "Each row is computed from this run's files; 95 % intervals are bootstrap intervals over queries "
           "(resampled within objects; paired where two methods answer the same queries)."
           + (" Ablation rows also carry the training-seed spread: the largest seed-to-seed range of Rota. Acc. "
              "among the variants trained with several seeds in that notebook (`seed_noise` rows give each "
              "seed-to-seed difference with its own interval); an ablation claim **holds** only if its interval "
              "excludes 0 AND the difference exceeds the seed spread (\"within seed spread\" when only the "
              "interval excludes 0)." if seeded else ""), "",
           "| id | claim | ours | 95 % CI | seed spread | paper | verdict |", "|---|---|---:|---|---:|---:|---|"]
    for c in claims:
        nd = row_digits(c)
        ci = "—" if c["ci95"] is None else f"[{num(c['ci95'][0], nd)}, {num(c['ci95'][1], nd)}]"
        sp = c.get("seed_spread_pts")
        out.append(f"| `{c['id']}` | {c['claim']} | {num(c['ours'], nd)} | {ci} | {'—' if sp is None else num(sp)} | "
                   f"{num(c['paper'])} | {c['verdict']} |")
    return out + [""]
