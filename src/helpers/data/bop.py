"""Read datasets in the BOP format (LineMOD, LineMOD-Occluded, T-LESS).

Layout (https://github.com/thodan/bop_toolkit/blob/master/docs/bop_datasets_format.md)::

    <root>/models/models_info.json           per object: diameter (mm), symmetries
    <root>/models/obj_XXXXXX.ply
    <root>/<split>/<scene_id:06d>/scene_gt.json        per image: list of GT poses
    <root>/<split>/<scene_id:06d>/scene_camera.json    per image: cam_K, depth_scale
    <root>/<split>/<scene_id:06d>/scene_gt_info.json   optional: bbox_visib, visib_fract
    <root>/<split>/<scene_id:06d>/rgb/XXXXXX.png       (or .jpg)
    <root>/<split>/<scene_id:06d>/mask_visib/XXXXXX_YYYYYY.png

``models_info.json`` may also sit directly in ``<root>`` (some downloads do
that); both places are tried. Rotations are ``R_m2c`` (OpenCV camera),
translations millimetres, as BOP stores them.

Any malformed, missing or inconsistent input raises :class:`BOPFormatError`
naming the file and what was expected.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np
import trimesh

from ..core.rotations import Symmetries
from ..core.views import ObjectViews

#: Rotations closer than this (degrees) count as the same symmetry.
_SYM_DEDUP_DEG = 1e-3


class BOPFormatError(ValueError):
    """A BOP dataset file is missing, malformed or lacks an expected key."""


@dataclass(frozen=True)
class ModelInfo:
    """One object's entry in ``models_info.json``.

    Attributes:
        obj_id: BOP object id (1-based).
        diameter: largest vertex distance, millimetres.
        symmetries: (K, 3, 3) float64 model-frame symmetry rotations, identity
            first; discrete ones combined with the discretised continuous ones.
        bbox_min: (3,) model-frame bounding-box minimum, mm (zeros if absent).
        bbox_size: (3,) bounding-box size, mm (zeros if absent).
        exact_symmetries: the same group kept exact: a :class:`helpers.core.rotations.Symmetries`
            (continuous axis x discrete set) when the object has continuous symmetries,
            else the discrete (K, 3, 3) array.
    """

    obj_id: int
    diameter: float
    symmetries: np.ndarray
    bbox_min: np.ndarray
    bbox_size: np.ndarray
    exact_symmetries: Any = None

    def __post_init__(self) -> None:
        if self.exact_symmetries is None:
            object.__setattr__(self, "exact_symmetries", self.symmetries)


@dataclass(frozen=True)
class Instance:
    """One annotated object instance in one image.

    Attributes:
        scene_id, im_id: BOP scene and image ids.
        gt_index: position of this instance in the image's ``scene_gt`` list
            (the ``YYYYYY`` of the mask file name).
        obj_id: BOP object id.
        R_m2c: (3, 3) float64 rotation, model -> OpenCV camera.
        t_m2c: (3,) float64 translation, millimetres.
        K: (3, 3) float64 camera intrinsics, pixels.
        rgb_path: colour image.
        mask_path: visible-part mask (may not exist on disk; checked when cropping).
        bbox_visib: (4,) int ``[x, y, w, h]`` of the visible part, pixels, or
            None when ``scene_gt_info.json`` is absent (then the mask is used).
        visib_fract: visible fraction in [0, 1], or None when unknown.
        bbox_obj: (4,) int ``[x, y, w, h]`` of the whole projected object
            (occluded parts included), or None when unknown.
    """

    scene_id: int
    im_id: int
    gt_index: int
    obj_id: int
    R_m2c: np.ndarray
    t_m2c: np.ndarray
    K: np.ndarray
    rgb_path: Path
    mask_path: Path
    bbox_visib: np.ndarray | None
    visib_fract: float | None
    bbox_obj: np.ndarray | None = None


# --------------------------------------------------------------------------- json helpers

def _read_json(path: Path) -> Any:
    """Parse a JSON file; every failure becomes a BOPFormatError naming it."""
    if not path.is_file():
        raise BOPFormatError(f"{path}: file does not exist (expected a BOP json file)")
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except json.JSONDecodeError as e:
        raise BOPFormatError(f"{path}: malformed JSON ({e.msg} at line {e.lineno} column {e.colno})") from None
    except (OSError, UnicodeDecodeError) as e:
        raise BOPFormatError(f"{path}: cannot read ({e})") from None


def _int_keyed(data: Any, path: Path, what: str) -> dict[int, Any]:
    """BOP stores dicts keyed by decimal ids as strings; return them keyed by int."""
    if not isinstance(data, dict):
        raise BOPFormatError(f"{path}: expected a JSON object mapping {what} ids to entries, "
                             f"got {type(data).__name__}")
    out = {}
    for k, v in data.items():
        try:
            out[int(k)] = v
        except ValueError:
            raise BOPFormatError(f"{path}: key {k!r} is not an integer {what} id") from None
    return out


def _get(entry: Any, key: str, path: Path, where: str) -> Any:
    if not isinstance(entry, dict):
        raise BOPFormatError(f"{path}: {where}: expected a JSON object, got {type(entry).__name__}")
    if key not in entry:
        raise BOPFormatError(f"{path}: {where}: missing key {key!r}")
    return entry[key]


def _floats(value: Any, n: int, path: Path, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise BOPFormatError(f"{path}: {where}: expected {n} numbers, got {value!r:.80}") from None
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise BOPFormatError(f"{path}: {where}: expected {n} finite numbers, got {arr.size}")
    return arr


# --------------------------------------------------------------------------- models

def _models_info_path(root: Path) -> Path:
    for p in (root / "models" / "models_info.json", root / "models_info.json"):
        if p.is_file():
            return p
    raise BOPFormatError(f"{root}: no models_info.json (looked in {root / 'models'} and {root})")


def _rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues formula: rotation (3, 3) by ``angle`` radians about unit ``axis``."""
    x, y, z = axis
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def _dedup_rotations(rots: np.ndarray) -> np.ndarray:
    """Drop near-duplicates (keeps first occurrences, so identity stays first)."""
    keep: list[np.ndarray] = []
    cos_tol = np.cos(np.radians(_SYM_DEDUP_DEG))
    for r in rots:
        if all((np.trace(k.T @ r) - 1) / 2 < cos_tol for k in keep):
            keep.append(r)
    return np.stack(keep)


