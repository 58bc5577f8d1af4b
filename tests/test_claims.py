"""claims.json: records computed from per-query files, with object-weighted bootstrap intervals."""

import json

import numpy as np
import pandas as pd
import pytest

from helpers.study.experiments import build_claims, write_claims
from helpers.evaluation.search_results import SearchComparison
from helpers.evaluation.stats import accuracy_ci, direction_verdict, paired_difference

KEYS = {"id", "claim", "paper", "ours", "ci95", "verdict"}


def _pq(rng, split_objects: dict[int, list[str]], p_ok: dict[str, float], n: int = 60, part: str = "unseen"):
    rows = []
    for s, objs in split_objects.items():
        for o in objs:
            ok = rng.random(n) < p_ok[o]
            for i in range(n):
                rows.append({"split": s, "part": part, "obj": o, "pred_obj": o, "query_id": f"{o}:{i}",
                             "class_ok": True, "err_deg": 5.0 if ok[i] else 90.0, "rot_ok": bool(ok[i])})
    return pd.DataFrame(rows)


def _comparison(base, rows: dict, **extra) -> SearchComparison:
    """Notebook 07's files for ``rows``: row name -> (per-query table, seconds of every query)."""
    table = pd.DataFrame([{"method": k, "median s/query": s} for k, (_, s) in rows.items()])
    r = SearchComparison(table, {k: df.assign(seconds=s) for k, (df, s) in rows.items()}, {}, {}, **extra,
                         n_queries=len(next(iter(rows.values()))[0]))
    (base / "07_fast_vs_greedy").mkdir(parents=True)
    r.save(base / "07_fast_vs_greedy")
    return r


def test_accuracy_is_mean_over_splits_of_mean_over_objects():
    # Split 1: two objects at 100 % and 0 %; split 2: one object at 100 %. Object weights
    # 1/4, 1/4, 1/2 -> 75 %, whatever the query counts.
    df = pd.DataFrame({"split": [1] * 3 + [1] * 5 + [2] * 2, "obj": ["a"] * 3 + ["b"] * 5 + ["c"] * 2,
                       "rot_ok": [1] * 3 + [0] * 5 + [1] * 2})
    v, ci = accuracy_ci(df)
    assert v == pytest.approx(75.0)
    assert ci == pytest.approx([75.0, 75.0])  # no within-object variance: no spread


def test_paired_difference_detects_a_real_gap_and_not_a_fake_one():
    rng = np.random.default_rng(0)
    objs = {1: ["a", "b"], 2: ["c", "d"]}
    base = _pq(rng, objs, {o: 0.3 for o in "abcd"}, n=120)
    better = base.copy()
    flip = (~better["rot_ok"]) & (np.random.default_rng(1).random(len(better)) < 0.5)
    better.loc[flip, "rot_ok"] = True  # about +35 points on the same queries
    c = paired_difference(base, better)
    assert c["diff_pts"] > 25 and c["ci"][0] > 0 and direction_verdict(c["ci"]) == "holds"
    assert direction_verdict(paired_difference(better, base)["ci"]) == "reversed"
    c0 = paired_difference(base, base)
    assert c0["diff_pts"] == 0 and c0["ci"] == [0.0, 0.0] and direction_verdict(c0["ci"]) == "within noise"
    with pytest.raises(ValueError, match="must hold the same queries"):
        paired_difference(base, better.iloc[:-3])


