"""The LineMOD-like (tabletop) query sampler: viewpoints inside the stated range, labels
that match renders, and the named query styles."""

import numpy as np
import pytest

from helpers.core.configs import QueryStyle, RenderConfig
from helpers.core.rotations import geodesic_deg
from helpers.data.render import query_style, render_query, render_reference
from helpers.data.tabletop import elevation_of, look_at_w2c, sample_viewpoint, stable_poses

RC = RenderConfig(size=48, render_size=72)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


@pytest.fixture(scope="module")
def mug(manifest):
    from helpers.data.meshes import load_object

    return load_object("mug", manifest)


def test_look_at_camera_is_upright_and_looks_at_the_origin():
    for elev, azim in ((20.0, 0.0), (60.0, 135.0), (89.0, -70.0)):
        R = look_at_w2c(elev, azim, 0.0)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
        e, a = np.radians(elev), np.radians(azim)
        cam = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        assert np.allclose(R[2], -cam, atol=1e-12)  # optical axis points at the origin
        assert R[1] @ np.array([0, 0, 1.0]) < 0  # image y points down the world's up axis
        assert abs(R[0, 2]) < 1e-12  # no roll: image x stays horizontal
    # Roll turns the picture about the optical axis only.
    d = look_at_w2c(40.0, 10.0, 12.0) @ look_at_w2c(40.0, 10.0, 0.0).T
    assert np.isclose(geodesic_deg(d, np.eye(3)), 12.0) and np.allclose(d[2], [0, 0, 1], atol=1e-12)


def test_viewpoints_stay_inside_the_stated_range(mug):
    style = query_style("linemod")
    R_rest, prob = stable_poses(mug)
    assert len(prob) >= 1 and np.isclose(prob.sum(), 1.0)
    rng = np.random.default_rng(0)
    elevs = []
    for _ in range(200):
        vp = sample_viewpoint(mug, rng, style.elevation_deg, style.roll_deg)
        lo, hi = style.elevation_deg
        assert lo <= vp.elevation_deg <= hi and abs(vp.roll_deg) <= style.roll_deg
        # The label itself implies that elevation: the table normal, seen from the camera.
        up_model = vp.R_m2w.T @ np.array([0, 0, 1.0])
        assert abs(elevation_of(vp.R_m2c, up_model) - vp.elevation_deg) < 1e-6
        # The object rests on one of its stable poses (turned about the table normal only).
        assert any(np.allclose((vp.R_m2w @ R.T)[2], [0, 0, 1], atol=1e-9) for R in R_rest)
        elevs.append(vp.elevation_deg)
    assert np.ptp(elevs) > 0.8 * (style.elevation_deg[1] - style.elevation_deg[0])  # the range is used


@pytest.mark.gl
def test_tabletop_labels_match_reference_renders(mug, manifest):
    """A silhouette rendered as a reference at the query's label overlaps the query's object
    mask (IoU > 0.8), and clearly better than at a rotation 40 degrees away."""
    from scipy.spatial.transform import Rotation

    from helpers.data.datasets import background_photos

    turn = Rotation.from_rotvec(np.radians(40) * np.array([1.0, 0.0, 0.0])).as_matrix()  # about camera x
    photos = background_photos(manifest, "test")
    style = query_style("linemod", crop_shift=0.0, crop_scale=0.0, n_clutter=(0, 0))
    rng = np.random.default_rng(3)
    for i in range(6):
        img, vis, R = render_query(mug, None, RC, style, photos, rng)
        assert img.shape == (48, 48, 3) and img.dtype == np.uint8 and vis.shape == (48, 48)
        _, ref_mask = render_reference(mug, R, RC)
        iou = _iou(vis, ref_mask)
        assert iou > 0.8, f"view {i}: IoU {iou:.2f}"
        _, far_mask = render_reference(mug, turn @ R, RC)
        assert _iou(vis, far_mask) < iou


@pytest.mark.gl
def test_tabletop_scene_has_surroundings_and_leaves_references_clean(mug, manifest):
    from helpers.data.datasets import background_photos

    photos = background_photos(manifest, "train")
    ref_before, _ = render_reference(mug, np.eye(3), RC)
    img, vis, _ = render_query(mug, None, RC, query_style("linemod"), photos, np.random.default_rng(0))
    assert (img[~vis].max(axis=1) > 10).mean() > 0.9  # table and clutter around the object, not black
    ref_after, _ = render_reference(mug, np.eye(3), RC)
    assert np.array_equal(ref_before, ref_after)  # table and clutter hidden again for references
    # Context: stored side = crop side x context, the crop in the middle.
    big, bvis, _ = render_query(mug, None, RC, query_style("linemod", context=1.5), photos,
                                np.random.default_rng(0))
    assert big.shape == (72, 72, 3) and bvis.shape == (72, 72)


def test_named_styles_and_validation():
    assert query_style().scene == "tabletop" and query_style("hard").scene == "photo"
    assert query_style("hard") == QueryStyle()
    with pytest.raises(ValueError, match="query style"):
        query_style("lm")
    with pytest.raises(ValueError, match="scene"):
        QueryStyle(scene="studio")
    with pytest.raises(ValueError, match="elevation_deg"):
        QueryStyle(elevation_deg=(60.0, 10.0))
    with pytest.raises(ValueError, match="context"):
        QueryStyle(context=0.5)