def symmetry_rotations(entry: dict, path: Path, where: str, step_deg: float = 10.0) -> np.ndarray:
    """Model-frame symmetry rotations (K, 3, 3) of one ``models_info`` entry.

    Discrete symmetries are 4x4 row-major transforms (their translations only
    re-centre the model and do not matter for rotation errors). Continuous ones
    (an axis through an offset) are discretised every ``step_deg`` degrees.
    The result holds every product ``R_cont @ R_disc`` (identity included in
    both factors), deduplicated, identity first.
    """
    if not step_deg > 0 or step_deg > 360:
        raise BOPFormatError(f"step_deg: expected a step in (0, 360] degrees, got {step_deg}")
    disc = [np.eye(3)]
    for i, s in enumerate(entry.get("symmetries_discrete", []) or []):
        m = _floats(s, 16, path, f"{where}: symmetries_discrete[{i}]").reshape(4, 4)
        r = m[:3, :3]
        if not np.allclose(r.T @ r, np.eye(3), atol=1e-4) or np.linalg.det(r) < 0:
            raise BOPFormatError(f"{path}: {where}: symmetries_discrete[{i}] is not a rotation "
                                 "(expected a proper orthonormal 3x3 block)")
        # Re-orthonormalise: BOP stores ~8 significant digits.
        u, _, vt = np.linalg.svd(r)
        disc.append(u @ vt)
    cont = [np.eye(3)]
    for i, s in enumerate(entry.get("symmetries_continuous", []) or []):
        axis = _floats(_get(s, "axis", path, f"{where}: symmetries_continuous[{i}]"), 3, path,
                       f"{where}: symmetries_continuous[{i}].axis")
        n = np.linalg.norm(axis)
        if n == 0:
            raise BOPFormatError(f"{path}: {where}: symmetries_continuous[{i}].axis is the zero vector")
        # Several continuous axes only occur for spheres; their products are
        # not a closed set at this step, but the min over them is still a bound.
        steps = int(np.ceil(360.0 / step_deg - 1e-9))
        base = list(cont)
        for r0 in base:
            for j in range(1, steps):
                cont.append(_rotation_about(axis / n, 2 * np.pi * j / steps) @ r0)
    combos = np.array([c @ d for d in disc for c in cont])
    return _dedup_rotations(combos)


def exact_group(entry: dict, path: Path, where: str) -> Any:
    """The symmetry group of one ``models_info`` entry without discretisation: a
    :class:`Symmetries` if it lists continuous symmetries, else the discrete (K, 3, 3) set."""
    disc = symmetry_rotations({k: v for k, v in entry.items() if k != "symmetries_continuous"}, path, where)
    axes = [_floats(_get(s, "axis", path, f"{where}: symmetries_continuous[{i}]"), 3, path,
                    f"{where}: symmetries_continuous[{i}].axis")
            for i, s in enumerate(entry.get("symmetries_continuous", []) or [])]
    return Symmetries(disc, np.array(axes)) if axes else disc