def test_claims_file_from_a_report_folder(tmp_path):
    rng = np.random.default_rng(2)
    splits = {1: ["a", "b"], 2: ["c"], 3: ["d", "e"]}
    p = {o: 0.6 for o in "abcde"}
    ev = tmp_path / "03_evaluate"
    ev.mkdir()
    ours = pd.concat([_pq(rng, splits, p, part="unseen"), _pq(rng, splits, {o: 0.8 for o in "abcde"}, part="seen"),
                      _pq(rng, splits, {o: 0.3 for o in "abcde"}, part="occluded")])
    ours.assign(search="fast").to_csv(ev / "per_query_ours.csv", index=False)
    hog = _pq(rng, splits, {o: 0.33 for o in "abcde"})
    hog.assign(search="fast").to_csv(ev / "per_query_hog.csv", index=False)
    # the other search, like with like: ours and HOG greedy on the same unseen queries
    _pq(rng, splits, {o: 0.7 for o in "abcde"}, part="unseen").assign(search="greedy").to_csv(
        ev / "per_query_ours_greedy.csv", index=False)
    _pq(rng, splits, {o: 0.4 for o in "abcde"}).assign(search="greedy").to_csv(ev / "per_query_hog_greedy.csv",
                                                                             index=False)
    glob_ = _pq(rng, {1: ["a", "b"]}, {o: 0.5 for o in "ab"})
    glob_.to_csv(ev / "per_query_global.csv", index=False)
    held = _pq(rng, {1: ["f", "g"]}, {"f": 0.9, "g": 0.1}).assign(model="all")
    held.to_csv(ev / "per_query_held_out.csv", index=False)
    byo = pd.DataFrame({"obj": "f", "query_id": range(40), "err_deg": np.r_[np.full(10, 5.0), np.full(30, 170.0)],
                        "rot_ok": [True] * 10 + [False] * 30, "model": "all"})
    (tmp_path / "10_explore").mkdir()
    byo.to_csv(tmp_path / "10_explore" / "byo_per_query.csv", index=False)  # bring your own: notebook 10
    fusion = tmp_path / "05_ablation_fusion"
    fusion.mkdir()
    (fusion / "metrics.json").write_text(json.dumps({"table": [], "split": 1, "trend": {
        "adaptive_beats_avg": {"point_estimate_agrees": True, "compare": "adaptive vs avg", "diff_pts": 4.0,
                               "ci": [-1.0, 9.0], "seeds": [1, 1], "matched_seeds": 1, "per_seed_diff_pts": [4.0],
                               "seed_spread_pts": None, "verdict": "within noise"}}}))
    path = write_claims(tmp_path)
    claims = json.loads(path.read_text())
    ids = {c["id"]: c for c in claims}
    for c in claims:
        assert KEYS <= set(c)
    for k in ("hog_unseen_rot_acc", "unseen_rot_acc", "unseen_class_acc", "seen_rot_acc",
              "occluded_unseen_rot_acc", "ours_minus_hog", "ours_minus_global", "fusion:adaptive_beats_avg"):
        assert k in ids, k
    u = ids["unseen_rot_acc"]
    assert u["ci95"][0] <= u["ours"] <= u["ci95"][1] and 45 < u["ours"] < 75
    assert ids["unseen_class_acc"]["ours"] == 100.0
    assert ids["hog_unseen_rot_acc"]["verdict"] == "calibrated"  # ~33 %, inside 28-38
    assert "fast search, the study's" in ids["hog_unseen_rot_acc"]["claim"]
    assert ids["ours_minus_hog"]["verdict"] == "holds" and ids["ours_minus_hog"]["ci95"][0] > 0
    assert "same search" in ids["ours_minus_hog"]["claim"]  # fast against fast
    g = ids["ours_minus_hog_greedy"]  # greedy against greedy, paired: about 70 - 40 points
    assert "greedy search, same search" in g["claim"] and g["verdict"] == "holds" and 20 < g["ours"] < 40
    assert ids["hog_unseen_rot_acc_greedy"]["verdict"] == "measured" and 33 < ids["hog_unseen_rot_acc_greedy"]["ours"] < 47
    assert "#1" in ids["ours_minus_global"]["claim"]  # Global ran on split 1 only
    h = ids["held_out_rot_acc"]  # the named model on objects no split trains on, with its interval
    assert "(all;" in h["claim"] and h["ci95"][0] <= h["ours"] <= h["ci95"][1] and 35 < h["ours"] < 65
    b = ids["byo_rot_acc"]  # one object's photos from its mesh file: 10 of 40 within 30 deg, the model named
    assert b["ours"] == 25.0 and b["ci95"][0] < 25.0 < b["ci95"][1] and "f's 40 test photos" in b["claim"]
    assert "(all;" in b["claim"]
    assert ids["fusion:adaptive_beats_avg"]["paper"] == pytest.approx(89.55 - 80.9)
    assert ids["fusion:adaptive_beats_avg"]["verdict"] == "within noise"
    assert build_claims(tmp_path / "missing") == []
    assert not any(k.startswith("longer_budget") for k in ids)  # one budget: no budget claim


