"""Training-regime screens (issue #44): a model is scored at the input side it was trained at, on the same views."""

import numpy as np
import pytest

from helpers.core.configs import DataConfig
from helpers.core.views import ObjectViews
from helpers.study.pipeline import prepare_data
from helpers.study.protocols import screens
from helpers.study.protocols.screens import data_at_sizes, evaluate_at_sizes, model_sizes, render_sides
from helpers.study.protocols.variants import Trained


def test_another_side_renders_the_same_views(tmp_path):
    """Screen c compares a 128 px network with the 64 px one: each is scored on the SAME views at its own side."""
    cfg = DataConfig(image_size=64, render_size=96, n_references=2, n_train_queries=1, n_val_queries=1,
                     n_test_queries=3, seed=0, workers=0, cache_dir=str(tmp_path))
    data = prepare_data(cfg, ["duck"], occluded=False, training=False)
    assert not data.train_q and not data.val_q and not data.clean_q  # evaluation alone renders no training views
    both = data_at_sizes(data, {128: 192}, ["duck"])
    assert sorted(both) == [64, 128] and both[64] is data
    big = both[128]
    assert big.cfg.image_size == 128 and big.cfg.render_size == 192  # the render side its models were trained at
    for kind in ("refs", "test_q"):
        small, large = getattr(data, kind)["duck"], getattr(big, kind)["duck"]
        assert large.images.shape[1:3] == (128, 128)
        np.testing.assert_allclose(large.rotations, small.rotations, atol=1e-6)
        # Same scene and draws: the 128 px view, halved, is the 64 px view up to resampling and sensor noise.
        halved = large.images.reshape(len(large), 64, 2, 64, 2, 3).mean(axis=(2, 4))
        assert np.abs(halved - small.images.astype(float)).mean() < 6.0  # measured about 2; two views: about 42
    # Without the afterwards part no test query is rendered at the other side (the references are all it needs).
    assert not data_at_sizes(data, {128: 192}, ["duck"], test=False)[128].test_q
    # The tolerance is far below what two different views differ by.
    assert np.abs(data.test_q["duck"].images[0].astype(float) - data.test_q["duck"].images[1]).mean() > 20.0


def _trained(side: int, render: int = 0) -> Trained:
    return Trained(None, None, {"zoo": f"m{side}", "zoo_entry": {"data": {"image_size": side,
                                                                           "render_size": render or side * 3 // 2}}})


def test_one_arm_is_one_side_and_views_must_match():
    assert model_sizes({"current": [_trained(64)] * 2, "128px": [_trained(128)] * 2}) == {"current": 64,
                                                                                           "128px": 128}
    with pytest.raises(ValueError, match=r"mixed's models take different input sides \[64, 128\]"):
        model_sizes({"mixed": [_trained(64), _trained(128)]})
    assert render_sides({"current": [_trained(64)], "128px": [_trained(128)]}) == {64: 96, 128: 192}
    with pytest.raises(ValueError, match=r"renders 128 px crops from 160 px, another model of that side from 192"):
        render_sides({"a": [_trained(128)], "b": [_trained(128, 160)]})
    R = np.repeat(np.eye(3, dtype=np.float32)[None], 2, axis=0)
    v64 = ObjectViews("duck", np.zeros((2, 64, 64, 3), np.uint8), R, kind="query")
    turned = R.copy()
    turned[1] = np.diag([-1.0, -1.0, 1.0])
    v128 = ObjectViews("duck", np.zeros((2, 128, 128, 3), np.uint8), turned, kind="query")
    trained = {"current": [_trained(64)], "128px": [_trained(128)]}
    with pytest.raises(ValueError, match=r"views of 'duck' at 128 px are not those at 64 px"):
        evaluate_at_sizes(trained, {}, {64: {"duck": v64}, 128: {"duck": v128}}, ["duck"])
    with pytest.raises(ValueError, match=r"views of 'duck' at 128 px are not those at 64 px"):
        evaluate_at_sizes(trained, {}, {64: {"duck": v64}, 128: {}}, ["duck"])


def test_each_label_is_scored_on_the_data_and_views_of_its_side(monkeypatch):
    seen = []
    monkeypatch.setattr(screens, "evaluate_queries", lambda t, data, queries, bench, device: seen.append(
        (list(t), data, queries)) or {k: [k] for k in t})
    R = np.repeat(np.eye(3, dtype=np.float32)[None], 2, axis=0)
    q = {s: {"duck": ObjectViews("duck", np.zeros((2, s, s, 3), np.uint8), R, kind="query")} for s in (64, 128)}
    trained = {"current": [_trained(64)], "128px": [_trained(128)], "avg": [_trained(64)]}
    out = evaluate_at_sizes(trained, {64: "data64", 128: "data128"}, q, ["duck"])
    assert list(out) == ["current", "128px", "avg"]  # the labels' order is kept
    assert [(labels, data, queries is q[s]) for (labels, data, queries), s in zip(seen, (64, 128, 64))] == [
        (["current"], "data64", True), (["128px"], "data128", True), (["avg"], "data64", True)]


def test_an_arm_may_take_another_side_the_baseline_may_not(monkeypatch):
    """Notebook 12 scores an arm at its own side (screen c); its baseline, and notebook 14's arms, take the data's."""
    import helpers.study.experiments.training_screens as ts
    import helpers.study.parameter_rules as rules
    from helpers.study.parameters import ParameterError

    zoo = dict(rules.zoo_entries())
    zoo["big"] = {**zoo["split1"], "data": {**zoo["split1"]["data"], "image_size": 128}}
    monkeypatch.setattr(rules, "zoo_entries", lambda: zoo)
    monkeypatch.setattr(ts, "zoo_entries", lambda: zoo)
    P = {"image_size": 64, "split": 1, "baseline": ["split1"], "arms": [["128px", "big"]]}
    ts.check_arms("12_training_screens", P, arms_any_side=True)
    with pytest.raises(ParameterError, match=r"a model taking image_size=64 px crops \(big takes 128\)"):
        ts.check_arms("14_extra_objects", P)
    with pytest.raises(ParameterError, match=r"a model taking image_size=64 px crops \(big takes 128\)"):
        ts.check_arms("12_training_screens", {**P, "baseline": ["big"], "arms": []}, arms_any_side=True)
