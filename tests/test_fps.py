"""Farthest point sampling on SO(3) (helpers.search.fps): spread, exact traces, kernel = numpy."""

import numpy as np
import pytest

from helpers.core import rotations as rot
from helpers.search import fps


def test_fps_spreads_points():
    R = rot.haar_uniform(4000, seed=0)
    idx = fps.farthest_point_sampling(R, 64)
    assert len(set(idx.tolist())) == 64
    fps_min = rot.pairwise_geodesic(R[idx], R[idx])[~np.eye(64, dtype=bool)].min()
    rnd = np.random.default_rng(0).choice(4000, 64, replace=False)
    rnd_min = rot.pairwise_geodesic(R[rnd], R[rnd])[~np.eye(64, dtype=bool)].min()
    assert fps_min > 2 * rnd_min
    # Coverage: every rotation lies closer to the FPS set than the FPS set's own spacing.
    _, cover = rot.nearest(R, R[idx])
    assert cover.max() <= fps_min + 1e-9
    # Restricted pool.
    sub = fps.farthest_point_sampling(R, 10, candidates=np.arange(100, 200))
    assert np.all((sub >= 100) & (sub < 200))


def test_fps_traces_are_exact_in_any_order():
    """The quantised layout makes traces order-independent, so ties break alike everywhere."""
    L = fps.exact_traces_layout(rot.haar_uniform(500, seed=3))
    v = L[:, 7]
    forward = sum(L[c] * v[c] for c in range(9))
    backward = sum(L[c] * v[c] for c in reversed(range(9)))
    np.testing.assert_array_equal(v @ L, forward)
    np.testing.assert_array_equal(forward, backward)
    assert np.abs(L.T.reshape(-1, 3, 3) - rot.haar_uniform(500, seed=3)).max() <= fps.TRACE_QUANTUM


def _fps_numpy(R, k, start=0, candidates=None, monkeypatch=None):
    monkeypatch.setattr(fps, "_fps_kernel", lambda: None)
    out = fps.farthest_point_sampling(R, k, start=start, candidates=candidates)
    monkeypatch.undo()
    return out


@pytest.mark.skipif(fps._fps_kernel() is None, reason="no C++ toolchain: the FPS kernel cannot build here")
def test_fps_kernel_matches_numpy(monkeypatch):
    R = rot.haar_uniform(3000, seed=1)
    for k, start, cand in [(64, 0, None), (256, 17, np.arange(500, 2900)), (2, 5, np.arange(10))]:
        np.testing.assert_array_equal(fps.farthest_point_sampling(R, k, start=start, candidates=cand),
                                      _fps_numpy(R, k, start, cand, monkeypatch))
    # A symmetric set (90-degree turns about the axes, composed) is full of exact ties.
    turns = [rot.rot_z(a) for a in (0, np.pi / 2, np.pi, 3 * np.pi / 2)]
    swap = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], dtype=float)
    grid = np.stack([a @ np.linalg.matrix_power(swap, p) @ b.T for a in turns for b in turns for p in range(3)])
    np.testing.assert_array_equal(fps.farthest_point_sampling(grid, 20),
                                  _fps_numpy(grid, 20, monkeypatch=monkeypatch))
