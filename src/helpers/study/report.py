"""Assemble ``reports/<preset>/REPORT.md`` from the files the notebooks wrote.

Every number here is read from a metrics JSON/CSV that a notebook computed
in this run; the paper's numbers come from :mod:`helpers.evaluation.paper` and are
labelled as such. Each section states whether the paper's trend holds with the verdict of
its claim in ``claims.json`` (the vocabulary of :mod:`helpers.evaluation.stats`).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pandas as pd

from ..core.fileio import atomic_write_text
from ..core.paths import REPO_ROOT
from ..evaluation import paper
from ..evaluation.claims import HOG_BAND, TLESS_HOG_BAND, UNNAMED_MODEL, claims_by_section, write_claims
from ..evaluation.search_results import SearchComparison
from .provenance import git_revision


def _load(path: Path) -> Any:
    return json.loads(path.read_text()) if path.exists() else None


_LABEL_COLUMNS = ("split", "method", "variant", "setting")


def _md(df: pd.DataFrame) -> str:
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


def _claim_line(claims: dict[str, dict], cid: str, text: str, unit: str = "points") -> list[str]:
    """"- text: +3.1 points, 95 % CI [-2.0, 8.1] — **within noise**" from claim ``cid`` (nothing if absent)."""
    c = claims.get(cid)
    if c is None:
        return []
    f = "+.2f" if unit == "points" else ".2f"  # differences carry their sign; ratios do not
    ci = "" if c["ci95"] is None else f", 95 % CI [{c['ci95'][0]:{f}}, {c['ci95'][1]:{f}}]"
    paper_part = "" if c["paper"] is None else f" (paper: {c['paper']:{f}})"
    return [f"- {text}: {c['ours']:{f}} {unit}{ci}{paper_part} — **{c['verdict']}**"]


def _held_out_line(h: dict, claim: dict | None) -> list[str]:
    """The held-out objects' line of section 3: model, Rota. Acc. with its interval where the claim has one."""
    ci = "" if claim is None or claim["ci95"] is None else f" [{claim['ci95'][0]:.1f}, {claim['ci95'][1]:.1f}]"
    model = h.get("model", UNNAMED_MODEL)
    return [f"- held-out objects (never trained on, retrieved among all objects; {model}): Rota. Acc. "
            f"{_fmt(h['rot_acc'])} %{ci}, Class. Acc. {_fmt(h['class_acc'])} %"]


def _byo_line(byo: dict, claim: dict | None) -> str:
    """The bring-your-own demo's line: its photos' accuracy with the interval (files from before
    ``byo_queries`` hold one photo and its error only)."""
    head = (f"Bring-your-own-object demo ({byo.get('model', UNNAMED_MODEL)}): `{byo['object']}` from its mesh file, "
            f"{byo['n_refs']} references")
    if "n_queries" not in byo:
        return f"{head}, error {_fmt(byo['error_deg'])}°."
    ci = byo.get("ci95") or (claim or {}).get("ci95")
    ci = "" if not ci else f" [{ci[0]:.1f}, {ci[1]:.1f}]"
    return (f"{head}: {_fmt(byo['rot_acc'])} %{ci} of its {byo['n_queries']} test photos within "
            f"{_fmt(byo.get('threshold_deg', 30.0), 0)}°, median error {_fmt(byo['median_err_deg'])}°; the photo "
            f"drawn below: error {_fmt(byo['error_deg'])}°.")


def _fmt(x: Any, nd: int = 1) -> str:
    try:
        return f"{float(x):.{nd}f}"
    except (TypeError, ValueError):
        return "n/a"