def load_models_info(root: str | os.PathLike, step_deg: float = 10.0) -> dict[int, ModelInfo]:
    """Read ``models_info.json``: object id -> :class:`ModelInfo`.

    Args:
        root: dataset root (the folder holding ``models/``).
        step_deg: discretisation step of continuous symmetries, degrees.
    """
    root = Path(root)
    path = _models_info_path(root)
    out = {}
    for obj_id, entry in sorted(_int_keyed(_read_json(path), path, "object").items()):
        where = f"object {obj_id}"
        diameter = float(_floats(_get(entry, "diameter", path, where), 1, path, f"{where}: diameter")[0])
        if diameter <= 0:
            raise BOPFormatError(f"{path}: {where}: diameter must be > 0 mm, got {diameter}")
        bmin = np.array([entry.get(f"min_{a}", 0.0) for a in "xyz"], dtype=np.float64)
        bsize = np.array([entry.get(f"size_{a}", 0.0) for a in "xyz"], dtype=np.float64)
        out[obj_id] = ModelInfo(obj_id, diameter, symmetry_rotations(entry, path, where, step_deg), bmin, bsize,
                                exact_group(entry, path, where))
    if not out:
        raise BOPFormatError(f"{path}: no objects listed (expected at least one entry)")
    return out


def load_model_mesh(root: str | os.PathLike, obj_id: int) -> trimesh.Trimesh:
    """Load ``models/obj_XXXXXX.ply`` as one Trimesh (units as stored: mm)."""
    path = Path(root) / "models" / f"obj_{int(obj_id):06d}.ply"
    if not path.is_file():
        raise BOPFormatError(f"{path}: model file does not exist (expected a PLY mesh for object {obj_id})")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for bad files
        raise BOPFormatError(f"{path}: cannot load as a mesh ({type(e).__name__}: {e})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0:
        raise BOPFormatError(f"{path}: expected a triangle mesh with vertices, got an empty/unsupported file")
    return mesh


# --------------------------------------------------------------------------- scenes

def _scene_dirs(root: Path, split: str) -> list[Path]:
    split_dir = root / split
    if not split_dir.is_dir():
        raise BOPFormatError(f"{split_dir}: split folder does not exist (expected <root>/{split}/<scene_id>/)")
    scenes = sorted(p for p in split_dir.iterdir() if p.is_dir() and p.name.isdigit())
    if not scenes:
        raise BOPFormatError(f"{split_dir}: no scene folders (expected 6-digit numeric folder names)")
    return scenes


def _rgb_path(scene_dir: Path, im_id: int) -> Path:
    for ext in (".png", ".jpg", ".jpeg", ".tif"):
        p = scene_dir / "rgb" / f"{im_id:06d}{ext}"
        if p.is_file():
            return p
    raise BOPFormatError(f"{scene_dir / 'rgb'}: no image {im_id:06d}.png/.jpg "
                         f"(expected the colour image of im_id {im_id})")


def iter_scene_instances(root: str | os.PathLike, split: str, obj_ids: list[int] | None = None,
                         min_visib: float = 0.0) -> Iterator[Instance]:
    """Yield every annotated instance of ``split`` in sorted (scene, image, gt) order.

    Args:
        root: dataset root.
        split: split folder name, e.g. ``"test"`` or ``"test_primesense"``.
        obj_ids: keep only these object ids (None: all).
        min_visib: keep instances with ``visib_fract >= min_visib``. Instances
            whose ``bbox_visib`` is empty (nothing visible) are always skipped.
            Needs ``scene_gt_info.json`` when > 0.
    """
    root = Path(root)
    wanted = None if obj_ids is None else {int(o) for o in obj_ids}
    for scene_dir in _scene_dirs(root, split):
        scene_id = int(scene_dir.name)
        gt_path, cam_path, info_path = (scene_dir / n for n in
                                        ("scene_gt.json", "scene_camera.json", "scene_gt_info.json"))
        scene_gt = _int_keyed(_read_json(gt_path), gt_path, "image")
        cams = _int_keyed(_read_json(cam_path), cam_path, "image")
        infos = _int_keyed(_read_json(info_path), info_path, "image") if info_path.is_file() else None
        if infos is None and min_visib > 0:
            raise BOPFormatError(f"{info_path}: file does not exist but min_visib={min_visib} needs visib_fract")
        for im_id in sorted(scene_gt):
            gts = scene_gt[im_id]
            if not isinstance(gts, list):
                raise BOPFormatError(f"{gt_path}: image {im_id}: expected a list of poses, got {type(gts).__name__}")
            if wanted is not None and not any(isinstance(g, dict) and g.get("obj_id") in wanted for g in gts):
                continue
            if im_id not in cams:
                raise BOPFormatError(f"{cam_path}: missing image {im_id} (listed in {gt_path.name})")
            K = _floats(_get(cams[im_id], "cam_K", cam_path, f"image {im_id}"), 9, cam_path,
                        f"image {im_id}: cam_K").reshape(3, 3)
            info_list = None
            if infos is not None:
                info_list = infos.get(im_id)
                if not isinstance(info_list, list) or len(info_list) != len(gts):
                    raise BOPFormatError(f"{info_path}: image {im_id}: expected a list of {len(gts)} entries "
                                         f"(one per pose in {gt_path.name})")
            rgb = None
            for gi, g in enumerate(gts):
                where = f"image {im_id} pose {gi}"
                obj_id = int(_floats(_get(g, "obj_id", gt_path, where), 1, gt_path, f"{where}: obj_id")[0])
                if wanted is not None and obj_id not in wanted:
                    continue
                R = _floats(_get(g, "cam_R_m2c", gt_path, where), 9, gt_path, f"{where}: cam_R_m2c").reshape(3, 3)
                t = _floats(_get(g, "cam_t_m2c", gt_path, where), 3, gt_path, f"{where}: cam_t_m2c")
                if not np.allclose(R @ R.T, np.eye(3), atol=1e-3):
                    raise BOPFormatError(f"{gt_path}: {where}: cam_R_m2c is not a rotation matrix")
                bbox, vf, bbox_obj = None, None, None
                if info_list is not None:
                    if "bbox_obj" in info_list[gi]:
                        bbox_obj = _floats(info_list[gi]["bbox_obj"], 4, info_path,
                                           f"{where}: bbox_obj").astype(np.int64)
                    bbox = _floats(_get(info_list[gi], "bbox_visib", info_path, where), 4, info_path,
                                   f"{where}: bbox_visib").astype(np.int64)
                    vf = float(_floats(_get(info_list[gi], "visib_fract", info_path, where), 1, info_path,
                                       f"{where}: visib_fract")[0])
                    if bbox[2] <= 0 or bbox[3] <= 0 or vf < min_visib:
                        continue
                if rgb is None:
                    rgb = _rgb_path(scene_dir, im_id)  # only looked up for images we keep
                yield Instance(scene_id, im_id, gi, obj_id, R, t, K, rgb,
                               scene_dir / "mask_visib" / f"{im_id:06d}_{gi:06d}.png", bbox, vf, bbox_obj)


# --------------------------------------------------------------------------- crops

def _read_image(path: Path, flags: int, what: str) -> np.ndarray:
    if not path.is_file():
        raise BOPFormatError(f"{path}: file does not exist (expected the {what})")
    img = cv2.imread(str(path), flags)
    if img is None:
        raise BOPFormatError(f"{path}: cannot decode as an image (expected the {what})")
    return img


def _crop_square(img: np.ndarray, x0: int, y0: int, side: int) -> np.ndarray:
    """The side x side window with top-left (x0, y0); parts outside the image are 0."""
    out = np.zeros((side, side) + img.shape[2:], img.dtype)
    h, w = img.shape[:2]
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + side, w), min(y0 + side, h)
    if sx1 > sx0 and sy1 > sy0:
        out[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = img[sy0:sy1, sx0:sx1]
    return out


def crop_instance(inst: Instance, size: int = 128, pad: float = 1.0,
                  box: str = "visib") -> tuple[np.ndarray, np.ndarray]:
    """Square crop of the visible object, resized to ``size`` x ``size``.

    The square is centred on the visible bounding box (``bbox_visib``, or the
    mask's bounding box if that is unknown) and its side is ``pad`` times the
    box's longer side (``pad=1`` is tight). Parts outside the image are black.
    ``box="obj"`` centres on the whole object's box (``bbox_obj``) instead,
    which matches silhouette-framed renders better under occlusion.

    Returns:
        crop: (size, size, 3) uint8 RGB.
        mask: (size, size) bool visible-object mask in the same crop.
    """
    if int(size) != size or size < 8:
        raise ValueError(f"crop_instance: size must be an integer >= 8, got {size}")
    if not pad > 0:
        raise ValueError(f"crop_instance: pad must be > 0, got {pad}")
    bgr = _read_image(inst.rgb_path, cv2.IMREAD_COLOR, "colour image")
    mask = _read_image(inst.mask_path, cv2.IMREAD_GRAYSCALE, f"visible mask of object {inst.obj_id}") > 0
    if mask.shape != bgr.shape[:2]:
        raise BOPFormatError(f"{inst.mask_path}: mask is {mask.shape}, expected the image size {bgr.shape[:2]}")
    if box not in ("visib", "obj"):
        raise ValueError(f"crop_instance: box must be 'visib' or 'obj', got {box!r}")
    if box == "obj":
        if inst.bbox_obj is None:
            raise BOPFormatError(f"{inst.rgb_path.parent.parent / 'scene_gt_info.json'}: no bbox_obj for "
                                 f"image {inst.im_id} pose {inst.gt_index} (needed by box='obj')")
        x, y, w, h = (float(v) for v in inst.bbox_obj)
    elif inst.bbox_visib is not None:
        x, y, w, h = (float(v) for v in inst.bbox_visib)
    else:
        ys, xs = np.nonzero(mask)
        if len(xs) == 0:
            raise BOPFormatError(f"{inst.mask_path}: mask is empty (expected visible pixels of object {inst.obj_id})")
        x, y, w, h = xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1
    side = max(1, int(round(pad * max(w, h))))
    x0 = int(round(x + w / 2 - side / 2))
    y0 = int(round(y + h / 2 - side / 2))
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    # Area filter when shrinking avoids aliasing; bilinear when enlarging.
    interp = cv2.INTER_AREA if side > size else cv2.INTER_LINEAR
    crop = cv2.resize(_crop_square(rgb, x0, y0, side), (int(size), int(size)), interpolation=interp)
    mcrop = cv2.resize(_crop_square(mask.astype(np.uint8), x0, y0, side), (int(size), int(size)),
                       interpolation=cv2.INTER_NEAREST) > 0
    return np.ascontiguousarray(crop, dtype=np.uint8), mcrop


def load_bop_views(root: str | os.PathLike, split: str, obj_id: int, size: int = 128,
                   max_instances: int | None = None, *, min_visib: float = 0.0, pad: float = 1.0,
                   box: str = "visib",
                   name: str | None = None, step_deg: float | None = None) -> ObjectViews:
    """All (or an evenly spread subset of) instances of one object as query views.

    Args:
        root, split: dataset root and split folder.
        obj_id: BOP object id.
        size: crop side, pixels.
        max_instances: if set, keep this many instances spread evenly over the
            sorted list (so every scene is represented, unlike "the first n").
        min_visib, pad, box: see :func:`iter_scene_instances` and :func:`crop_instance`.
        name: ObjectViews name (default ``"obj_XXXXXX"``).
        step_deg: None (default): continuous symmetries kept exact (errors minimised in
            closed form); a number: discretised every ``step_deg`` degrees, as before.

    Returns:
        ObjectViews(kind="query") with images (N,size,size,3) uint8, rotations
        (N,3,3) float32 ``R_m2c``, masks (N,size,size) bool, the object's
        symmetries, and ``meta["instances"]`` = list of (scene_id, im_id, gt_index).
    """
    infos = load_models_info(root, step_deg or 10.0)
    if int(obj_id) not in infos:
        raise BOPFormatError(f"{_models_info_path(Path(root))}: object {obj_id} is not listed "
                             f"(known: {sorted(infos)})")
    insts = list(iter_scene_instances(root, split, [int(obj_id)], min_visib))
    if not insts:
        raise BOPFormatError(f"{Path(root) / split}: no instances of object {obj_id} "
                             f"(with visib_fract >= {min_visib})")
    if max_instances is not None:
        if max_instances < 1:
            raise ValueError(f"load_bop_views: max_instances must be >= 1 or None, got {max_instances}")
        if max_instances < len(insts):
            idx = np.unique(np.linspace(0, len(insts) - 1, max_instances).round().astype(int))
            insts = [insts[i] for i in idx]
    images = np.empty((len(insts), size, size, 3), np.uint8)
    masks = np.empty((len(insts), size, size), bool)
    for i, inst in enumerate(insts):
        images[i], masks[i] = crop_instance(inst, size, pad, box)
    rots = np.stack([inst.R_m2c for inst in insts]).astype(np.float32)
    return ObjectViews(name or f"obj_{int(obj_id):06d}", images, rots, masks, kind="query",
                       symmetries=(infos[int(obj_id)].exact_symmetries if step_deg is None
                                   else infos[int(obj_id)].symmetries),
                       meta={"source": "bop", "root": str(root), "split": split, "obj_id": int(obj_id),
                             "size": int(size), "pad": float(pad), "box": box, "min_visib": float(min_visib),
                             "instances": [(i.scene_id, i.im_id, i.gt_index) for i in insts]})
