"""Write the study's sets and predictions in the BOP format, so the BOP toolkit can score them.

Dataset (https://github.com/thodan/bop_toolkit/blob/master/docs/bop_datasets_format.md), written by
:func:`export_tless_like`::

    <root>/models/models_info.json, obj_XXXXXX.ply     millimetres, symmetries as BOP lists them
    <root>/test/<scene_id:06d>/scene_camera.json        cam_K, depth_scale (mm per depth unit)
    <root>/test/<scene_id:06d>/scene_gt.json            cam_R_m2c, cam_t_m2c (mm), obj_id
    <root>/test/<scene_id:06d>/scene_gt_info.json       bbox_obj, bbox_visib, px counts, visib_fract
    <root>/test/<scene_id:06d>/{rgb,depth,mask,mask_visib}/

One scene per part (scene_id = obj_id = the part's index + 1), one image per query (im_id = query index), the
query part its only annotated instance (the other parts in the picture are clutter without annotations).
Images are the full render frames (``render_size`` pixels) with the renders' intrinsics.

:func:`export_linemod_like` writes the LineMOD-like benchmark's objects under LineMOD's layout and object ids as
``<root>/lm`` (one scene per object, scene_id = obj_id, as BOP's LineMOD) and ``<root>/lmo`` (one scene, 000002,
as LineMOD-O): the BOP-format stand-in for real LineMOD that the tests run the notebooks' real-data path on.

Predictions (:func:`write_results_csv`): BOP's results CSV, one row per estimate:
``scene_id,im_id,obj_id,score,R,t,time`` with R the 9 row-major entries of ``R_m2c`` and t the 3 entries of
``t_m2c`` in mm, both space-separated, time in seconds (-1 when unknown).
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

import cv2
import numpy as np

from ..core.configs import RenderConfig
from ..core.fileio import atomic_write_text
from .datasets import background_photos
from .linemod_bop import LM_OBJECTS, LMO_OBJECT_IDS
from .manifest import Manifest, load_manifest
from .meshes import load_object
from .parts import part_file, spec
from .render import query_style
from .tabletop import render_tabletop
from .tless import TlessSet

#: Depth PNGs store millimetres / DEPTH_SCALE as uint16 (0.1 mm resolution, up to 6.5 m).
DEPTH_SCALE = 0.1


def _bbox(mask: np.ndarray) -> list[int]:
    """[x, y, w, h] of a mask's pixels ([-1, -1, 0, 0] when empty, as BOP writes it)."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, 0, 0]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


def _t_mm(tset: TlessSet, name: str) -> list[float]:
    """The part's translation in the camera frame, mm: on the optical axis at the renders' distance."""
    return [0.0, 0.0, float(tset.cfg.render_config().distance_diameters * tset.parts[name].diameter * 1000.0)]


def _models(tset: TlessSet, root: Path, cache: str | os.PathLike | None) -> dict[str, int]:
    """Copy each part's PLY (mm) as obj_XXXXXX.ply and write models_info.json; returns name -> obj_id."""
    import trimesh

    (root / "models").mkdir(parents=True, exist_ok=True)
    ids, info = {}, {}
    for i, name in enumerate(tset.names):
        oid = i + 1
        src = part_file(name, cache=cache)
        (root / "models" / f"obj_{oid:06d}.ply").write_bytes(src.read_bytes())
        mesh = trimesh.load(src, process=False)
        lo, size = mesh.bounds[0], mesh.extents
        info[str(oid)] = {"diameter": float(tset.parts[name].diameter * 1000.0),
                          "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
                          "size_x": float(size[0]), "size_y": float(size[1]), "size_z": float(size[2]),
                          **spec(name).symmetry_entry()}
        ids[name] = oid
    atomic_write_text(root / "models" / "models_info.json", json.dumps(info, indent=1))
    return ids