def build_report(preset: str, root: Path | None = None) -> Path:
    """Write REPORT.md for ``preset``; sections for notebooks that did not run say so."""
    base = (root or REPO_ROOT / "reports") / preset
    lines: list[str] = [f"# Study report — preset `{preset}`", ""]
    lines += ["Reproduction of *Fusing Local Similarities for Retrieval-based 3D Orientation Estimation of Unseen "
              "Objects* (Zhao, Hu, Salzmann, ECCV 2022) on an embedded rendered benchmark (see `data_manifest.yaml`). "
              "Every number below was computed by this repository's code in this run and read from the files in "
              "this folder. The paper's numbers were measured on real LineMOD / LineMOD-O photographs with "
              "200-epoch GPU training and 10,000 references per object; ours come from rendered real-like queries "
              "and a CPU budget, so **compare trends, not values**.", ""]
    claims, stale = claims_by_section(base)
    write_claims(base, claims)
    by_id = {c["id"]: c for c in claims}
    head = _provenance(base)
    sections = [
        ("01_render", lambda d: _render(d)), ("02_train", lambda d: _train(d)),
        ("03_evaluate", lambda d: _eval(d, by_id)),
        ("04_ablation_scales", lambda d: _ablation(d, "Scales (paper Fig. 5a)", "scales.png", paper.SCALES_CLAIM)),
        ("05_ablation_fusion", lambda d: _ablation(d, "Fusion (paper Fig. 6a)", "fusion.png",
                                                   "Avg 80.9 < Sigmoid 88.57 < Softmax 89.03 < adaptive 89.55 "
                                                   "(split #1 unseen)")),
        ("06_reference_count", lambda d: _refcount(d, by_id)),
        ("07_fast_vs_greedy", lambda d: _fast(d, by_id)),
        ("08_components", lambda d: _ablation(d, "Components (paper Table 5)", "components.png",
                                              "neither 85.91 < weighted loss 87.14 < local norm 89.25 < both 89.55 "
                                              "(split #1 unseen)")),
        ("09_tless", lambda d: _tless(d, by_id)),
        ("11_gap_to_paper", lambda d: _gap(d, by_id)),
    ]
    body: list[str] = []
    for sub, section in sections:
        try:
            body += section(base / sub) if sub not in stale else []
        except (KeyError, TypeError, ValueError) as e:  # a file of another layout: that section only
            stale[sub] = f"{base / sub}: its files were written by another version of the code ({e!r}); rerun {sub}"
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
           f"{', GPU ' + dev['gpu'] if dev.get('gpu') else ''}){fusion_impl}; GL `{gl}`",
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


def _render(d: Path) -> list[str]:
    s = _load(d / "render_summary.json")
    if not s:
        return ["## 1 · Rendered benchmark", "", "_not run_", ""]
    c = s["data_config"]
    return ["## 1 · Rendered benchmark", "",
            f"{len(s['objects'])} objects, {s['views']} views rendered or loaded in {s['render_or_load_seconds']:.0f} s "
            f"({c['n_references']} references per object at {c['image_size']} px; "
            f"{c['n_train_queries']}/{c['n_val_queries']}/{c['n_test_queries']} train/val/test queries per object). "
            f"10,000 references of one object take {s['reference_bytes_per_10000_per_object'] / 1e6:.0f} MB on disk "
            f"at this size.", "", "![views](01_render/views.png)", ""]


