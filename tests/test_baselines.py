"""HOG baseline: descriptor sanity and drop-in use with the cache and retrieval."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from helpers.core.rotations import haar_uniform
from helpers.core.views import ObjectViews
from helpers.evaluation.baselines import HogModel, hog_descriptor
from helpers.search.features import FeatureCache, model_fingerprint
from helpers.search.retrieval import ReferenceBank, greedy_search, model_scorer

S = 64


def shapes() -> np.ndarray:
    """Five distinct simple images (N, S, S, 3) uint8."""
    ims = np.zeros((5, S, S, 3), np.uint8)
    cv2.rectangle(ims[0], (10, 20), (50, 40), (255, 255, 255), -1)
    cv2.circle(ims[1], (32, 32), 18, (200, 100, 50), -1)
    cv2.line(ims[2], (5, 5), (58, 58), (0, 255, 0), 4)
    cv2.fillPoly(ims[3], [np.array([[32, 5], [58, 58], [5, 58]])], (255, 0, 255))
    ims[4, :, ::8] = 255  # vertical stripes
    return ims


def test_descriptor_self_nearest():
    ims = shapes()
    d = hog_descriptor(ims)
    assert d.shape == (5, (S // 8 - 1) ** 2 * 4 * 9) and d.dtype == np.float32
    assert np.allclose(np.linalg.norm(d, axis=1), 1, atol=1e-5)
    sim = d @ d.T
    assert (np.argmax(sim, axis=1) == np.arange(5)).all()
    # Also robust to mild noise: a noisy copy is still nearest to its original.
    rng = np.random.default_rng(0)
    noisy = np.clip(ims.astype(int) + rng.integers(-10, 11, ims.shape), 0, 255).astype(np.uint8)
    assert (np.argmax(hog_descriptor(noisy) @ d.T, axis=1) == np.arange(5)).all()


def test_rotation_changes_descriptor():
    rect = shapes()[:1]
    rot = cv2.warpAffine(rect[0], cv2.getRotationMatrix2D((S / 2, S / 2), 45, 1.0), (S, S))[None]
    d0, d1 = hog_descriptor(rect), hog_descriptor(rot)
    assert float((d0 @ d1.T)[0, 0]) < 0.9


def test_bad_input():
    with pytest.raises(ValueError, match="uint8"):
        hog_descriptor(np.zeros((1, S, S, 3), np.float32))
    with pytest.raises(ValueError, match="smaller than one block"):
        hog_descriptor(np.zeros((1, 8, 8, 3), np.uint8))


def test_plugs_into_cache_and_retrieval(tmp_path):
    ims = shapes()
    model = HogModel()
    x = torch.from_numpy(ims).permute(0, 3, 1, 2).float() / 255
    f = model.encode(x)
    assert f.shape == (5, hog_descriptor(ims).shape[1], 1)
    np.testing.assert_allclose(f[:, :, 0].numpy(), hog_descriptor(ims), atol=1e-6)
    s = model.score(f, f, chunk=2)
    assert s.shape == (5, 5) and torch.allclose(torch.diagonal(s), torch.ones(5), atol=1e-5)

    views = ObjectViews("shapes", ims, haar_uniform(5, seed=0).astype(np.float32))
    key = model_fingerprint(model)
    assert key == model_fingerprint(HogModel()) and key != model_fingerprint(HogModel.__new__(HogModel))
    feats = FeatureCache(tmp_path).get_or_build(model, key, views, "shapes64", batch=2, progress=False)
    bank = ReferenceBank([feats], views.rotations, ["shapes"], k_ac=3)
    p = greedy_search(f[3], bank, model_scorer(model))
    assert (p.obj_index, p.ref_index) == (0, 3)
