import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from helpers import rotations as rot


def test_haar_uniform_is_orthonormal_and_deterministic():
    R = rot.haar_uniform(500, seed=3)
    assert R.shape == (500, 3, 3)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_array_equal(R, rot.haar_uniform(500, seed=3))
    assert not np.allclose(R, rot.haar_uniform(500, seed=4))


def test_haar_uniform_angle_distribution():
    # Haar measure: the rotation angle has density (1 - cos t) / pi on [0, pi].
    ang = rot.geodesic(rot.haar_uniform(20000, seed=0), np.eye(3))
    hist, edges = np.histogram(ang, bins=10, range=(0, np.pi))
    cdf = lambda t: (t - np.sin(t)) / np.pi  # noqa: E731
    expected = 20000 * np.diff(cdf(edges))
    assert np.all(np.abs(hist - expected) < 5 * np.sqrt(expected) + 5)


def test_geodesic_known_angles():
    Rz90 = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    assert rot.geodesic_deg(np.eye(3), np.eye(3)) == pytest.approx(0.0, abs=1e-6)
    assert rot.geodesic_deg(np.eye(3), Rz90) == pytest.approx(90.0)
    Rx180 = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    assert rot.geodesic_deg(np.eye(3), Rx180) == pytest.approx(180.0)
    A, B = rot.haar_uniform(5, 1), rot.haar_uniform(7, 2)
    P = rot.pairwise_geodesic(A, B)
    assert P.shape == (5, 7)
    assert P[2, 3] == pytest.approx(rot.geodesic(A[2], B[3]))


def test_nearest_matches_bruteforce():
    Q, R = rot.haar_uniform(50, 1), rot.haar_uniform(3000, 2)
    idx, ang = rot.nearest(Q, R, chunk=700)
    P = rot.pairwise_geodesic(Q, R)
    np.testing.assert_array_equal(idx, P.argmin(1))
    np.testing.assert_allclose(ang, P.min(1), atol=1e-6)


def test_fps_spreads_points():
    R = rot.haar_uniform(4000, seed=0)
    idx = rot.farthest_point_sampling(R, 64)
    assert len(set(idx.tolist())) == 64
    fps_min = rot.pairwise_geodesic(R[idx], R[idx])[~np.eye(64, dtype=bool)].min()
    rnd = np.random.default_rng(0).choice(4000, 64, replace=False)
    rnd_min = rot.pairwise_geodesic(R[rnd], R[rnd])[~np.eye(64, dtype=bool)].min()
    assert fps_min > 2 * rnd_min
    # Coverage: every rotation lies closer to the FPS set than the FPS set's own spacing.
    _, cover = rot.nearest(R, R[idx])
    assert cover.max() <= fps_min + 1e-9
    # Restricted pool.
    sub = rot.farthest_point_sampling(R, 10, candidates=np.arange(100, 200))
    assert np.all((sub >= 100) & (sub < 200))


def test_symmetric_error_and_inplane_label():
    S = rot.discrete_symmetries_from_axis([0, 0, 1], 2)
    R = rot.haar_uniform(10, 0)
    flipped = R @ S[1]
    np.testing.assert_allclose(rot.symmetric_geodesic_deg(flipped, R, S), 0.0, atol=1e-5)
    assert np.all(rot.symmetric_geodesic_deg(flipped, R, None) > 179)
    R2 = rot.inplane_rotate_label(R, 30.0)
    np.testing.assert_allclose(rot.geodesic_deg(R2, R), 30.0, atol=1e-6)