def export_tless_like(tset: TlessSet, root: str | os.PathLike, cache: str | os.PathLike | None = None) -> Path:
    """Write the T-LESS-like set ``tset`` as a BOP dataset under ``root`` (split ``test``); returns ``root``."""
    if not tset.frames:
        raise ValueError("export_tless_like: this set has no full frames (rendered before SET_VERSION 2)")
    root = Path(root)
    ids = _models(tset, root, cache)
    K = tset.cfg.render_config().intrinsics()
    for name, oid in ids.items():
        scene = root / "test" / f"{oid:06d}"
        for sub in ("rgb", "depth", "mask", "mask_visib"):
            (scene / sub).mkdir(parents=True, exist_ok=True)
        t_mm = _t_mm(tset, name)
        cams, gts, infos = {}, {}, {}
        for i, R in enumerate(tset.queries[name].rotations.astype(np.float64)):
            full, vis = tset.full[name][i], tset.visible[name][i]
            cv2.imwrite(str(scene / "rgb" / f"{i:06d}.png"), cv2.cvtColor(tset.frames[name][i], cv2.COLOR_RGB2BGR))
            depth_mm = tset.depth[name][i].astype(np.float64) * 1000.0
            cv2.imwrite(str(scene / "depth" / f"{i:06d}.png"), np.round(depth_mm / DEPTH_SCALE).astype(np.uint16))
            cv2.imwrite(str(scene / "mask" / f"{i:06d}_000000.png"), full.astype(np.uint8) * 255)
            cv2.imwrite(str(scene / "mask_visib" / f"{i:06d}_000000.png"), vis.astype(np.uint8) * 255)
            cams[str(i)] = {"cam_K": K.reshape(-1).tolist(), "depth_scale": DEPTH_SCALE}
            gts[str(i)] = [{"cam_R_m2c": R.reshape(-1).tolist(), "cam_t_m2c": t_mm, "obj_id": oid}]
            n_all, n_vis = int(full.sum()), int((full & vis).sum())
            infos[str(i)] = [{"bbox_obj": _bbox(full), "bbox_visib": _bbox(vis), "px_count_all": n_all,
                              "px_count_valid": n_all, "px_count_visib": n_vis,
                              "visib_fract": float(n_vis / n_all) if n_all else 0.0}]
        for fname, data in (("scene_camera.json", cams), ("scene_gt.json", gts), ("scene_gt_info.json", infos)):
            atomic_write_text(scene / fname, json.dumps(data, indent=1))
    return root


def _write_frame(scene: Path, i: int, color: np.ndarray, depth_m: np.ndarray, full: np.ndarray,
                 vis: np.ndarray) -> dict:
    """Write one view's rgb, depth (mm / DEPTH_SCALE), mask and mask_visib; returns its scene_gt_info entry."""
    for sub in ("rgb", "depth", "mask", "mask_visib"):
        (scene / sub).mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(scene / "rgb" / f"{i:06d}.png"), cv2.cvtColor(color, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(scene / "depth" / f"{i:06d}.png"), np.round(depth_m * 1000.0 / DEPTH_SCALE).astype(np.uint16))
    cv2.imwrite(str(scene / "mask" / f"{i:06d}_000000.png"), full.astype(np.uint8) * 255)
    cv2.imwrite(str(scene / "mask_visib" / f"{i:06d}_000000.png"), vis.astype(np.uint8) * 255)
    n_all, n_vis = int(full.sum()), int((full & vis).sum())
    return {"bbox_obj": _bbox(full), "bbox_visib": _bbox(full & vis), "px_count_all": n_all,
            "px_count_valid": n_all, "px_count_visib": n_vis, "visib_fract": float(n_vis / n_all) if n_all else 0.0}


