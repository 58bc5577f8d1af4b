"""What the notebooks' smoke runs (nbval, same pytest session) wrote: keys, types and value ranges of
their result files, read back as a reader of ``reports/smoke/`` would. Skipped when the notebooks did
not run in this session (e.g. ``pytest tests/``)."""

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from helpers.core.paths import REPO_ROOT
from helpers.data.manifest import load_manifest
from helpers.study.experiments import REGISTRY, build_claims
from helpers.evaluation.search_results import FAST_ROW, GREEDY_ROW, SearchComparison, variant_row
from helpers.evaluation.stats import VERDICTS

pytestmark = pytest.mark.after_notebooks
SMOKE = REPO_ROOT / "reports" / "smoke"


def _fresh(nb: str, session_start: float) -> Path:
    d = SMOKE / nb
    run = d / "run.json"
    if not run.exists() or run.stat().st_mtime < session_start:
        pytest.skip(f"notebooks/{nb}.ipynb did not run in this pytest session (no fresh {run})")
    return d


def _json(path: Path) -> dict:
    assert path.exists(), f"{path} was not written"
    return json.loads(path.read_text())


def _pct(x) -> bool:
    return isinstance(x, (int, float)) and 0.0 <= x <= 100.0


def _per_query(path: Path, cols=("obj", "query_id", "rot_ok", "class_ok")) -> pd.DataFrame:
    df = pd.read_csv(path)
    assert set(cols) <= set(df.columns), f"{path}: columns {list(df.columns)}"
    assert len(df) > 0 and df["rot_ok"].isin([0, 1, True, False]).all()
    assert (df["rot_ok"].astype(bool) <= df["class_ok"].astype(bool)).all(), f"{path}: rot_ok without class_ok"
    return df


NOTEBOOKS = [e.notebook for e in REGISTRY]


@pytest.mark.parametrize("nb", NOTEBOOKS)
def test_every_run_records_its_provenance(nb, session_start):
    r = _json(_fresh(nb, session_start) / "run.json")
    assert {"parameters", "seed", "git", "packages", "device"} <= set(r), sorted(r)
    assert str(r["parameters"]["out_dir"]).endswith(f"smoke/{nb}")
    assert r["git"].get("commit") and r["packages"].get("torch") and r["device"].get("resolved")


def test_render_summary(session_start):
    s = _json(_fresh("01_render", session_start) / "render_summary.json")
    assert len(s["objects"]) >= 13 and s["views"] > 0 and s["render_or_load_seconds"] >= 0
    assert s["gl_platform"] in ("egl", "osmesa") and s["reference_bytes_per_object"] > 0


def test_train_metrics(session_start):
    d = _fresh("02_train", session_start)
    m = _json(d / "train_metrics.json")
    assert m["split"] in (1, 2, 3) and m["train_images_per_s"] > 0
    assert m["parameters"]["encoder_decoder"] > 0 and m["parameters"]["fusion_head"] > 0
    u, ch = m["unseen_test"], m["chance"]
    assert _pct(u["rot_acc"]) and _pct(u["class_acc"]) and u["rot_acc"] <= u["class_acc"]
    assert 0 < ch["class_acc"] < 100 and 0 < ch["rot_acc"] < ch["class_acc"]
    steps = [h["global_step"] for h in _json(d / "history.json")["history"]]
    assert steps == sorted(steps) and steps[-1] > 0


def test_evaluation_metrics(session_start):
    d = _fresh("03_evaluate", session_start)
    m = _json(d / "metrics.json")
    t1 = pd.DataFrame(m["table1"])
    assert t1["split"].iloc[-1] == "mean" and all(_pct(v) for v in t1["unseen rot_acc"])
    assert {"method", "unseen rot_acc"} <= set(pd.DataFrame(m["table2"]).columns)
    assert m["protocol"]["method"] in ("fast", "greedy", "c2f") and m["protocol"]["threshold_deg"] == 30.0
    ours = _per_query(d / "per_query_ours.csv", ("split", "part", "obj", "query_id", "rot_ok", "class_ok"))
    assert set(ours["part"]) == {"unseen", "seen", "occluded"}
    # like with like: ours, HOG and Global with the protocol's search and the other one, rotations kept
    other = "greedy" if m["protocol"]["method"] == "fast" else "fast"
    for stem in ("ours", "hog", "global"):
        for f in (f"per_query_{stem}.csv", f"per_query_{stem}_{other}.csv"):
            pq = _per_query(d / f, ("obj", "query_id", "rot_ok", "class_ok", "R_est", "R_gt", "search"))
            assert set(pq["search"]) == {m["protocol"]["method"] if f == f"per_query_{stem}.csv" else other}, f
    like = pd.DataFrame(m["table1_searches"])
    assert set(like["method"]) == {"Ours", "HOG", "Global"} and set(like["search"]) == {"fast", "greedy"}
    held = _per_query(d / "per_query_held_out.csv", ("obj", "query_id", "rot_ok", "class_ok", "model"))
    assert set(held["obj"]).isdisjoint(ours["obj"])  # held-out objects belong to no split


