"""The machine-readable claims of a report: ``reports/<preset>/claims.json``.

A claim record is ``{"id", "claim", "paper", "ours", "ci95", "verdict"}``: ``ours`` is our number
(percent or percentage points, or a fraction for agreement, or a ratio for speed), ``ci95`` its
95 % interval ``[lo, hi]``, ``paper`` the paper's number for the same quantity on real data (None
where the paper gives none), ``verdict`` one of :data:`helpers.evaluation.stats.VERDICTS`. Every
record is computed here from the files the notebooks wrote in this run (per-query CSVs and
metrics JSON); nothing is typed in. Intervals and verdicts: :mod:`helpers.evaluation.stats`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from . import paper
from .search_results import C2F_FAMILIES, C2F_ROWS, FAST_ROW, GREEDY_ROW, SearchComparison
from .stats import (
    MEASURED,
    VERDICTS,
    accuracy_ci,
    calibration_verdict,
    direction_verdict,
    equivalence_verdict,
    paired_difference,
    unpaired_difference,
)

#: The LineMOD-like benchmark's calibration band for HOG's unseen Rota. Acc. (paper's HOG on LineMOD: 33.13 %).
HOG_BAND = (28.0, 38.0)
#: The T-LESS-like set's calibration band for HOG's VSD accuracy (paper's HOG on T-LESS: 74.22 %).
TLESS_HOG_BAND = (60.0, 85.0)
#: The model of the held-out objects' or bring-your-own files written before they named it.
UNNAMED_MODEL = "first split's model"
#: Coarse-to-fine claims: "within 1 point of fast retrieval" (#15's target), an equivalence margin in points.
C2F_MARGIN_PTS = 1.0


def record(id_: str, claim: str, paper_value: float | None, ours: float | None, ci95: list[float] | None,
           verdict: str, **extra: Any) -> dict[str, Any]:
    """One claim record (numbers rounded to 0.01); ``extra`` fields (e.g. the seed spread) follow."""
    if verdict not in VERDICTS:
        raise ValueError(f"claim {id_}: verdict {verdict!r} is not one of {VERDICTS}")
    r = None if ours is None else round(float(ours), 2)
    ci = None if ci95 is None else [round(float(v), 2) for v in ci95]
    return {"id": id_, "claim": claim, "paper": paper_value, "ours": r, "ci95": ci, "verdict": verdict, **extra}


def _round(v: Any) -> Any:
    if isinstance(v, float):
        return round(v, 2)
    if isinstance(v, list):
        return [_round(x) for x in v]
    return v


def _read_csv(path: Path) -> pd.DataFrame | None:
    return pd.read_csv(path) if path.exists() else None


def _load(path: Path) -> Any:
    return json.loads(path.read_text()) if path.exists() else None


def _diff_record(id_: str, text: str, paper_value: float | None, c: dict, sign: int = 1) -> dict:
    return record(id_, text, paper_value, c["diff_pts"], c["ci"], direction_verdict(c["ci"], sign=sign))


def evaluation_claims(d: Path) -> list[dict]:
    """Claims of Tables 1 and 2 from their per-query tables (``per_query_*.csv``)."""
    ours = _read_csv(d / "per_query_ours.csv")
    if ours is None:
        return []
    unseen, seen, occl = (ours[ours["part"] == p] for p in ("unseen", "seen", "occluded"))
    n_sp = unseen["split"].nunique()
    where = f"mean of {n_sp} split{'s' if n_sp > 1 else ''}"
    pm = paper.LINEMOD_UNSEEN_ROT_ACC["mean"]
    out = [record("unseen_rot_acc", f"Rota. Acc. on unseen objects ({where}, %)", pm, *accuracy_ci(unseen),
                  MEASURED),
           record("unseen_class_acc", f"Class. Acc. on unseen objects ({where}, %)",
                  paper.LINEMOD_UNSEEN_CLASS_ACC_MEAN, *accuracy_ci(unseen, "class_ok"), MEASURED)]
    if len(seen):
        out.append(record("seen_rot_acc", f"Rota. Acc. on seen objects' test views ({where}, %)",
                          paper.LINEMOD_SEEN_ROT_ACC_MEAN, *accuracy_ci(seen), MEASURED))
        out.append(_diff_record("seen_minus_unseen", "seen objects are easier than unseen ones (points)",
                                round(paper.LINEMOD_SEEN_ROT_ACC_MEAN - pm, 2), unpaired_difference(unseen, seen)))
    if len(occl):
        out.append(record("occluded_unseen_rot_acc", f"Rota. Acc. on occluded unseen objects, LM-O-like ({where}, %)",
                          paper.LINEMOD_O_UNSEEN_ROT_ACC_MEAN, *accuracy_ci(occl), MEASURED))
        out.append(_diff_record("occlusion_hurts", "occlusion lowers unseen Rota. Acc. (unseen minus occluded, "
                                "points; different renders, not paired)",
                                round(pm - paper.LINEMOD_O_UNSEEN_ROT_ACC_MEAN, 2), unpaired_difference(occl, unseen)))
    held = _read_csv(d / "per_query_held_out.csv")
    if held is not None:  # the 7 objects no split trains on; the model is named in the file (held_out_model)
        label = held["model"].iloc[0] if "model" in held.columns else UNNAMED_MODEL
        out.append(record("held_out_rot_acc", f"Rota. Acc. on the held-out objects, never trained on ({label}; "
                          "retrieved among all objects, %)", None, *accuracy_ci(held), MEASURED))
    return out + _baseline_claims(d, unseen)


def byo_claims(d: Path) -> list[dict]:
    """The bring-your-own answers (``byo_per_query.csv``, ``byo.json``): one held-out object's test photos, each
    answered from the object's mesh file alone (its own references, no classification)."""
    byo = _read_csv(d / "byo_per_query.csv")
    if byo is None:
        return []
    label = byo["model"].iloc[0] if "model" in byo.columns else UNNAMED_MODEL
    threshold = (_load(d / "byo.json") or {}).get("threshold_deg", 30.0)
    return [record("byo_rot_acc", f"bring your own: share of {byo['obj'].iloc[0]}'s {len(byo)} test photos "
                   f"answered within {threshold:g} deg from its mesh file alone ({label}; its references only, %)",
                   None, *accuracy_ci(byo), MEASURED)]