def _symmetry_keys(group) -> dict:
    """BOP's symmetry keys of a declared group (model frame centred on the box, so no translation part)."""
    out: dict = {}
    disc = getattr(group, "discrete", group)
    rots = [R for R in np.asarray(disc, np.float64) if not np.allclose(R, np.eye(3))]
    if rots:
        out["symmetries_discrete"] = [np.block([[R, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]
                                               ).reshape(-1).tolist() for R in rots]
    axes = getattr(group, "axes", ())
    if len(axes):
        out["symmetries_continuous"] = [{"axis": [float(v) for v in a], "offset": [0.0, 0.0, 0.0]} for a in axes]
    return out


def export_linemod_like(root: str | os.PathLike, objects: dict[str, int], n_views: int = 20, n_occluded: int = 6,
                        render_size: int = 96, seed: int = 0, manifest: Manifest | None = None) -> Path:
    """Write benchmark objects as a BOP LineMOD (``<root>/lm``) and LineMOD-O (``<root>/lmo``) pair.

    Args:
        objects: benchmark object name -> the LineMOD BOP id it stands for (its paper split follows the id).
        n_views: tabletop views per object in ``lm`` (scene = obj_id, im_id = view index).
        n_occluded: views per object in ``lmo`` (for ids LineMOD-O annotates; all in scene 2).
        render_size: frame side, pixels (the renders' intrinsics are the camera's).

    Meshes are the normalised benchmark meshes in millimetres with their colours as vertex colours (LineMOD's
    PLYs are vertex-coloured); ``models_info.json`` lists each object's declared symmetries.
    Returns ``root``.
    """
    bad = sorted(i for i in objects.values() if i not in LM_OBJECTS)
    if bad or len(set(objects.values())) != len(objects):
        raise ValueError(f"export_linemod_like: ids must be distinct LineMOD ids among {sorted(LM_OBJECTS)}, "
                         f"got {objects}")
    m = manifest or load_manifest()
    root = Path(root)
    cfg = RenderConfig(render_size=render_size)
    style, photos = query_style("linemod"), background_photos(m, "test")
    K, rng = cfg.intrinsics(), np.random.default_rng([seed, 4242])
    meshes = {name: load_object(name, m) for name in objects}
    lmo_views: list[tuple] = []
    for name, oid in objects.items():
        obj = meshes[name]
        views = []
        for _ in range(n_views + (n_occluded if oid in LMO_OBJECT_IDS else 0)):
            color, depth, full, vis, vp = render_tabletop(obj, cfg, style, photos, rng)
            t_mm = [0.0, 0.0, float(cfg.distance_diameters * obj.diameter * 1000.0)]
            views.append((color, depth, full, vis,
                          {"cam_R_m2c": vp.R_m2c.reshape(-1).tolist(), "cam_t_m2c": t_mm, "obj_id": oid}))
        _write_scene(root / "lm" / "test" / f"{oid:06d}", views[:n_views], K)
        lmo_views += views[n_views:]
    _write_scene(root / "lmo" / "test" / f"{2:06d}", lmo_views, K)
    for ds, ids in (("lm", objects), ("lmo", {n: i for n, i in objects.items() if i in LMO_OBJECT_IDS})):
        _write_lm_models(root / ds / "models", {i: meshes[n] for n, i in ids.items()}, m)
    return root


def _write_scene(scene: Path, views: list[tuple], K: np.ndarray) -> None:
    """One BOP scene: each view (colour, depth m, full mask, visible mask, its scene_gt pose) as image ``i``, then
    scene_camera.json, scene_gt.json and scene_gt_info.json."""
    scene.mkdir(parents=True, exist_ok=True)
    cams, gts, infos = {}, {}, {}
    for i, (color, depth, full, vis, pose) in enumerate(views):
        infos[str(i)] = [_write_frame(scene, i, color, depth, full, vis)]
        cams[str(i)] = {"cam_K": K.reshape(-1).tolist(), "depth_scale": DEPTH_SCALE}
        gts[str(i)] = [pose]
    for fname, data in (("scene_camera.json", cams), ("scene_gt.json", gts), ("scene_gt_info.json", infos)):
        atomic_write_text(scene / fname, json.dumps(data, indent=1))


def _write_lm_models(models: Path, objs: dict, m: Manifest) -> None:
    """obj_XXXXXX.ply (mm, vertex colours) and models_info.json of LineMOD ids -> normalised benchmark meshes."""
    import trimesh

    models.mkdir(parents=True, exist_ok=True)
    info = {}
    for oid, obj in objs.items():
        mesh = obj.mesh.copy()
        mesh.apply_scale(1000.0)
        vis = mesh.visual.to_color() if getattr(mesh.visual, "kind", None) == "texture" else mesh.visual
        # per-vertex colours, as LineMOD's PLYs store them (a texture is sampled, face colours spread to vertices)
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.asarray(vis.vertex_colors))
        (models / f"obj_{oid:06d}.ply").write_bytes(mesh.export(file_type="ply"))
        lo, size = mesh.bounds[0], mesh.extents
        info[str(oid)] = {"diameter": float(obj.diameter * 1000.0), "min_x": float(lo[0]), "min_y": float(lo[1]),
                          "min_z": float(lo[2]), "size_x": float(size[0]), "size_y": float(size[1]),
                          "size_z": float(size[2]), **_symmetry_keys(m.object(obj.name).symmetry_group())}
    atomic_write_text(models / "models_info.json", json.dumps(info, indent=1))


