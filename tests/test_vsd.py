"""err_vsd (helpers.evaluation.vsd) on hand-computed depth images, and on renders of a symmetric object."""

from __future__ import annotations

import numpy as np
import pytest

from helpers.evaluation.vsd import depth_to_distance, visible_mask, vsd_accuracy, vsd_error

K = np.array([[100.0, 0, 10], [0, 100.0, 10], [0, 0, 1]])  # 20 x 20 image, principal point at (10, 10)


def _square(x0: int, y0: int, side: int, z: float, size: int = 20) -> np.ndarray:
    d = np.zeros((size, size))
    d[y0:y0 + side, x0:x0 + side] = z
    return d


def test_distance_image_from_depth():
    d = np.full((20, 20), 2.0)
    dist = depth_to_distance(d, K)
    assert dist[10, 10] == pytest.approx(2.0)  # on the optical axis distance = depth
    assert dist[10, 13] == pytest.approx(2.0 * np.sqrt(1 + 0.03 ** 2))  # 3 px right: slope 3/100
    assert dist[14, 6] == pytest.approx(2.0 * np.sqrt(1 + 0.04 ** 2 + 0.04 ** 2))
    assert depth_to_distance(np.zeros((20, 20)), K).max() == 0
    with pytest.raises(ValueError, match="K must be a"):
        depth_to_distance(d, np.eye(2))


def test_identical_poses_give_zero():
    gt = _square(5, 5, 8, 1000.0)
    assert vsd_error(gt, gt, gt, K, delta=15, tau=20) == 0.0


def test_disjoint_silhouettes_give_one():
    gt, est = _square(0, 0, 5, 1000.0), _square(12, 12, 5, 1000.0)
    assert vsd_error(est, gt, gt, K, delta=15, tau=20) == 1.0
    assert vsd_error(np.zeros((20, 20)), np.zeros((20, 20)), gt, K, 15, 20) == 1.0  # nothing visible at all


def test_shifted_square_by_hand():
    """8x8 squares shifted by 2 columns: union 80 px, intersection 48 px of equal depth -> err = 32 / 80."""
    gt, est = _square(4, 4, 8, 1000.0), _square(6, 4, 8, 1000.0)
    assert vsd_error(est, gt, gt, K, delta=15, tau=20) == pytest.approx(32 / 80)
    # The same silhouettes 30 mm apart in depth: every intersection pixel now costs 1 too.
    assert vsd_error(est + (est > 0) * 30.0, gt, gt, K, delta=50, tau=20) == pytest.approx(1.0)
    # ... within tau they do not; tlinear charges them 10/20 each: (32 + 48 * 0.5) / 80 (up to the rays' slope:
    # 10 mm of depth is at most 10 * sqrt(1 + 2 * 0.06^2) mm of distance here).
    est10 = est + (est > 0) * 10.0
    assert vsd_error(est10, gt, gt, K, delta=50, tau=20) == pytest.approx(32 / 80)
    assert vsd_error(est10, gt, gt, K, delta=50, tau=20, cost="tlinear") == pytest.approx((32 + 24) / 80, abs=1e-3)


def test_occluded_pixels_are_not_counted():
    """An occluder 200 mm in front hides the left half of the object in the test image: an estimate that differs
    only there is not penalised (both masks exclude it); missing test depth counts as visible."""
    gt = _square(4, 4, 8, 1000.0)
    test = gt.copy()
    test[:, :8] = np.where(gt[:, :8] > 0, 800.0, 0)  # occluder over columns 4-7 of the object
    est = gt.copy()
    est[4:12, 4:8] = 1100.0  # wrong only behind the occluder
    vis = visible_mask(depth_to_distance(test, K), depth_to_distance(gt, K), 15)
    assert vis.sum() == 32 and not vis[:, :8].any()
    assert vsd_error(est, gt, test, K, delta=15, tau=20) == 0.0
    no_depth = np.where(np.arange(20)[None, :] < 8, 0.0, gt)  # the sensor saw nothing there
    assert vsd_error(gt, gt, no_depth, K, 15, 20) == 0.0
    assert vsd_error(est, gt, no_depth, K, 15, 20) == pytest.approx(32 / 64)


def test_an_estimate_behind_the_test_surface_keeps_the_gt_visible_pixels():
    """The toolkit's rule: pixels visible at the true pose that the estimate covers stay in the estimate's mask,
    even if the estimate lies more than delta behind the test surface (10 mm behind, delta 5, tau 20)."""
    gt = _square(4, 4, 8, 1000.0)
    est = gt + (gt > 0) * 10.0
    assert vsd_error(est, gt, gt, K, delta=5, tau=20) == 0.0  # without the rule the union would be gt alone: 1.0
    vis_est_alone = visible_mask(depth_to_distance(gt, K), depth_to_distance(est, K), 5)
    assert not vis_est_alone.any()


def test_bad_arguments_are_named():
    gt = _square(4, 4, 8, 1000.0)
    with pytest.raises(ValueError, match="cost must be one of"):
        vsd_error(gt, gt, gt, K, 15, 20, cost="linear")
    with pytest.raises(ValueError, match="differ in size"):
        vsd_error(gt[:10], gt, gt, K, 15, 20)
    with pytest.raises(ValueError, match="delta and tau must be > 0"):
        vsd_error(gt, gt, gt, K, 0, 20)
    with pytest.raises(ValueError, match="must be in the depth images' unit"):
        vsd_error(gt / 1000, gt / 1000, gt / 1000, K, 15, 20)  # mm thresholds on metre depth
    assert vsd_accuracy(np.array([0.1, 0.3, 0.31, 0.9])) == 50.0


@pytest.mark.gl
def test_a_cylinder_turned_about_its_axis_scores_about_zero(tmp_path):
    """Rendered depth (metres) of a cylinder at R and at R @ rot(axis, 37 deg): the same visible surface."""
    import trimesh
    from scipy.spatial.transform import Rotation

    from helpers.core.configs import RenderConfig
    from helpers.data.gl import render_raw
    from helpers.study.byo import custom_object

    path = tmp_path / "cylinder.ply"
    trimesh.creation.cylinder(radius=0.5, height=1.2, sections=128).export(path)
    obj = custom_object(path)
    cfg = RenderConfig(size=64, render_size=96)
    R = Rotation.from_euler("xyz", [50, 20, 10], degrees=True).as_matrix()
    spun = R @ Rotation.from_rotvec([0, 0, np.radians(37)]).as_matrix()  # the cylinder's axis is its z
    tilted = R @ Rotation.from_rotvec([np.radians(40), 0, 0]).as_matrix()
    d_gt = render_raw(obj, R, cfg)[1]
    d_spun, d_tilted = render_raw(obj, spun, cfg)[1], render_raw(obj, tilted, cfg)[1]
    K = cfg.intrinsics()
    assert (d_gt > 0).sum() > 500
    assert vsd_error(d_spun, d_gt, d_gt, K, delta=0.015, tau=0.02) < 0.03
    assert vsd_error(d_tilted, d_gt, d_gt, K, delta=0.015, tau=0.02) > 0.3