def _search_of(df: pd.DataFrame | None, default: str) -> str:
    return str(df["search"].iloc[0]) if df is not None and "search" in df.columns and len(df) else default


def _baseline_claims(d: Path, unseen: pd.DataFrame) -> list[dict]:
    """HOG's calibration line (on every split HOG ran) and ours minus each baseline on the same queries (the
    splits both ran; notebook 03 runs HOG on all three whatever its ``splits``), under the same search.

    ``per_query_<method>.csv`` holds the protocol's search (ours: ``per_query_ours.csv``); the other search, where
    it ran, is in ``per_query_<method>_<search>.csv`` for ours and the baselines alike, and gives the same claims
    with ``_<search>`` after their ids. A baseline file from before the ``search`` column was HOG's greedy search.
    """
    out, pb = [], paper.BASELINES_UNSEEN_ROT_ACC
    main = _search_of(_read_csv(d / "per_query_ours.csv"), "fast")
    for suffix in ("", "_greedy", "_fast"):
        mine = unseen if suffix == "" else _read_csv(d / f"per_query_ours{suffix}.csv")
        if mine is not None and suffix:
            mine = mine[mine["part"] == "unseen"] if "part" in mine.columns else mine
        for name, pid in (("HOG", "hog"), ("Global", "global")):
            base = _read_csv(d / f"per_query_{pid}{suffix}.csv")
            if base is None:
                continue
            how = _search_of(base, "greedy" if pid == "hog" and suffix == "" else suffix.lstrip("_") or main)
            if pid == "hog":
                out.append(_hog_record(base, suffix, how, pb["HOG"]))
            ours_how = _search_of(mine, main if suffix == "" else suffix.lstrip("_"))
            both = sorted(set(base["split"]) & set(mine["split"])) if mine is not None else []
            if not both:
                continue
            sp = ",".join(f"#{s}" for s in both)
            paper_diff = round(pb["Ours (paper)"] - pb["HOG"], 2) if pid == "hog" else None
            same = "same search" if how == ours_how else f"NOT the same search: ours {ours_how}"
            out.append(_diff_record(f"ours_minus_{pid}{suffix}", f"ours beats {name} on unseen objects ({how} "
                                    f"search, {same}; splits {sp}, points, paired)", paper_diff,
                                    paired_difference(base[base["split"].isin(both)], mine[mine["split"].isin(both)])))
    return out


