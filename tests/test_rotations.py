import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from helpers.core import rotations as rot


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


def test_symmetric_error_and_inplane_label():
    S = rot.discrete_symmetries_from_axis([0, 0, 1], 2)
    R = rot.haar_uniform(10, 0)
    flipped = R @ S[1]
    np.testing.assert_allclose(rot.symmetric_geodesic_deg(flipped, R, S), 0.0, atol=1e-5)
    assert np.all(rot.symmetric_geodesic_deg(flipped, R, None) > 179)
    R2 = rot.inplane_rotate_label(R, 30.0)
    np.testing.assert_allclose(rot.geodesic_deg(R2, R), 30.0, atol=1e-6)


# ------------------------------------------------------------------ continuous symmetries, exact


def _rx(deg):
    from scipy.spatial.transform import Rotation
    return Rotation.from_euler("x", deg, degrees=True).as_matrix()


def _rz(deg):
    from scipy.spatial.transform import Rotation
    return Rotation.from_euler("z", deg, degrees=True).as_matrix()


def test_continuous_symmetry_hand_computed_cases():
    from helpers.core.rotations import Symmetries, symmetric_geodesic_deg

    cyl = Symmetries(np.eye(3)[None], np.array([[0.0, 0.0, 2.0]]))  # axis z, not unit on purpose
    eye = np.eye(3)[None]
    # A turn about the symmetry axis is no error at all.
    assert symmetric_geodesic_deg(_rz(37.0)[None], eye, cyl) == pytest.approx([0.0], abs=1e-6)
    # Rz(a) Rx(b) vs the identity: the best turn about z leaves exactly b.
    assert symmetric_geodesic_deg((_rz(50.0) @ _rx(20.0))[None], eye, cyl) == pytest.approx([20.0], abs=1e-6)
    # With a 180-degree flip about x as well (a plain cylinder): Rx(195) is 15 deg from the flip.
    flip = Symmetries(np.stack([np.eye(3), _rx(180.0)]), np.array([[0.0, 0.0, 1.0]]))
    assert symmetric_geodesic_deg(_rx(195.0)[None], eye, flip) == pytest.approx([15.0], abs=1e-6)
    assert symmetric_geodesic_deg(_rx(195.0)[None], eye, cyl) == pytest.approx([165.0], abs=1e-6)
    # Two non-parallel axes: a sphere, every rotation is symmetric.
    sphere = Symmetries(np.eye(3)[None], np.eye(3)[:2])
    assert symmetric_geodesic_deg(_rx(123.0)[None], eye, sphere) == pytest.approx([0.0])


def test_continuous_symmetry_is_the_limit_of_fine_discretisation():
    from helpers.core.rotations import Symmetries, haar_uniform, symmetric_geodesic_deg

    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    flip = Symmetries(np.stack([np.eye(3), _rx(180.0)]), axis[None])
    t = np.radians(np.arange(0, 360, 0.01))
    from scipy.spatial.transform import Rotation
    cont = Rotation.from_rotvec(t[:, None] * axis).as_matrix()
    fine = np.concatenate([cont @ d for d in flip.discrete])  # R_cont @ R_disc, as BOP composes them
    R_est, R_gt = haar_uniform(50, seed=1), haar_uniform(50, seed=2)
    exact = symmetric_geodesic_deg(R_est, R_gt, flip)
    approx = np.array([symmetric_geodesic_deg(R_est[i:i + 1], R_gt[i:i + 1], fine)[0] for i in range(50)])
    assert (exact <= approx + 1e-6).all() and np.abs(approx - exact).max() < 0.01
    # Near the orbit (small true errors), the old 10-degree discretisation over-estimates by up to
    # 5 degrees; the exact form does not.
    turns = Rotation.from_rotvec(np.radians(5.0 + 10.0 * np.arange(50))[:, None] * axis).as_matrix()
    perp = np.cross(axis, [1.0, 0.0, 0.0])
    tilt = Rotation.from_rotvec(np.radians(2.0) * perp / np.linalg.norm(perp)).as_matrix()
    R_est = R_gt @ turns @ tilt  # 2 deg off the orbit, perpendicular to the axis
    exact = symmetric_geodesic_deg(R_est, R_gt, flip)
    assert exact == pytest.approx(np.full(50, 2.0), abs=1e-6)
    coarse = np.concatenate([Rotation.from_rotvec(np.radians(np.arange(0, 360, 10.0))[:, None] * axis).as_matrix() @ d
                             for d in flip.discrete])
    old = np.array([symmetric_geodesic_deg(R_est[i:i + 1], R_gt[i:i + 1], coarse)[0] for i in range(50)])
    assert (old >= exact - 1e-6).all() and (old - exact).max() > 3.0