def test_budget_claims_pair_the_longer_and_the_shorter_zoo_budget(tmp_path):
    """Notebook 13: each split's shorter- and longer-budget models on the same unseen / seen queries, paired."""
    rng = np.random.default_rng(3)
    splits = {1: ["a", "b"], 2: ["c"]}
    bd = tmp_path / "13_budget"
    bd.mkdir()
    long = pd.concat([_pq(rng, splits, {o: 0.6 for o in "abc"}, part="unseen"),
                      _pq(rng, splits, {o: 0.8 for o in "abc"}, part="seen")])
    short = long.copy()
    short.loc[short["part"] == "unseen", "rot_ok"] = False  # the longer budget answers more unseen queries
    pd.concat([short.assign(budget="shorter", steps=4000), long.assign(budget="longer", steps=12000)]).to_csv(
        bd / "per_query_budget.csv", index=False)
    ids = {c["id"]: c for c in build_claims(tmp_path)}
    u, s = ids["longer_budget_unseen"], ids["longer_budget_seen"]
    assert "12000-step" in u["claim"] and "4000-step" in u["claim"] and "mean of 2 splits" in u["claim"]
    from helpers.evaluation.stats import accuracy_ci

    assert u["verdict"] == "holds" and u["ours"] == pytest.approx(accuracy_ci(long[long["part"] == "unseen"])[0], abs=0.01)
    assert s["ours"] == 0.0 and s["verdict"] == "within noise"  # the same answers on seen objects
    (bd / "per_query_budget.csv").unlink()
    assert not any(c["id"].startswith("longer_budget") for c in build_claims(tmp_path))



def test_ablation_claims_carry_the_seed_aware_verdict_and_paired_refcount_and_fast(tmp_path):
    rng = np.random.default_rng(5)
    fusion = tmp_path / "05_ablation_fusion"
    fusion.mkdir()
    pair = {"point_estimate_agrees": True, "compare": "adaptive vs avg", "diff_pts": 4.0, "ci": [1.0, 7.0],
            "seeds": [2, 2], "matched_seeds": 2, "per_seed_diff_pts": [6.0, 2.0], "seed_spread_pts": 5.0,
            "verdict": "within seed spread"}
    (fusion / "metrics.json").write_text(json.dumps({"table": [], "split": 1, "trend": {"adaptive_beats_avg": pair},
                                                     "seeds": {"avg": {"compare": "avg seed 2 vs seed 1",
                                                                       "diff_pts": 5.0, "ci": [2.0, 8.0]}}}))
    refc = tmp_path / "06_reference_count"
    refc.mkdir()
    few = _pq(rng, {1: ["a", "b"]}, {"a": 0.2, "b": 0.2}, n=200)
    many = few.copy()
    many["rot_ok"] = many["rot_ok"] | (rng.random(len(many)) < 0.3)
    few.to_csv(refc / "per_query_32refs.csv", index=False)
    many.to_csv(refc / "per_query_512refs.csv", index=False)
    (refc / "metrics.json").write_text(json.dumps({"table": [
        {"refs_per_object": 32, "unseen rot_acc": 100 * few["rot_ok"].mean()},
        {"refs_per_object": 512, "unseen rot_acc": 100 * many["rot_ok"].mean()}]}))
    _comparison(tmp_path, {"greedy": (few, 1.0), "fast (converge)": (few, 0.1)})
    ids = {c["id"]: c for c in build_claims(tmp_path)}
    a = ids["fusion:adaptive_beats_avg"]
    assert a["verdict"] == "within seed spread" and a["seed_spread_pts"] == 5.0 and a["seeds"] == [2, 2]
    assert ids["fusion:seed_noise:avg"]["verdict"] == "measured" and ids["fusion:seed_noise:avg"]["ours"] == 5.0
    r = ids["refcount_accuracy_rises"]
    assert r["verdict"] == "holds" and r["ci95"][0] > 0 and "paired" in r["claim"] and "greedy" in r["claim"]
    assert ids["refcount_step:32-512"]["ours"] == r["ours"]  # two counts: the one step is the whole rise
    assert "refcount_accuracy_rises_fast" not in ids  # no fast rows in this table
    g = ids["greedy_rot_acc"]  # the greedy row's own accuracy with its interval
    assert g["ours"] == pytest.approx(100 * few["rot_ok"].mean()) and g["ci95"][0] <= g["ours"] <= g["ci95"][1]
    f = ids["fast_minus_greedy"]
    assert f["ours"] == 0.0 and f["verdict"] == "within noise"
    sp = ids["fast_speedup"]  # 10x on every query: the interval is [10, 10]
    assert sp["ours"] == 10.0 and sp["ci95"] == [10.0, 10.0] and sp["verdict"] == "holds"
    assert "c2f_minus_fast" not in ids  # notebook 07 without coarse-to-fine rows