def _hog_record(base: pd.DataFrame, suffix: str, how: str, paper_hog: float) -> dict:
    """HOG's unseen Rota. Acc.: the calibration line at the protocol's search, a measured line at the other."""
    sp = ",".join(f"#{s}" for s in sorted(base["split"].unique()))
    v, ci = accuracy_ci(base)
    if suffix:
        return record(f"hog_unseen_rot_acc{suffix}", f"HOG nearest neighbour, unseen Rota. Acc. ({how} search; "
                      f"splits {sp}, %)", paper_hog, v, ci, MEASURED)
    lo, hi = HOG_BAND
    return record("hog_unseen_rot_acc", f"HOG nearest neighbour, unseen Rota. Acc. ({how} search, the study's; splits "
                  f"{sp}, %): the benchmark's difficulty calibration, target {lo:.0f}-{hi:.0f}", paper_hog, v, ci,
                  calibration_verdict(v, HOG_BAND))


def budget_claims(d: Path) -> list[dict]:
    """The longer zoo budget minus the shorter on the same unseen / seen queries, paired per split
    (``per_query_budget.csv``: one row per query and budget, ``budget`` "shorter" / "longer", ``steps``)."""
    pq = _read_csv(d / "per_query_budget.csv")
    if pq is None:
        return []
    out = []
    for part in ("unseen", "seen"):
        short = pq[(pq["budget"] == "shorter") & (pq["part"] == part)]
        long = pq[(pq["budget"] == "longer") & (pq["part"] == part)]
        if not (len(short) and len(long)):
            continue
        a, b = sorted(short["steps"].unique()), sorted(long["steps"].unique())
        steps = (lambda s: "/".join(str(int(x)) for x in s))
        n_sp = short["split"].nunique()
        out.append(_diff_record(f"longer_budget_{part}", f"the zoo's {steps(b)}-step models beat its {steps(a)}-step "
                                f"ones on {part} objects (Rota. Acc., mean of {n_sp} split{'s' if n_sp > 1 else ''}, "
                                "points, paired)", None, paired_difference(short, long)))
    return out


def _seed_fields(p: dict) -> dict:
    """The training-seed fields of a paired claim (:func:`helpers.evaluation.stats.claim`), rounded."""
    return {k: _round(p[k]) for k in ("seeds", "matched_seeds", "per_seed_diff_pts", "seed_spread_pts")}


def ablation_claims(d: Path, prefix: str, paper_values: dict[str, float] | None = None) -> list[dict]:
    """One record per paired claim in an ablation notebook's ``metrics.json`` trend
    (:func:`helpers.evaluation.stats.claim` / ``chain`` dicts, their verdicts as computed there)."""
    m = _load(d / "metrics.json")
    if not m:
        return []
    # What the differences were measured on (files without the key: an ablation's unseen queries).
    measured_on = m.get("measured_on", f"split #{m['split']} unseen Rota. Acc.")
    out = []
    for key, v in m.get("trend", {}).items():
        if not isinstance(v, dict):
            continue
        pairs = v.get("pairs") or [v]
        for p in pairs:
            better, worse = p["compare"].split(" vs ")
            pv = None
            if paper_values and better in paper_values and worse in paper_values:
                pv = round(paper_values[better] - paper_values[worse], 2)
            cid = f"{prefix}:{key}" if len(pairs) == 1 else f"{prefix}:{key}:{better}>{worse}"
            out.append(record(cid, f"{better} beats {worse} ({measured_on}, points, paired)",
                              pv, p["diff_pts"], p["ci"], p["verdict"], **_seed_fields(p)))
    for label, c in (m.get("seeds") or {}).items():
        out.append(record(f"{prefix}:seed_noise:{label}", f"training noise: {c['compare']} ({measured_on}, points, "
                          "paired)", None, c["diff_pts"], c["ci"], MEASURED))
    return out


