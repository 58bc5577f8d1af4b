"""helpers.evaluation.stats: paired differences, seed-aware claims and the one verdict vocabulary."""

import numpy as np
import pandas as pd
import pytest

from helpers.evaluation.stats import (HOLDS, REVERSED, VERDICTS, WITHIN_NOISE, WITHIN_SEED_SPREAD, chain, claim,
                                      direction_verdict, equivalence_verdict, paired_difference,
                                      ratio_of_medians_ci, seed_differences, seed_spread, share_ci,
                                      unpaired_difference)
from helpers.study.protocols.variants import claims_table


def _pq(correct, objs=None, n_obj: int = 4) -> pd.DataFrame:
    correct = np.asarray(correct, dtype=bool)
    n = len(correct)
    objs = objs if objs is not None else [f"o{i % n_obj}" for i in range(n)]
    return pd.DataFrame({"query_id": [f"q{i}" for i in range(n)], "obj": objs, "rot_ok": correct,
                         "class_ok": np.ones(n, bool), "err_deg": np.where(correct, 5.0, 90.0)})


def test_paired_difference_separates_signal_from_noise():
    objs = ["a"] * 50 + ["b"] * 50
    base = [False] * 100
    better = [i % 2 == 0 for i in range(100)]  # +50 points, every changed query in one direction
    r = paired_difference(_pq(base, objs), _pq(better, objs))
    assert r["diff_pts"] == pytest.approx(50.0) and r["ci"][0] > 30 and r["n_queries"] == 100
    assert direction_verdict(r["ci"]) == HOLDS
    assert direction_verdict(paired_difference(_pq(better, objs), _pq(base, objs))["ci"]) == REVERSED
    # One query of 100 flips: a 1-point difference, which the interval does not distinguish from 0.
    one = list(base)
    one[3] = True
    r = paired_difference(_pq(base, objs), _pq(one, objs))
    assert r["diff_pts"] == pytest.approx(1.0) and direction_verdict(r["ci"]) == WITHIN_NOISE
    # Objects weigh equally: a gain on the 10-query object counts as much as on the 90-query one.
    objs2 = ["a"] * 10 + ["b"] * 90
    gain_small = [i < 10 for i in range(100)]
    assert paired_difference(_pq(base, objs2), _pq(gain_small, objs2))["diff_pts"] == pytest.approx(50.0)
    with pytest.raises(ValueError, match="same queries"):
        paired_difference(_pq(base, objs), _pq(base[:99], objs[:99]))


def test_unpaired_difference_and_shares():
    rng = np.random.default_rng(4)
    a, b = _pq(rng.random(300) < 0.2), _pq(rng.random(300) < 0.6)
    r = unpaired_difference(a, b)
    assert 30 < r["diff_pts"] < 50 and r["ci"][0] > 20
    s = share_ci(np.array([1, 1, 0, 1]))
    assert s["share"] == 0.75 and s["n"] == 4 and 0 <= s["ci95"][0] <= 0.75 <= s["ci95"][1] <= 1
    assert np.isnan(share_ci(np.array([]))["share"])


def test_ratio_of_medians_is_paired():
    slow = np.linspace(1.0, 2.0, 50)
    r = ratio_of_medians_ci(slow, slow / 4)
    assert r["ratio"] == pytest.approx(4.0) and r["ci"] == pytest.approx([4.0, 4.0])
    with pytest.raises(ValueError, match="one length"):
        ratio_of_medians_ci(slow, slow[:3])