def _train(d: Path) -> list[str]:
    m = _load(d / "train_metrics.json")
    if not m:
        return ["## 2 · Training", "", "_not run_", ""]
    u = m["unseen_test"]
    ch = m["chance"]
    bv = m.get("best_val") or {}
    hist = (_load(d / "history.json") or {}).get("history") or []
    run = (_load(d / "run.json") or {}).get("parameters") or {}
    budget = (f"- training budget: {hist[-1]['global_step']:,} optimiser steps of {run.get('batch_size', '?')} queries "
              f"in {sum(h['seconds'] for h in hist):.0f} s (paper: 200 epochs over every real training image, "
              f"batch 16); a CPU budget for trends, not the paper's accuracy"
              if hist else "- training budget: n/a")
    return ["## 2 · Training (split #%d)" % m["split"], "",
            budget,
            f"- parameters: encoder/decoder {m['parameters']['encoder_decoder']:,}, fusion head "
            f"{m['parameters']['fusion_head']:,} (paper: about 1.9 M and 50 K)",
            f"- training speed {_fmt(m['train_images_per_s'])} images/s; selected epoch {bv.get('epoch')} on held-out "
            f"views of seen objects by `{m.get('selection', 'rot_acc')}` (val Class. Acc. {_fmt(bv.get('class_acc'))} %, "
            f"Rota. Acc. {_fmt(bv.get('rot_acc'))} %)",
            f"- unseen objects of the split: Class. Acc. {_fmt(u['class_acc'])} % (chance {_fmt(ch['class_acc'])} %), "
            f"Rota. Acc. {_fmt(u['rot_acc'])} % (chance {_fmt(ch['rot_acc'], 2)} %)", "",
            "![history](02_train/loss.png)", ""]


def _eval(d: Path, claims: dict[str, dict]) -> list[str]:
    m = _load(d / "metrics.json")
    if not m:
        return ["## 3 · Evaluation", "", "_not run_", ""]
    t1 = pd.DataFrame(m["table1"])
    t2 = pd.DataFrame(m["table2"])
    out = ["## 3 · Evaluation (paper Tables 1 and 2)", "", _md(t1), "",
           f"Paper (LineMOD): unseen Class. Acc. {paper.LINEMOD_UNSEEN_CLASS_ACC_MEAN}, seen Rota. Acc. "
           f"{paper.LINEMOD_SEEN_ROT_ACC_MEAN}, LineMOD-O unseen {paper.LINEMOD_O_UNSEEN_ROT_ACC_MEAN} (means).", "",
           *_claim_line(claims, "seen_minus_unseen", "seen objects easier than unseen (seen minus unseen)"),
           *_claim_line(claims, "occlusion_hurts", "occlusion hurts (unseen minus occluded)"),
           *_held_out_line(m["held_out"], claims.get("held_out_rot_acc")), "",
           "![bars](03_evaluate/table1_bars.png)", "", "### Baselines", "", _md(t2), ""]
    hog = claims.get("hog_unseen_rot_acc")
    if hog is not None:
        lo, hi = HOG_BAND
        out += [f"**Benchmark calibration** (a method nobody trains): HOG nearest neighbour (Dalal-Triggs: 9 bins, "
                f"8 px cells, 2x2 blocks) with the study's search over the same references, errors under the declared "
                f"symmetries ({hog['claim']}): {hog['ours']:.1f} % (95 % CI [{hog['ci95'][0]:.1f}, "
                f"{hog['ci95'][1]:.1f}]); the paper's HOG scores {paper.BASELINES_UNSEEN_ROT_ACC['HOG']} % on real "
                f"LineMOD. Target band {lo:.0f}-{hi:.0f} %: **{hog['verdict']}**.", ""]
        out += _claim_line(claims, "hog_unseen_rot_acc_greedy", "HOG with exhaustive (greedy) search", unit="%")
        out += _claim_line(claims, "hog_unseen_rot_acc_fast", "HOG with fast search", unit="%")
    out += _claim_line(claims, "ours_minus_hog", "ours beats HOG (ours minus HOG, the study's search for both, paired)")
    out += _claim_line(claims, "ours_minus_global", "ours beats the Global descriptor (ours minus Global, paired)")
    out += _searches(m, claims)
    out += _budget(d, claims)
    out += ["", "![examples](03_evaluate/examples_unseen.png)", "", "![fusion maps](03_evaluate/fusion_maps.png)", ""]
    byo = _load(d / "byo.json")
    if byo:
        out += [_byo_line(byo, claims.get("byo_rot_acc")), "", "![byo](03_evaluate/byo_overlay.png)", ""]
    return out