def screen_claims(d: Path, prefix: str = "screen") -> list[dict]:
    """Training-regime screens: each arm against the current recipe on held-out views of the split's SEEN objects
    (the deciding claims, as :func:`ablation_claims`), then on the split's unseen test objects (``afterwards``:
    reported, never used to choose; their verdicts are measured, not decisions)."""
    out = ablation_claims(d, prefix)
    m = _load(d / "metrics.json")
    for key, p in ((m or {}).get("afterwards") or {}).items():
        if not isinstance(p, dict):
            continue
        better, worse = p["compare"].split(" vs ")
        out.append(record(f"{prefix}_unseen:{key}", f"afterwards, not used to choose: {better} minus {worse} "
                          f"({m['afterwards_measured_on']}, points, paired)", None, p["diff_pts"], p["ci"], MEASURED,
                          **_seed_fields(p)))
    return out


def fast_claims(d: Path) -> list[dict]:
    """Fast retrieval vs greedy search, and coarse-to-fine vs fast (notebook 07's
    :class:`helpers.evaluation.search_results.SearchComparison`)."""
    r = SearchComparison.load(d)
    if r is None:
        return []
    fg, out = paper.FAST_VS_GREEDY, []
    a = r.agreement_30deg.get(FAST_ROW)
    if a:
        out.append(record("fast_greedy_agreement", f"share of unseen queries on which fast retrieval ({FAST_ROW}) "
                          "returns greedy's object and a rotation within 30 deg of greedy's (fraction)", None,
                          a["share"], a["ci95"], MEASURED))
    g, f = r.per_query.get(GREEDY_ROW), r.per_query.get(FAST_ROW)
    if g is None or f is None:
        return out
    split = ((_load(d / "run.json") or {}).get("parameters") or {}).get("split", "?")
    out.append(record("greedy_rot_acc", f"Rota. Acc. on unseen objects with greedy search (split #{split}, "
                      f"{r.bank.get('objects', '?')} objects x {r.bank.get('refs_per_object', '?')} references, %)",
                      fg["greedy"]["rot_acc"], *accuracy_ci(g), MEASURED))
    out.append(_diff_record("fast_minus_greedy", f"fast retrieval ({FAST_ROW}) costs unseen Rota. Acc. against "
                            "greedy search (fast minus greedy, points, paired)",
                            round(fg["fast"]["rot_acc"] - fg["greedy"]["rot_acc"], 2), paired_difference(g, f),
                            sign=-1))
    sp = r.speedup(GREEDY_ROW, FAST_ROW)
    out.append(record("fast_speedup", "fast retrieval is faster than greedy search (ratio of median seconds per "
                      "query, greedy / fast, same queries)",
                      round(fg["greedy"]["seconds_per_query"] / fg["fast"]["seconds_per_query"], 2), sp["ratio"],
                      sp["ci"], direction_verdict([sp["ci"][0] - 1.0, sp["ci"][1] - 1.0])))
    for stem, row in C2F_ROWS.items():
        pc = r.per_query.get(row)
        if pc is None:
            continue
        c = paired_difference(f, pc)
        extra: dict[str, Any] = {"speedup_over_fast": round(r.speedup(FAST_ROW, row)["ratio"], 2)}
        if row in r.c2f_agreement_with_fast:
            extra["unseen_same_reference_as_fast"] = round(float(r.c2f_agreement_with_fast[row]), 3)
        picked = (r.c2f_selection.get("chosen") or {}).get(C2F_FAMILIES[stem])
        if picked:  # the settings, chosen on held-out views of seen objects (helpers.search.c2f_select)
            extra["settings_chosen_on_seen_val"] = picked
        out.append(record(f"{stem}_minus_fast", f"{row} keeps fast retrieval's ({FAST_ROW}) unseen Rota. Acc. "
                          f"within {C2F_MARGIN_PTS:g} point (c2f minus fast, points, paired; holds when the whole "
                          "interval lies within the margin)", None, c["diff_pts"], c["ci"],
                          equivalence_verdict(c["ci"], C2F_MARGIN_PTS), **extra))
    return out