def test_refcount_claims_step_by_step_for_both_searches(tmp_path):
    rng = np.random.default_rng(6)
    refc = tmp_path / "06_reference_count"
    refc.mkdir()
    base = _pq(rng, {1: ["a", "b"]}, {"a": 0.2, "b": 0.2}, n=200)
    rows = []
    for k, c in enumerate((128, 512, 2048)):
        for how, sfx in (("greedy", ""), ("fast", "_fast")):
            f = base.copy()
            f["rot_ok"] = f["rot_ok"] | (rng.random(len(f)) < 0.25 * k)  # each step adds about a quarter
            f.to_csv(refc / f"per_query_{c}refs{sfx}.csv", index=False)
            rows.append({"refs_per_object": c, "search": how, "unseen rot_acc": 100 * f["rot_ok"].mean()})
    (refc / "metrics.json").write_text(json.dumps({"table": rows}))
    ids = {c["id"]: c for c in build_claims(tmp_path)}
    for sfx in ("", "_fast"):
        assert ids[f"refcount_accuracy_rises{sfx}"]["verdict"] == "holds"
        for step in ("128-512", "512-2048"):
            c = ids[f"refcount_step{sfx}:{step}"]
            assert c["verdict"] == "holds" and 5 < c["ours"] < 40, (sfx, step, c)


def test_c2f_claims_need_the_whole_interval_within_one_point(tmp_path):
    rng = np.random.default_rng(9)
    f = _pq(rng, {1: ["a", "b"]}, {"a": 0.4, "b": 0.4}, n=300)
    worse = f.copy()
    worse["rot_ok"] = worse["rot_ok"] & (rng.random(len(worse)) > 0.3)  # loses ~12 points
    _comparison(tmp_path, {"greedy": (f, 1.0), "fast (converge)": (f, 0.2), "coarse-to-fine (converge)": (worse, 0.05),
                           "coarse-to-fine halving (converge)": (f, 0.1)},
                c2f_agreement_with_fast={"coarse-to-fine (converge)": 0.7, "coarse-to-fine halving (converge)": 1.0},
                c2f_selection={"min_agreement": 0.99, "chosen": {"halving": {"coarse_k": 8, "refine_objects": 2,
                                                                            "agreement_with_fast": 1.0, "met": True}}})
    ids = {c["id"]: c for c in build_claims(tmp_path)}
    c, h = ids["c2f_minus_fast"], ids["c2f_halving_minus_fast"]
    # the unseen agreement and the settings chosen on seen views travel with the claim (only where recorded)
    assert c["unseen_same_reference_as_fast"] == 0.7 and "settings_chosen_on_seen_val" not in c
    assert h["settings_chosen_on_seen_val"]["coarse_k"] == 8 and h["unseen_same_reference_as_fast"] == 1.0
    assert c["verdict"] == "reversed" and c["ci95"][1] < -1 and c["speedup_over_fast"] == 4.0
    assert h["ours"] == 0.0 and h["ci95"] == [0.0, 0.0] and h["verdict"] == "holds"
    assert h["speedup_over_fast"] == 2.0


def test_baselines_pair_on_the_splits_ours_ran(tmp_path):
    """Notebook 03 with splits [1]: HOG ran on all three splits (its calibration line keeps them), ours on
    split #1 only, so ours minus HOG pairs split #1's queries."""
    rng = np.random.default_rng(4)
    ev = tmp_path / "03_evaluate"
    ev.mkdir()
    _pq(rng, {1: ["a", "b"]}, {"a": 0.7, "b": 0.7}, part="unseen").to_csv(ev / "per_query_ours.csv", index=False)
    hog = _pq(rng, {1: ["a", "b"], 2: ["c"], 3: ["d"]}, {o: 0.3 for o in "abcd"})
    hog.to_csv(ev / "per_query_hog.csv", index=False)
    ids = {c["id"]: c for c in build_claims(tmp_path)}
    assert "splits #1,#2,#3, %)" in ids["hog_unseen_rot_acc"]["claim"]
    assert "splits #1, points, paired)" in ids["ours_minus_hog"]["claim"]
    assert ids["ours_minus_hog"]["ours"] == pytest.approx(
        paired_difference(hog[hog["split"] == 1], pd.read_csv(ev / "per_query_ours.csv"))["diff_pts"], abs=0.01)