def _searches(m: dict, claims: dict[str, dict]) -> list[str]:
    """Table 1 like with like: every method with greedy and fast search on the same references, and the paired
    claims of each search (nothing for files written before notebook 03 ran both)."""
    if not m.get("table1_searches"):
        return []
    out = ["", "### Table 1, like with like (greedy and fast search, the same references and queries)", "",
           _md(pd.DataFrame(m["table1_searches"])), ""]
    for how in ("greedy", "fast"):
        out += _claim_line(claims, f"ours_minus_hog_{how}", f"ours minus HOG, both {how} (paired)")
        out += _claim_line(claims, f"ours_minus_global_{how}", f"ours minus Global, both {how} (paired)")
    return out


def _refcount(d: Path, claims: dict[str, dict]) -> list[str]:
    """Notebook 06: the reference-count table (greedy and fast), its figure and each step's paired claim."""
    out = _ablation(d, "Number of references (paper Fig. 7)", "reference_count.png", paper.REFERENCE_COUNT_CLAIM)
    steps = sorted((c for k, c in claims.items() if k.startswith("refcount_step")), key=lambda c: c["id"])
    if steps:
        out += ["Each step up in count, paired on the same queries:", ""]
        for c in steps:
            out += _claim_line(claims, c["id"], c["claim"].split(" (")[0])
        out.append("")
    return out


#: Column order of notebook 11's every-split table (its metrics.json stores records with sorted keys).
ALL_SPLITS_COLUMNS = ["answers", "splits", "rot_acc, no symmetries", "rot_acc, declared symmetries", "change_pts",
                      "change_lo", "change_hi", "verdict"]


def _gap(d: Path, claims: dict[str, dict]) -> list[str]:
    """Notebook 11: the gap account's steps, waterfall and the symmetry step on every split."""
    m = _load(d / "metrics.json")
    title = "## 11 · The gap to the paper, step by step"
    if not m:
        return [title, "", "_not run_", ""]
    steps = pd.DataFrame(m["steps"])[["label", "rot_acc", "ci95_lo", "ci95_hi", "change_pts", "change_lo",
                                      "change_hi", "verdict"]]
    return [title, "", f"Split #{m['split']} unseen queries, one model ({m['setup']['models']}, zoo_steps "
            f"{m['setup']['zoo_steps']}), each step a paired change on the same queries; the last row is the paper's "
            f"number minus the last measured step: **not measured** here. Objects with declared symmetries: "
            f"{', '.join(m['symmetric_objects']) or 'none'}.", "", _md(steps), "",
            f"![waterfall]({d.name}/gap_waterfall.png)", "", "Notebook 03's answers on every split, without and with "
            "the declared symmetries:", "", _md(pd.DataFrame(m["all_splits"])[ALL_SPLITS_COLUMNS]), ""]


def _budget(d: Path, claims: dict[str, dict]) -> list[str]:
    """Notebook 03's budget comparison (``budget_splits.csv``: the zoo's longer and shortest budget on the same
    queries) with its paired claims; nothing when the notebook ran one budget."""
    if not (d / "budget_splits.csv").exists():
        return []
    return ["", "### Budget (the same queries, the zoo's shortest budget)", "",
            _md(pd.read_csv(d / "budget_splits.csv")), "",
            *_claim_line(claims, "longer_budget_unseen", "the longer budget on unseen objects (longer minus shortest)"),
            *_claim_line(claims, "longer_budget_seen", "the longer budget on seen objects (longer minus shortest)")]


