import cv2
import numpy as np
import pytest
import trimesh

from helpers.core.configs import QueryStyle, RenderConfig
from helpers.core.rotations import haar_uniform, inplane_rotate_label
from helpers.data.gl import render_raw
from helpers.data.meshes import ObjectMesh, mesh_diameter
from helpers.data.render import add_occluder, render_query, render_reference

pytestmark = pytest.mark.gl


def _box(extents=(0.1, 0.1, 0.1), color=(0.8, 0.2, 0.2)):
    m = trimesh.creation.box(extents=extents)
    m.visual = trimesh.visual.ColorVisuals(m, face_colors=np.tile(np.array([*color, 1.0]) * 255, (len(m.faces), 1)).astype(np.uint8))
    return ObjectMesh("box", m, mesh_diameter(m.vertices), False, "box-test", np.eye(3)[None])


def test_box_has_expected_size_and_depth():
    obj = _box()
    cfg = RenderConfig(size=64, render_size=128)
    color, depth = render_raw(obj, np.eye(3), cfg)
    dist = cfg.distance_diameters * obj.diameter
    z_front = dist - 0.05
    K = cfg.intrinsics()
    # Depth at the centre is the front face; background is 0.
    c = cfg.render_size // 2
    assert depth[c, c] == pytest.approx(z_front, rel=1e-3)
    assert depth[0, 0] == 0 and color[0, 0].sum() == 0
    # Projected width of the front face: f * 0.1 / z_front pixels.
    mask = depth > 0
    cols = np.nonzero(mask.any(0))[0]
    rows = np.nonzero(mask.any(1))[0]
    expected = K[0, 0] * 0.1 / z_front
    assert abs((cols.max() - cols.min() + 1) - expected) <= 2
    assert abs((rows.max() - rows.min() + 1) - expected) <= 2
    # Centred on the principal point.
    assert abs((cols.max() + cols.min()) / 2 - K[0, 2]) <= 1.5


def test_opencv_axes():
    # A box long along model x, rotated identity: wide in the image (x right).
    obj = _box(extents=(0.18, 0.04, 0.04))
    cfg = RenderConfig(size=64, render_size=128)
    _, depth = render_raw(obj, np.eye(3), cfg)
    m = depth > 0
    assert m.any(0).sum() > 3 * m.any(1).sum()
    # Offset sphere along model +y must appear in the lower half (y down).
    s = trimesh.creation.icosphere(radius=0.02)
    s.apply_translation([0, 0.06, 0])
    both = trimesh.util.concatenate([trimesh.creation.box(extents=(0.02, 0.02, 0.02)), s])
    o2 = ObjectMesh("ys", both, 0.2, False, "ys", np.eye(3)[None])
    _, d2 = render_raw(o2, np.eye(3), cfg)
    ys, _ = np.nonzero(d2 > 0)
    assert ys.max() > cfg.render_size * 0.6


def test_inplane_label_matches_image_rotation():
    obj = _box(extents=(0.16, 0.06, 0.03))
    cfg = RenderConfig(size=64, render_size=128)
    R = haar_uniform(1, seed=5)[0]
    _, d0 = render_raw(obj, R, cfg)
    angle = 35.0
    c = cfg.intrinsics()[0, 2]
    M = cv2.getRotationMatrix2D((c, c), angle, 1.0)
    rotated = cv2.warpAffine((d0 > 0).astype(np.uint8), M, d0.shape[::-1], flags=cv2.INTER_NEAREST) > 0
    _, d1 = render_raw(obj, inplane_rotate_label(R, angle), cfg)
    iou = (rotated & (d1 > 0)).sum() / (rotated | (d1 > 0)).sum()
    assert iou > 0.95
    _, dwrong = render_raw(obj, inplane_rotate_label(R, -angle), cfg)
    assert (rotated & (dwrong > 0)).sum() / (rotated | (dwrong > 0)).sum() < iou - 0.1


def test_reference_crop_is_tight_and_black():
    obj = _box(extents=(0.1, 0.05, 0.08))
    cfg = RenderConfig(size=64, render_size=128)
    img, mask = render_reference(obj, haar_uniform(1, 2)[0], cfg)
    assert img.shape == (64, 64, 3) and mask.shape == (64, 64)
    rows, cols = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
    # The longer side spans the whole crop.
    assert max(rows.max() - rows.min(), cols.max() - cols.min()) >= 61
    assert img[~mask].max() == 0


def test_query_is_real_like(rng):
    obj = _box()
    cfg = RenderConfig(size=64, render_size=128)
    bg = (np.random.default_rng(1).random((200, 300, 3)) * 255).astype(np.uint8)
    img, vis, Rq = render_query(obj, np.eye(3), cfg, QueryStyle(occlusion=1.0, occlusion_fraction=(0.3, 0.3)), [bg], rng)
    assert img.shape == (64, 64, 3) and img.dtype == np.uint8
    assert (img[~vis] > 0).mean() > 0.9  # background filled
    assert np.allclose(Rq @ Rq.T, np.eye(3), atol=1e-9)
    assert 0.2 < vis.mean() < 0.9


def test_occluder_covers_requested_fraction(rng):
    mask = np.zeros((64, 64), bool)
    mask[16:48, 16:48] = True
    img = np.zeros((64, 64, 3), np.uint8)
    _, vis = add_occluder(img, mask, rng, (0.3, 0.3))
    covered = 1 - vis.sum() / mask.sum()
    assert 0.3 <= covered < 0.8