def reference_count_claims(d: Path) -> list[dict]:
    """More references per object raise accuracy (notebook 06): the fewest against the most for each search, and
    each step up in count, paired over the same queries. A table without a ``search`` column is greedy only."""
    m = _load(d / "metrics.json")
    if not m:
        return []
    t = pd.DataFrame(m["table"])
    if "search" not in t.columns:
        t["search"] = "greedy"
    out = []
    for how, sfx in (("greedy", ""), ("fast", "_fast")):
        counts = [int(c) for c in t.loc[t["search"] == how, "refs_per_object"]]
        frames = {c: _read_csv(d / f"per_query_{c}refs{sfx}.csv") for c in counts}
        if len(counts) < 2 or any(f is None for f in frames.values()):
            continue
        lo, hi = counts[0], counts[-1]
        out.append(_diff_record(f"refcount_accuracy_rises{sfx}", f"Rota. Acc. rises from {lo} to {hi} references "
                                f"per object ({how} search, points, paired)", None,
                                paired_difference(frames[lo], frames[hi])))
        for a, b in zip(counts[:-1], counts[1:]):
            out.append(_diff_record(f"refcount_step{sfx}:{a}-{b}", f"{how} search: {b} minus {a} references per "
                                    "object (points, paired)", None, paired_difference(frames[a], frames[b])))
    return out


def tless_claims(d: Path) -> list[dict]:
    """Claims of notebook 09 (T-LESS-like set) from its per-query tables: VSD accuracy of ours and of HOG,
    ours minus HOG and ours minus Global (paired over the same queries), Rota. Acc. at 30 deg beside them."""
    ours, hog, glob = (_read_csv(d / f"per_query_{m}.csv") for m in ("ours", "hog", "global"))
    if ours is None:
        return []
    t3 = paper.TLESS_TABLE3
    out = [record("tless_vsd_acc", "T-LESS-like Rota. Acc. (err_vsd <= 0.3, %), ours", t3["Ours (paper)"],
                  *accuracy_ci(ours, "vsd_ok"), MEASURED),
           record("tless_rot_acc", "T-LESS-like Rota. Acc. (error < 30 deg, %), ours", None,
                  *accuracy_ci(ours, "rot_ok"), MEASURED)]
    if hog is not None:
        v, ci = accuracy_ci(hog, "vsd_ok")
        out.append(record("tless_hog_vsd_acc", "T-LESS-like Rota. Acc. (err_vsd <= 0.3, %), HOG", t3["HOG"], v, ci,
                          calibration_verdict(v, TLESS_HOG_BAND)))
        out.append(_diff_record("tless_ours_minus_hog", "T-LESS-like: ours minus HOG (VSD accuracy, points)",
                                round(t3["Ours (paper)"] - t3["HOG"], 2), paired_difference(hog, ours, "vsd_ok")))
    if glob is not None:
        out.append(_diff_record("tless_ours_minus_global", "T-LESS-like: ours minus the Global descriptor (VSD "
                                "accuracy, points; paper column: ours minus NetVLAD, its global-descriptor baseline)",
                                round(t3["Ours (paper)"] - t3["NetVLAD"], 2), paired_difference(glob, ours, "vsd_ok")))
    return out


def gap_claims(d: Path) -> list[dict]:
    """Claims of notebook 11 (the gap account): each measured step's paired change on one split, the first and
    last measured levels, and the symmetry step on every split for notebook 03's answers."""
    m = _load(d / "metrics.json")
    if not m:
        return []
    sp, out = m["split"], []
    steps = [r for r in m["steps"] if r["verdict"] != "not measured"]
    for i, r in enumerate(steps):
        if i == 0:
            out.append(record(f"gap:{r['step']}:rot_acc", f"{r['label']}: Rota. Acc. (split #{sp} unseen, %)",
                              None, r["rot_acc"], [r["ci95_lo"], r["ci95_hi"]], MEASURED))
            continue
        out.append(record(f"gap:{r['step']}", f"{r['label']} (split #{sp} unseen, change in points, paired)", None,
                          r["change_pts"], [r["change_lo"], r["change_hi"]], r["verdict"]))
    if len(steps) > 1:
        last = steps[-1]
        out.append(record(f"gap:{last['step']}:rot_acc", f"after every measured step: Rota. Acc. (split #{sp} unseen, "
                          "%)", m.get("paper_rot_acc"), last["rot_acc"], [last["ci95_lo"], last["ci95_hi"]], MEASURED))
    for r in m.get("all_splits", []):
        key = r["answers"].lower().replace(" ", "_")
        out.append(record(f"gap:symmetries_all_splits:{key}", f"declared symmetries, {r['answers']} (notebook 03's "
                          f"answers, splits {r['splits']}; with minus without, points, paired)", None, r["change_pts"],
                          [r["change_lo"], r["change_hi"]], r["verdict"]))
    return out


class StaleResults(ValueError):
    """A notebook's result files cannot be read by this version of the code (written by another one)."""