def _ablation(d: Path, title: str, fig: str, claim: str) -> list[str]:
    m = _load(d / "metrics.json")
    if not m:
        return [f"## {title}", "", "_not run_", ""]
    df = pd.DataFrame(m["table"])
    out = [f"## {title}", "", _md(df.drop(columns=[c for c in ("run",) if c in df.columns])), "",
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


def _fast(d: Path, claims: dict[str, dict]) -> list[str]:
    r = SearchComparison.load(d)
    if r is None:
        return ["## Fast retrieval vs greedy search (paper Table 4)", "", "_not run_", ""]
    g = paper.FAST_VS_GREEDY
    b = r.bank
    return ["## Fast retrieval vs greedy search (paper Table 4)", "", _md(r.table), "",
            f"Bank: {b['objects']} objects x {b['refs_per_object']} references, {b['k_ac']} anchors; "
            f"{r.n_queries} queries on `{r.device}`; agreement with greedy: "
            + ", ".join(f"{k} {100 * v:.0f} %" for k, v in r.agreement_with_greedy.items()) + ".", "",
            f"Paper: fast {g['fast']['rot_acc']} % in {g['fast']['seconds_per_query']} s vs greedy "
            f"{g['greedy']['rot_acc']} % in {g['greedy']['seconds_per_query']} s (V100, 13 x 10,000).", "",
            *_claim_line(claims, "fast_speedup", "fast retrieval is faster than greedy (greedy / fast, median "
                         "seconds per query)", unit="x"),
            *_claim_line(claims, "fast_minus_greedy", "fast retrieval costs accuracy (fast minus greedy, paired)"),
            *_claim_line(claims, "c2f_minus_fast", "coarse-to-fine (one cut) within 1 point of fast (paired)"),
            *_claim_line(claims, "c2f_halving_minus_fast", "coarse-to-fine (halving) within 1 point of fast "
                         "(paired)"),
            *_c2f_selection_lines(r.c2f_selection), "", "![time](07_fast_vs_greedy/fast_vs_greedy.png)", ""]


def _c2f_selection_lines(sel: dict) -> list[str]:
    """The coarse-to-fine settings and how they were chosen (held-out views of seen objects)."""
    return [f"- coarse-to-fine {fam}: coarse_k {c['coarse_k']}, refine_objects {c['refine_objects']}, chosen on "
            f"held-out views of seen objects (same reference as fast on {100 * c['agreement_with_fast']:.1f} % of "
            f"them; bar {100 * sel['min_agreement']:.0f} % {'met' if c['met'] else 'NOT met: most agreeing kept'}; "
            f"{c['mean_comparisons']:.0f} pair scores/query)"
            for fam, c in sorted((sel.get("chosen") or {}).items(), key=lambda kv: kv[0] != "one cut")]  # one cut first


def _tless(d: Path, claims: dict[str, dict]) -> list[str]:
    m = _load(d / "metrics.json")
    if not m:
        return ["## 9 · T-LESS-like set", "", "_not run_", ""]
    t = pd.DataFrame(m["table"])
    lo, hi = TLESS_HOG_BAND
    hog = claims.get("tless_hog_vsd_acc")
    out = ["## 9 · T-LESS-like set (paper Table 3)", "", m["protocol"]["summary"], "", _md(t), "",
           "Paper (T-LESS, err_vsd <= 0.3): " + ", ".join(f"{k} {v}" for k, v in paper.TLESS_TABLE3.items()) + ".", ""]
    if hog:
        out += [f"**Calibration** (a method nobody trains): HOG scores {_fmt(hog['ours'])} % VSD accuracy "
                f"[{_fmt(hog['ci95'][0])}, {_fmt(hog['ci95'][1])}] (paper's HOG on T-LESS: {paper.TLESS_TABLE3['HOG']}); "
                f"target band {lo:.0f}-{hi:.0f} %: **{hog['verdict']}**.", ""]
    out += _claim_line(claims, "tless_ours_minus_hog", "ours beats HOG (VSD accuracy, paired)")
    out += _claim_line(claims, "tless_ours_minus_global", "ours beats the Global descriptor (VSD accuracy, paired)")
    return out + ["", "![T-LESS-like bars](09_tless/tless_bars.png)", "", "![examples](09_tless/examples.png)", ""]