@pytest.mark.parametrize("nb", ["04_ablation_scales", "05_ablation_fusion", "08_components"])
def test_ablation_metrics(nb, session_start):
    m = _json(_fresh(nb, session_start) / "metrics.json")
    table = pd.DataFrame(m["table"])
    assert len(table) >= 2 and table["variant"].is_unique and all(_pct(v) for v in table["unseen rot_acc"])
    claims = [p for v in m["trend"].values() if isinstance(v, dict) for p in (v.get("pairs") or [v])]
    assert claims, f"{nb}: no paired claim in its trend"
    for c in claims:
        assert c["verdict"] in VERDICTS and c["ci"][0] <= c["ci"][1] and math.isfinite(c["diff_pts"])
        assert set(c["compare"].split(" vs ")) <= set(table["variant"])


def test_reference_count_metrics(session_start):
    d = _fresh("06_reference_count", session_start)
    m = _json(d / "metrics.json")
    t = pd.DataFrame(m["table"])
    assert set(t["search"]) == {"greedy", "fast"} and (t["queries/s"] > 0).all()
    counts = list(t.loc[t["search"] == "greedy", "refs_per_object"])
    assert counts == sorted(counts) == list(t.loc[t["search"] == "fast", "refs_per_object"])
    assert counts[-1] > _json(d / "run.json")["parameters"]["n_references"]  # the sweep renders beyond the study's set
    fast = t[t["search"] == "fast"]
    assert (fast["k_ac"] == [max(1, round(c * 0.1024)) for c in fast["refs_per_object"]]).all()  # the paper's ratio
    for c in counts:
        _per_query(d / f"per_query_{c:.0f}refs.csv")
        _per_query(d / f"per_query_{c:.0f}refs_fast.csv")
    assert len(m["steps"]) == 2 * (len(counts) - 1) and len(m["fast_minus_greedy"]) == len(counts)


def test_fast_vs_greedy_results(session_start):
    r = SearchComparison.load(_fresh("07_fast_vs_greedy", session_start))
    assert r is not None and r.n_queries > 0 and r.bank["k_ac"] >= 1
    assert {GREEDY_ROW, FAST_ROW} <= set(r.per_query)
    for pq in r.per_query.values():
        assert len(pq) == r.n_queries and (pq["seconds"] > 0).all()
    assert r.median_seconds(GREEDY_ROW) > 0 and 0.0 <= r.agreement_30deg[FAST_ROW]["share"] <= 1.0
    params = _json(_fresh("07_fast_vs_greedy", session_start) / "run.json")["parameters"]
    for k, f in params["fast_variants"]:  # every named budget keeps its per-query file
        assert variant_row(k, f) in r.per_query


def test_gap_account(session_start):
    d = _fresh("11_gap_to_paper", session_start)
    m = _json(d / "metrics.json")
    steps = pd.DataFrame(m["steps"])
    assert list(steps["step"]) == ["earlier_protocol", "symmetries", "paper_search_ratio", "greedy",
                                   "dense_references", "not_measured"]
    measured = steps.iloc[1:-1]
    assert (measured["change_lo"] <= measured["change_pts"]).all() and (measured["change_pts"] <= measured["change_hi"]).all()
    # each change is the difference of the levels it joins, and the last row reaches the paper's number
    assert np.allclose(steps["rot_acc"].diff().iloc[1:-1], measured["change_pts"], atol=1e-6)
    assert steps["rot_acc"].iloc[-1] == m["paper_rot_acc"] and steps["verdict"].iloc[-1] == "not measured"
    assert steps["change_pts"].iloc[1] >= 0  # scoring the same answers under symmetries can only forgive errors
    assert (d / "gap_waterfall.png").stat().st_size > 5000
    ids = {c["id"] for c in build_claims(SMOKE)}
    assert {"gap:symmetries", "gap:dense_references", "gap:earlier_protocol:rot_acc"} <= ids


def test_tless_metrics(session_start):
    d = _fresh("09_tless", session_start)
    m = _json(d / "metrics.json")
    assert len(m["set"]["parts"]) >= 15 and _pct(m["hog_calibration"]["vsd_acc"])
    ours = _per_query(d / "per_query_ours.csv", ("obj", "query_id", "rot_ok", "class_ok", "vsd_ok"))
    assert ours["vsd_ok"].isin([0, 1, True, False]).all()


