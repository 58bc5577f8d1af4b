"""Symmetry-aware training (issue #44, screen a): positives and loss weights under declared symmetries."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from helpers.core.rotations import Symmetries, geodesic_deg, haar_uniform, nearest, nearest_symmetric
from helpers.core.views import ObjectViews
from helpers.study.pipeline import _train_key
from helpers.training.batches import _Batcher
from helpers.training.losses import pair_weights
from helpers.training.train import train
from test_train import tiny_cfg, tiny_data

HALF_TURN_Z = np.diag([-1.0, -1.0, 1.0])


def test_nearest_symmetric_finds_the_equivalent_view():
    refs = haar_uniform(64, np.random.default_rng(0))
    q = (refs[5] @ HALF_TURN_Z)[None]  # the same image as reference 5 for a half-turn-symmetric object
    idx, ang = nearest_symmetric(q, refs, np.stack([np.eye(3), HALF_TURN_Z]))
    assert idx[0] == 5 and ang[0] == pytest.approx(0.0, abs=1e-6)
    plain_idx, plain_ang = nearest(q, refs)
    assert plain_idx[0] != 5 and plain_ang[0] > 0.1  # symmetry-blind: some other, wrong-looking reference
    # No group: identical to nearest; a continuous axis: any turn about it is free.
    assert np.array_equal(nearest_symmetric(q, refs, None)[0], plain_idx)
    spun = (refs[7] @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]))[None]  # 90 deg about z
    idx, ang = nearest_symmetric(spun, refs, Symmetries(np.eye(3)[None], np.array([[0.0, 0, 1]])))
    assert idx[0] == 7 and ang[0] == pytest.approx(0.0, abs=1e-6)


def test_pair_weights_use_the_symmetric_geodesic_for_symmetric_objects_only():
    rng = np.random.default_rng(1)
    q = haar_uniform(2, rng)
    r = np.stack([q[0] @ HALF_TURN_Z, q[1] @ HALF_TURN_Z, q[0]])
    q_obj, r_obj = np.array([0, 1]), np.array([0, 1, 1])
    groups = [np.stack([np.eye(3), HALF_TURN_Z]), None]  # object 0 symmetric, object 1 not
    blind = pair_weights(q_obj, q, r_obj, r).numpy()
    aware = pair_weights(q_obj, q, r_obj, r, groups).numpy()
    assert blind[0, 0] == pytest.approx(1.0, abs=1e-5)  # a half-turn away: the heaviest negative
    assert aware[0, 0] == pytest.approx(0.0, abs=1e-5)  # the same view: no longer a negative
    # Object 1 declares nothing: its weights are unchanged; other objects' columns stay 1.
    assert aware[1, 1] == pytest.approx(blind[1, 1]) and aware[1, 2] == pytest.approx(blind[1, 2])
    assert aware[0, 1] == 1.0 and aware[0, 2] == 1.0 and aware[1, 0] == 1.0
    want = geodesic_deg(q[1][None], r[1][None])[0] / 180.0
    assert aware[1, 1] == pytest.approx(want, abs=1e-5)


def _symmetric(views: ObjectViews) -> ObjectViews:
    return ObjectViews(views.name, views.images, views.rotations, views.masks, views.kind,
                       np.stack([np.eye(3), HALF_TURN_Z]), dict(views.meta))


def test_batcher_positive_is_the_nearest_equivalent_reference():
    refs, queries, _, _ = tiny_data()
    refs = {n: _symmetric(v) for n, v in refs.items()}
    cfg = tiny_cfg()
    aug = replace(cfg.augment, enabled=False)
    names = sorted(refs)
    for aware in (False, True):
        b = _Batcher(names, refs, queries, aug, 64, symmetry_aware=aware)
        picks = np.arange(len(b))
        _, q_obj, q_rot, r_obj, r_rot = b.make(picks, np.random.default_rng(0))
        pos = r_rot[:len(picks)]
        sym = refs[names[0]].symmetries
        for o in range(len(names)):
            sel = q_obj == o
            best = (nearest_symmetric if aware else lambda a, c, _s: nearest(a, c))(q_rot[sel], refs[names[o]].rotations,
                                                                                   sym)[1]
            got = np.deg2rad(geodesic_deg(q_rot[sel], pos[sel]) if not aware else
                             np.array([min(geodesic_deg(qq[None], (p @ s)[None])[0] for s in sym)
                                       for qq, p in zip(q_rot[sel], pos[sel])]))
            assert np.allclose(got, best, atol=1e-5)
        assert (b.symmetries[0] is not None) == aware


def test_symmetry_aware_run_trains_and_keeps_earlier_run_keys(tmp_path):
    refs, queries, val_refs, val_queries = tiny_data()
    refs = {n: _symmetric(v) for n, v in refs.items()}
    cfg = tiny_cfg(epochs=1, symmetry_aware=True)
    res = train(cfg, refs, queries, val_refs, val_queries, tmp_path)
    assert np.isfinite(res.history[-1]["train_loss"])
    ck = torch.load(res.last_path, weights_only=True)
    assert ck["config"]["symmetry_aware"] is True
    # The default leaves the run-folder key of every earlier run as it was; switching it on changes it.
    assert "symmetry_aware" not in _train_key(tiny_cfg())
    assert _train_key(cfg)["symmetry_aware"] is True


def test_resume_accepts_a_checkpoint_written_before_the_field(tmp_path):
    data = tiny_data()
    cfg = tiny_cfg(epochs=1)
    train(cfg, *data, tmp_path)
    ck = torch.load(tmp_path / "last.pt", weights_only=False)
    ck["config"].pop("symmetry_aware")  # as a checkpoint of an earlier version
    torch.save(ck, tmp_path / "last.pt")
    res = train(replace(cfg, epochs=2), *data, tmp_path)
    assert [h["epoch"] for h in res.history] == [1, 2]
    with pytest.raises(ValueError, match="symmetry_aware"):
        train(replace(cfg, epochs=3, symmetry_aware=True), *data, tmp_path)