def tless_like_results(tset: TlessSet, res: dict, ids: dict[str, int] | None = None) -> list[dict]:
    """BOP result rows of one method's retrieval on the set (:func:`helpers.study.protocols.tless.evaluate_tless`):
    the estimated rotation with the true translation (the paper's rotation-only protocol), the retrieval score
    unknown (1.0), the predicted part as obj_id."""
    ids = ids or {n: i + 1 for i, n in enumerate(tset.names)}
    rows = []
    for r in res["records"]:
        name, i = r.query_id.rsplit(":", 1)
        rows.append({"scene_id": ids[name], "im_id": int(i), "obj_id": ids[r.pred_obj], "score": 1.0,
                     "R": np.asarray(r.R_est, np.float64), "t": _t_mm(tset, name), "time": -1})
    return rows


def write_results_csv(rows: list[dict], path: str | os.PathLike) -> Path:
    """Write BOP's results CSV (see the module docstring) from rows with scene_id, im_id, obj_id, score,
    R (3, 3), t (3,) mm and time (s)."""
    path = Path(path)
    lines = [["scene_id", "im_id", "obj_id", "score", "R", "t", "time"]]
    for r in rows:
        R = np.asarray(r["R"], np.float64).reshape(-1)
        if R.size != 9 or len(r["t"]) != 3:
            raise ValueError(f"write_results_csv: row {r.get('scene_id')}/{r.get('im_id')}: R needs 9 and t 3 values")
        lines.append([int(r["scene_id"]), int(r["im_id"]), int(r["obj_id"]), f"{float(r['score']):.6f}",
                      " ".join(f"{v:.8f}" for v in R), " ".join(f"{float(v):.4f}" for v in r["t"]),
                      f"{float(r['time']):.4f}"])
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(lines)
    atomic_write_text(path, buf.getvalue())
    return path


def read_results_csv(path: str | os.PathLike) -> list[dict]:
    """Rows of a BOP results CSV (R as (3, 3), t as (3,) mm)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    need = {"scene_id", "im_id", "obj_id", "score", "R", "t", "time"}
    if not rows or not need <= set(rows[0]):
        raise ValueError(f"{path}: expected a BOP results CSV with columns {sorted(need)}")
    return [{"scene_id": int(r["scene_id"]), "im_id": int(r["im_id"]), "obj_id": int(r["obj_id"]),
             "score": float(r["score"]), "R": np.array(r["R"].split(), float).reshape(3, 3),
             "t": np.array(r["t"].split(), float), "time": float(r["time"])} for r in rows]
