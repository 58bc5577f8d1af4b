"""The T-LESS-like set (helpers.data.tless) and its protocol (helpers.study.protocols.tless) on a tiny configuration."""

from __future__ import annotations

import numpy as np
import pytest

from helpers.core.configs import TlessConfig
from helpers.core.fileio import DamagedEntry
from helpers.data.gl import render_raw
from helpers.data.tless import load_tless
from helpers.evaluation.baselines import HogModel
from helpers.evaluation.tless_scoring import rotation_errors, vsd_errors
from helpers.study.protocols.tless import evaluate_tless

pytestmark = pytest.mark.gl
TINY = TlessConfig(n_references=12, n_queries=2)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    cache = tmp_path_factory.mktemp("tless")
    return load_tless(TINY, cache=cache, progress=False), cache


def test_the_set_holds_every_part_with_queries_depth_and_references(tiny):
    ts, _ = tiny
    assert len(ts.names) >= 15
    for n in ts.names:
        q, r = ts.queries[n], ts.refs[n]
        assert q.images.shape == (2, 64, 64, 3) and q.masks.shape == (2, 64, 64) and r.images.shape == (12, 64, 64, 3)
        assert ts.depth[n].shape == (2, 96, 96) and np.allclose(r.rotations, ts.refs[ts.names[0]].rotations)
        assert q.masks.mean(axis=(1, 2)).min() > 0.05  # the part is visible in its crop
        assert np.allclose(q.symmetries[0], np.eye(3))


def test_scene_depth_agrees_with_the_part_where_it_is_visible(tiny):
    """Where the part is in front, the scene's depth is the part's own render at its label (same camera)."""
    ts, _ = tiny
    name = "hex_nut"
    scene = ts.depth[name][0].astype(np.float32)
    own = render_raw(ts.parts[name], ts.queries[name].rotations[0].astype(np.float64), ts.cfg.render_config())[1]
    front = (own > 0) & (np.abs(scene - own) < 0.003)
    assert front.sum() >= 0.5 * (own > 0).sum()  # at least the kept visible share (min_visible)
    assert (scene[own > 0] <= own[own > 0] + 0.003).all()  # nothing of the scene lies behind the part's surface


def test_vsd_and_rotation_errors_of_the_labels_are_zero(tiny):
    ts, _ = tiny
    for name in ("box_two_holes", "ring"):
        R = ts.queries[name].rotations
        assert np.allclose(vsd_errors(ts, name, R), 0.0)
        assert np.allclose(rotation_errors(ts, name, R), 0.0, atol=0.05)  # float32 labels: arccos near 1
        assert vsd_errors(ts, name, R[::-1].copy(), indices=[1, 0]).max() == 0.0
    with pytest.raises(ValueError, match="2 estimates for 1 queries"):
        vsd_errors(ts, "ring", R, indices=[0])


def test_a_second_load_reuses_the_files_and_damage_is_named(tiny):
    ts, cache = tiny
    again = load_tless(TINY, cache=cache, progress=False)
    assert again.key == ts.key and np.array_equal(again.queries["plug"].images, ts.queries["plug"].images)
    f = cache / "tless" / ts.key / "plug.images.npy"
    f.write_bytes(f.read_bytes()[:-10])
    with pytest.raises(DamagedEntry, match="plug.images.npy"):
        load_tless(TINY, cache=cache, progress=False)


def test_hog_on_the_set_reports_vsd_and_rotation_accuracy(tmp_path):
    ts = load_tless(TINY, cache=tmp_path, progress=False)
    res = evaluate_tless(HogModel(), ts, device="cpu", cache=tmp_path, progress=False)
    pq = res["per_query"]
    assert len(pq) == 2 * len(ts.names) and {"vsd", "vsd_ok", "rot_ok", "class_ok"} <= set(pq.columns)
    assert ((pq["vsd"] >= 0) & (pq["vsd"] <= 1)).all()
    assert (pq.loc[~pq["class_ok"], "vsd"] == 1.0).all() and not pq.loc[~pq["class_ok"], "vsd_ok"].any()
    assert 0 <= res["means"]["vsd_acc"] <= 100 and res["means"]["n_objects"] == len(ts.names)


def _tless_parameters(**over):
    from helpers.study.parameters import declared_parameters, notebook_path

    P = declared_parameters(notebook_path("09_tless"))
    P.update(over)
    return P


@pytest.mark.parametrize("over, match", [
    ({"model": "no-such-model"}, r"'model' expects a zoo model among"),
    ({"global_model": "nope/best.pt"}, r"'global_model' expects a zoo model name or an existing checkpoint"),
    ({"min_visible": 0.0}, r"'min_visible' expects a share in \(0, 1\]"),
    ({"n_queries": 0}, r"'n_queries' expects an int >= 1"),
    ({"bop_root": "no/such/folder"}, r"'bop_root' expects '' or a BOP dataset folder"),
])
def test_tless_parameters_are_checked_before_any_work(over, match):
    from helpers.study.parameters import ParameterError, check_values

    with pytest.raises(ParameterError, match=match):
        check_values("09_tless", _tless_parameters(**over))
    check_values("09_tless", _tless_parameters())
