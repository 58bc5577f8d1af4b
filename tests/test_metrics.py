"""Rotation errors and per-object accuracy averaging."""

from __future__ import annotations

import numpy as np
import pytest

from helpers.core.rotations import discrete_symmetries_from_axis, haar_uniform, rot_z
from helpers.evaluation.metrics import (
    Record,
    evaluate_predictions,
    group_by_split,
    per_query_table,
    rotation_errors_deg,
)


def test_identity_and_known_angle():
    R = haar_uniform(5, seed=1)
    assert np.allclose(rotation_errors_deg(R, R), 0, atol=1e-5)
    assert rotation_errors_deg(R[0] @ rot_z(np.pi / 2), R[0])[0] == pytest.approx(90.0)
    assert rotation_errors_deg(rot_z(np.radians(30)) @ R, R) == pytest.approx(np.full(5, 30.0))


def test_symmetric():
    R = haar_uniform(4, seed=2)
    sym = discrete_symmetries_from_axis([0, 0, 1], 2)  # 180 degrees about model z
    Rz180 = rot_z(np.pi)
    assert np.allclose(rotation_errors_deg(R @ Rz180, R, sym), 0, atol=1e-5)
    assert np.allclose(rotation_errors_deg(R @ Rz180, R), 180, atol=1e-4)
    # 100 degrees about z is 80 from the symmetric pose.
    assert np.allclose(rotation_errors_deg(R @ rot_z(np.radians(100)), R, sym), 80)


def _rec(obj, pred, err_deg, sym=None, qid=None):
    R = haar_uniform(1, seed=int(10 * err_deg) + ord(obj[0]))[0]
    return Record(obj, pred, R, R @ rot_z(np.radians(err_deg)), sym, qid)


def test_per_object_averaging_by_hand():
    recs = [
        # "a": 4 queries; class right 3/4; rot right (class right and < 30): 2/4.
        _rec("a", "a", 10, qid=0), _rec("a", "a", 20, qid=1), _rec("a", "a", 50, qid=2), _rec("a", "b", 5, qid=3),
        # "b": 1 query, right.
        _rec("b", "b", 29.9),
        # "c": 2 queries, symmetric about z by 180: 175 deg is 5 deg off.
        _rec("c", "c", 175, sym=discrete_symmetries_from_axis([0, 0, 1], 2), qid=0),
        _rec("c", "a", 0, qid=1),
    ]
    per_obj, means = evaluate_predictions(recs)
    assert list(per_obj.index) == ["a", "b", "c"]
    assert per_obj.loc["a", "n"] == 4
    assert per_obj.loc["a", "class_acc"] == pytest.approx(75.0)
    assert per_obj.loc["a", "rot_acc"] == pytest.approx(50.0)
    # Median over all 4 queries of "a" (errors 5, 10, 20, 50), wrong class included.
    assert per_obj.loc["a", "median_err_deg"] == pytest.approx(15.0)
    assert per_obj.loc["b", "rot_acc"] == pytest.approx(100.0)
    assert per_obj.loc["c", "class_acc"] == pytest.approx(50.0)
    assert per_obj.loc["c", "rot_acc"] == pytest.approx(50.0)
    assert per_obj.loc["c", "median_err_deg"] == pytest.approx(2.5, abs=1e-4)
    # Unweighted over objects, not over queries.
    assert means["class_acc"] == pytest.approx((75 + 100 + 50) / 3)
    assert means["rot_acc"] == pytest.approx((50 + 100 + 50) / 3)
    assert means["n_objects"] == 3 and means["n_queries"] == 7

    # A tighter threshold changes rot_acc only.
    per_obj10, _ = evaluate_predictions(recs, threshold_deg=10)
    assert per_obj10.loc["a", "rot_acc"] == pytest.approx(0.0)
    assert per_obj10.loc["c", "rot_acc"] == pytest.approx(50.0)

    splits = group_by_split(per_obj, {"a": "seen", "b": "unseen", "c": "unseen"})
    assert splits.loc["seen", "rot_acc"] == pytest.approx(50.0)
    assert splits.loc["unseen", "rot_acc"] == pytest.approx(75.0)
    assert splits.loc["unseen", "n_objects"] == 2 and splits.loc["unseen", "n_queries"] == 3
    with pytest.raises(ValueError, match=r"\['c'\]"):
        group_by_split(per_obj, {"a": "seen", "b": "seen"})


def test_mapping_records_and_errors():
    R = np.eye(3)
    df = per_query_table([{"obj": "x", "pred_obj": "x", "R_gt": R, "R_est": R, "query_id": 7}])
    assert bool(df.loc[0, "rot_ok"]) and df.loc[0, "query_id"] == 7
    with pytest.raises(ValueError, match="missing keys.*R_est"):
        evaluate_predictions([{"obj": "x", "pred_obj": "x", "R_gt": R}])
    with pytest.raises(ValueError, match="no records"):
        evaluate_predictions([])
    with pytest.raises(ValueError, match="R_est has 2"):
        rotation_errors_deg(np.stack([R, R]), np.stack([R, R, R]))