def test_verdict_rules():
    assert direction_verdict([1.0, 3.0]) == HOLDS and direction_verdict([-3.0, -1.0]) == REVERSED
    assert direction_verdict([-1.0, 3.0]) == WITHIN_NOISE
    assert direction_verdict([-3.0, -1.0], sign=-1) == HOLDS  # "b loses to a"
    assert direction_verdict([1.0, 3.0], diff=2.0, seed_spread=2.5) == WITHIN_SEED_SPREAD
    assert direction_verdict([1.0, 3.0], diff=2.0, seed_spread=1.5) == HOLDS
    assert equivalence_verdict([-0.5, 0.8], 1.0) == HOLDS
    assert equivalence_verdict([-3.0, -1.5], 1.0) == REVERSED
    assert equivalence_verdict([-1.5, 0.5], 1.0) == WITHIN_NOISE
    assert {HOLDS, REVERSED, WITHIN_NOISE, WITHIN_SEED_SPREAD} <= set(VERDICTS)


def test_claims_detect_a_real_gap_and_tables_show_it():
    rng = np.random.default_rng(0)
    worse = rng.random(400) < 0.2
    better = worse | (rng.random(400) < 0.4)
    pq = {"a": _pq(worse), "b": _pq(better), "same": _pq(worse.copy())}
    c = claim(pq, "a", "b")
    assert c["point_estimate_agrees"] and c["verdict"] == HOLDS and c["ci"][0] > 0
    assert claim(pq, "a", "same")["verdict"] == WITHIN_NOISE
    assert claim(pq, "a", "missing") is None
    ch = chain(pq, ["a", "b"])
    assert ch["point_estimate_agrees"] and ch["verdict"] == HOLDS and len(ch["pairs"]) == 1
    assert chain(pq, ["b", "a"])["verdict"] == REVERSED
    t = claims_table({"gap": c, "note": "text is skipped"})
    assert list(t["claim"]) == ["gap"] and t["verdict"][0] == HOLDS


def test_seed_spread_enters_the_verdict():
    rng = np.random.default_rng(3)
    n = 800
    worse = rng.random(n) < 0.3
    better = worse | (rng.random(n) < 0.1)          # about +7 points on the same queries
    noisy = worse ^ (rng.random(n) < 0.05)          # a second seed of `worse`: training noise
    pq = {"w": [_pq(worse), _pq(noisy)], "b": [_pq(better)]}
    spread = seed_spread({k: [100 * t["rot_ok"].mean() for t in v] for k, v in pq.items()})
    assert spread == pytest.approx(100 * abs(noisy.mean() - worse.mean()))
    assert seed_spread({"a": [3.0], "b": [4.0]}) is None
    c = claim(pq, "w", "b", seed_spread=spread)
    # Matched seeds: the one-seed variant meets only the first seed of the other.
    assert c["ci"][0] > 0 and c["seeds"] == [2, 1] and c["matched_seeds"] == 1 and len(c["per_seed_diff_pts"]) == 1
    assert c["diff_pts"] == pytest.approx(100 * (better.mean() - worse.mean()), abs=0.3)
    assert c["verdict"] == (HOLDS if abs(c["diff_pts"]) > spread else WITHIN_SEED_SPREAD)
    # Two seeds on both sides: the difference of the accuracies averaged over the matched seeds.
    better2 = noisy | (rng.random(n) < 0.1)
    c2 = claim({"w": [_pq(worse), _pq(noisy)], "b": [_pq(better), _pq(better2)]}, "w", "b")
    assert c2["matched_seeds"] == 2 and len(c2["per_seed_diff_pts"]) == 2
    want = 100 * ((better.mean() + better2.mean()) - (worse.mean() + noisy.mean())) / 2
    assert c2["diff_pts"] == pytest.approx(want, abs=0.3)
    assert claim(pq, "w", "b", seed_spread=50.0)["verdict"] == WITHIN_SEED_SPREAD
    assert claim(pq, "b", "w", seed_spread=0.0)["verdict"] == REVERSED
    assert claim(pq, "w", "b")["seed_spread_pts"] is None  # not measured: the interval alone
    d = seed_differences(pq)
    assert list(d) == ["w"] and d["w"]["diff_pts"] == pytest.approx(100 * (noisy.mean() - worse.mean()), abs=2)
    t = claims_table({"c": c})
    assert "seed spread (pts)" in t.columns and t["verdict"][0] == c["verdict"]