def test_explore_records_and_byo(session_start):
    d = _fresh("10_explore", session_start)
    e = _json(d / "explore.json")
    assert len(e["bank"]) == 13 and e["queries"] and 0 <= e["score_peak_within_30deg"] <= len(e["queries"])
    byo = _json(d / "byo.json")
    held = set(load_manifest().held_out_objects())
    assert byo["object"] in held and byo["model"] == e["model"]  # smoke: byo_model "" is the explorer's model
    R = np.array(byo["R_m2c"])
    assert R.shape == (3, 3) and np.allclose(R @ R.T, np.eye(3), atol=1e-4) and np.linalg.det(R) > 0
    assert 0.0 <= byo["error_deg"] <= 180.0
    # every photo answered from the mesh file, the first one being the drawn one
    per_q = _per_query(d / "byo_per_query.csv", ("obj", "query_id", "err_deg", "rot_ok", "score", "model"))
    assert len(per_q) == byo["n_queries"] >= 1 and set(per_q["obj"]) == {byo["object"]}
    assert per_q["err_deg"].iloc[0] == pytest.approx(byo["error_deg"])
    assert (per_q["rot_ok"] == (per_q["err_deg"] < byo["threshold_deg"])).all() and byo["threshold_deg"] == 30.0
    assert byo["rot_acc"] == pytest.approx(100 * per_q["rot_ok"].mean())
    assert byo["ci95"][0] <= byo["rot_acc"] <= byo["ci95"][1]
    assert byo["median_err_deg"] == pytest.approx(per_q["err_deg"].median()) and set(per_q["model"]) == {byo["model"]}


def test_budget_pairs(session_start):
    d = _fresh("13_budget", session_start)
    m = _json(d / "metrics.json")
    pq = _per_query(d / "per_query_budget.csv", ("split", "part", "obj", "query_id", "rot_ok", "budget", "steps"))
    assert [(p["shorter"], p["longer"]) for p in m["pairs"]] == [("split1", "split1-12k")]
    assert set(pq["budget"]) == {"shorter", "longer"} and set(pq["part"]) == {"unseen", "seen"}
    short, long = (pq[pq["budget"] == b].sort_values(["part", "query_id"]) for b in ("shorter", "longer"))
    assert list(short["query_id"]) == list(long["query_id"])  # the same queries for both budgets
    assert set(short["steps"]) == {4000} and set(long["steps"]) == {12000}
    ids = {c["id"]: c for c in build_claims(SMOKE)}
    assert {"longer_budget_unseen", "longer_budget_seen"} <= set(ids)
    assert all(_pct(v) for row in m["table"] for k, v in row.items() if k != "split")


def test_claims_of_the_smoke_reports(session_start):
    _fresh("03_evaluate", session_start)
    claims = build_claims(SMOKE)
    ids = [c["id"] for c in claims]
    assert len(ids) == len(set(ids)) and {"unseen_rot_acc", "hog_unseen_rot_acc", "ours_minus_hog"} <= set(ids)
    for c in claims:
        assert c["verdict"] in VERDICTS, c
        assert c["ci95"] is None or (c["ci95"][0] <= c["ci95"][1] and all(math.isfinite(v) for v in c["ci95"]))


def test_training_screens(session_start):
    d = _fresh("12_training_screens", session_start)
    m = _json(d / "metrics.json")
    assert {"table", "trend", "measured_on", "changes", "afterwards", "models"} <= set(m), sorted(m)
    assert m["changes"]["current"] == "the current recipe" and "->" in m["changes"]["avg-fusion"]
    for row in m["table"]:
        assert _pct(row["seen val rot_acc"]) and row["ci95 lo"] <= row["seen val rot_acc"] <= row["ci95 hi"]
    ids = {c["id"]: c for c in build_claims(SMOKE)}
    deciding = ids["screen:avg-fusion_beats_current"]
    assert deciding["verdict"] in VERDICTS and deciding["matched_seeds"] == 2
    assert deciding["seed_spread_pts"] is not None  # two seeds on each side: the spread enters the verdict
    assert ids["screen_unseen:avg-fusion_beats_current"]["verdict"] == "measured"  # reported, never a decision
    assert (d / "screens.png").stat().st_size > 0 and (d / "afterwards.csv").exists()


def test_extra_objects(session_start):
    d = _fresh("14_extra_objects", session_start)
    m = _json(d / "metrics.json")
    assert {"table", "trend", "curve", "counts", "validation_objects", "afterwards", "models"} <= set(m), sorted(m)
    assert m["counts"]["current"] == 0 and [r["N extra objects"] for r in m["curve"]] == sorted(m["counts"].values())
    extras = set(yaml.safe_load((REPO_ROOT / m["extras_file"]).read_text())["validation"])
    assert m["validation_objects"] and set(m["validation_objects"]) <= extras  # never a benchmark object
    for row in m["curve"]:
        assert _pct(row["validation rot_acc"]) and row["validation ci95 lo"] <= row["validation rot_acc"]
        assert _pct(row["unseen test rot_acc"])
    assert (d / "extra_objects.png").stat().st_size > 0 and (d / "curve.csv").exists()
