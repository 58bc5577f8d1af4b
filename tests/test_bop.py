"""BOP loader on a tiny fixture written here: 2 box objects, 1 scene, 2 images."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from helpers.core.rotations import geodesic_deg, haar_uniform
from helpers.data import bop

H, W = 120, 160


def _write_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj))


def make_bop(root: Path, with_info: bool = True) -> Path:
    """Write a minimal BOP dataset; returns its root."""
    models = root / "models"
    models.mkdir(parents=True)
    trimesh.creation.box(extents=(40, 20, 10)).export(models / "obj_000001.ply")
    trimesh.creation.box(extents=(30, 30, 30)).export(models / "obj_000002.ply")
    rz180 = np.diag([-1.0, -1.0, 1.0])
    flip = np.eye(4)
    flip[:3, :3] = rz180
    _write_json(models / "models_info.json", {
        "1": {"diameter": 46.0, "min_x": -20, "min_y": -10, "min_z": -5, "size_x": 40, "size_y": 20, "size_z": 10,
              "symmetries_discrete": [flip.reshape(-1).tolist()]},
        "2": {"diameter": 52.0, "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]},
    })
    scene = root / "test" / "000001"
    (scene / "rgb").mkdir(parents=True)
    (scene / "mask_visib").mkdir()
    rots = haar_uniform(4, seed=3)
    # Image 0: object 1 in a box at (20..60, 30..50), object 2 at (100..130, 60..100).
    # Image 3: only object 2, partly outside the image at the right edge.
    boxes = {0: [(1, (20, 30, 40, 20)), (2, (100, 60, 30, 40))], 3: [(2, (140, 10, 20, 30))]}
    gt, cam, info = {}, {}, {}
    for im_id, objs in boxes.items():
        rgb = np.full((H, W, 3), 40, np.uint8)
        gt[str(im_id)], info[str(im_id)] = [], []
        for gi, (obj_id, (x, y, w, h)) in enumerate(objs):
            colour = (255, 0, 0) if obj_id == 1 else (0, 255, 0)
            rgb[y:y + h, x:x + w] = colour
            mask = np.zeros((H, W), np.uint8)
            mask[y:y + h, x:x + w] = 255
            cv2.imwrite(str(scene / "mask_visib" / f"{im_id:06d}_{gi:06d}.png"), mask)
            R = rots[im_id + gi]
            gt[str(im_id)].append({"cam_R_m2c": R.reshape(-1).tolist(), "cam_t_m2c": [1.0, 2.0, 500.0],
                                   "obj_id": obj_id})
            info[str(im_id)].append({"bbox_obj": [x, y, w, h], "bbox_visib": [x, y, w, h],
                                     "visib_fract": 0.9 if gi == 0 else 0.4})
        cv2.imwrite(str(scene / "rgb" / f"{im_id:06d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        cam[str(im_id)] = {"cam_K": [500.0, 0, W / 2, 0, 500.0, H / 2, 0, 0, 1], "depth_scale": 1.0}
    _write_json(scene / "scene_gt.json", gt)
    _write_json(scene / "scene_camera.json", cam)
    if with_info:
        _write_json(scene / "scene_gt_info.json", info)
    return root


@pytest.fixture()
def root(tmp_path: Path) -> Path:
    return make_bop(tmp_path / "lm")


def test_models_info_and_symmetries(root):
    infos = bop.load_models_info(root)
    assert sorted(infos) == [1, 2]
    assert infos[1].diameter == 46.0
    s1 = infos[1].symmetries
    assert s1.shape == (2, 3, 3) and np.allclose(s1[0], np.eye(3))
    assert np.allclose(s1[1], np.diag([-1, -1, 1]))
    s2 = infos[2].symmetries
    assert s2.shape == (36, 3, 3) and np.allclose(s2[0], np.eye(3))
    # Every continuous step is a rotation about z by a multiple of 10 degrees.
    assert np.allclose(s2[:, 2, 2], 1.0)
    angles = np.sort(np.round(geodesic_deg(s2, np.eye(3)[None]), 6))
    assert np.allclose(np.unique(angles), np.arange(0, 181, 10))
    assert bop.load_models_info(root, step_deg=90)[2].symmetries.shape == (4, 3, 3)


def test_combined_discrete_and_continuous(tmp_path):
    flip_x = np.eye(4)
    flip_x[:3, :3] = np.diag([1.0, -1.0, -1.0])
    (tmp_path / "models").mkdir()
    _write_json(tmp_path / "models" / "models_info.json", {"7": {
        "diameter": 10, "symmetries_discrete": [flip_x.reshape(-1).tolist()],
        "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]}})
    sym = bop.load_models_info(tmp_path, step_deg=30)[7].symmetries
    assert sym.shape == (24, 3, 3)
    for s in sym:
        assert np.allclose(s @ s.T, np.eye(3)) and np.isclose(np.linalg.det(s), 1)


def test_load_mesh(root):
    mesh = bop.load_model_mesh(root, 1)
    assert np.allclose(mesh.extents, (40, 20, 10))
    with pytest.raises(bop.BOPFormatError, match="obj_000009.ply"):
        bop.load_model_mesh(root, 9)


def test_iter_instances(root):
    insts = list(bop.iter_scene_instances(root, "test"))
    assert [(i.im_id, i.gt_index, i.obj_id) for i in insts] == [(0, 0, 1), (0, 1, 2), (3, 0, 2)]
    i0 = insts[0]
    assert i0.scene_id == 1 and i0.R_m2c.shape == (3, 3) and np.allclose(i0.t_m2c, (1, 2, 500))
    assert np.allclose(i0.K[0, 0], 500) and i0.rgb_path.name == "000000.png"
    assert i0.mask_path.name == "000000_000000.png" and list(i0.bbox_visib) == [20, 30, 40, 20]
    assert [i.obj_id for i in bop.iter_scene_instances(root, "test", obj_ids=[2])] == [2, 2]
    assert len(list(bop.iter_scene_instances(root, "test", min_visib=0.5))) == 2


def test_crop(root):
    inst = next(bop.iter_scene_instances(root, "test"))
    crop, mask = bop.crop_instance(inst, size=32)
    assert crop.shape == (32, 32, 3) and crop.dtype == np.uint8 and mask.shape == (32, 32) and mask.dtype == bool
    # Tight square around a 40x20 box: the box spans full width, half the height.
    assert mask[16].all() and not mask[2].any() and mask.mean() == pytest.approx(0.5, abs=0.07)
    assert np.all(crop[16, 16] == (255, 0, 0))
    crop2, mask2 = bop.crop_instance(inst, size=32, pad=2.0)
    assert mask2.mean() == pytest.approx(0.125, abs=0.03)
    # Partly outside the image: outside is black, mask still there.
    # box="obj" uses bbox_obj (same box in this fixture).
    assert np.array_equal(bop.crop_instance(inst, size=32, box="obj")[1], mask)
    edge = list(bop.iter_scene_instances(root, "test"))[2]
    crop3, mask3 = bop.crop_instance(edge, size=30, pad=1.5)
    assert mask3.any() and (crop3[:, -3:] == 0).all()


def test_crop_without_gt_info_uses_mask(tmp_path):
    root = make_bop(tmp_path / "lm", with_info=False)
    inst = next(bop.iter_scene_instances(root, "test"))
    assert inst.bbox_visib is None and inst.visib_fract is None
    _, mask = bop.crop_instance(inst, size=32)
    assert mask[16].all() and mask.mean() == pytest.approx(0.5, abs=0.07)
    with pytest.raises(bop.BOPFormatError, match="scene_gt_info.json"):
        list(bop.iter_scene_instances(root, "test", min_visib=0.1))


def test_load_views(root):
    v = bop.load_bop_views(root, "test", 2, size=24)
    assert v.kind == "query" and v.images.shape == (2, 24, 24, 3) and v.masks.shape == (2, 24, 24)
    assert v.rotations.dtype == np.float32
    # Continuous symmetry kept exact by default; discretised on request (the old behaviour).
    from helpers.core.rotations import Symmetries
    assert isinstance(v.symmetries, Symmetries) and v.symmetries.axes.shape == (1, 3)
    assert bop.load_bop_views(root, "test", 2, size=24, step_deg=10.0).symmetries.shape == (36, 3, 3)
    assert v.meta["instances"] == [(1, 0, 1), (1, 3, 0)]
    assert len(bop.load_bop_views(root, "test", 2, size=24, max_instances=1)) == 1
    with pytest.raises(bop.BOPFormatError, match="object 5"):
        bop.load_bop_views(root, "test", 5)


# ----------------------------------------------------------------------------- errors

def test_malformed_json(root):
    p = root / "test" / "000001" / "scene_gt.json"
    p.write_text("{not json")
    with pytest.raises(bop.BOPFormatError, match=r"scene_gt\.json.*malformed JSON"):
        list(bop.iter_scene_instances(root, "test"))


def test_missing_keys(root):
    p = root / "test" / "000001" / "scene_gt.json"
    gt = json.loads(p.read_text())
    del gt["0"][1]["cam_t_m2c"]
    p.write_text(json.dumps(gt))
    with pytest.raises(bop.BOPFormatError, match=r"scene_gt\.json.*image 0 pose 1.*'cam_t_m2c'"):
        list(bop.iter_scene_instances(root, "test"))

    p = root / "models" / "models_info.json"
    info = json.loads(p.read_text())
    del info["2"]["diameter"]
    p.write_text(json.dumps(info))
    with pytest.raises(bop.BOPFormatError, match=r"models_info\.json.*object 2.*'diameter'"):
        bop.load_models_info(root)


def test_bad_values(root):
    p = root / "test" / "000001" / "scene_camera.json"
    cam = json.loads(p.read_text())
    cam["3"]["cam_K"] = [1, 2, 3]
    p.write_text(json.dumps(cam))
    with pytest.raises(bop.BOPFormatError, match=r"scene_camera\.json.*image 3: cam_K.*9"):
        list(bop.iter_scene_instances(root, "test"))
    p = root / "models" / "models_info.json"
    p.write_text(json.dumps({"one": {"diameter": 1}}))
    with pytest.raises(bop.BOPFormatError, match="not an integer object id"):
        bop.load_models_info(root)


def test_missing_files(root, tmp_path):
    scene = root / "test" / "000001"
    (scene / "mask_visib" / "000000_000000.png").unlink()
    inst = next(bop.iter_scene_instances(root, "test"))
    with pytest.raises(bop.BOPFormatError, match="000000_000000.png.*does not exist"):
        bop.crop_instance(inst)
    (scene / "rgb" / "000003.png").unlink()
    with pytest.raises(bop.BOPFormatError, match="no image 000003"):
        list(bop.iter_scene_instances(root, "test"))
    (scene / "scene_camera.json").unlink()
    with pytest.raises(bop.BOPFormatError, match=r"scene_camera\.json.*does not exist"):
        list(bop.iter_scene_instances(root, "test"))
    with pytest.raises(bop.BOPFormatError, match="split folder"):
        list(bop.iter_scene_instances(root, "train"))
    with pytest.raises(bop.BOPFormatError, match="models_info.json"):
        bop.load_models_info(tmp_path / "nowhere")
    assert issubclass(bop.BOPFormatError, ValueError)
