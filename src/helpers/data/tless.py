"""The T-LESS-like cross-dataset set: generated textureless parts (:mod:`helpers.data.parts`) on a table among
other parts of the same family, with the depth image of every query (for err_vsd, :mod:`helpers.evaluation.vsd`).

Protocol (the paper's Table 3, adapted): a model trained on the LineMOD-like objects only retrieves each query
among the references of ALL parts (the category is retrieved, not given; the same rule for HOG and Global).
A query is correct when err_vsd <= 0.3 with the estimated rotation and the ground-truth translation; Rota. Acc.
at 30 deg (symmetries included) is reported beside it.

Scenes: a part rests on a photo-textured table in one of its stable poses; 2-4 other parts of the family stand
around it, anywhere in azimuth (so some stand in front and hide part of it); the camera looks from the upper
hemisphere (elevation 15-75 deg). A view is kept only if at least ``min_visible`` of the part's silhouette is
visible. Each query stores its crop, its visible mask, its label ``R_m2c`` and the full-frame depth (metres) of
the scene; the part sits at ``t = (0, 0, distance_diameters * diameter)`` in the camera frame with the render
intrinsics ``K`` of :meth:`helpers.data.render.RenderConfig.intrinsics` (the references' camera).
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from ..core.configs import TlessConfig
from ..core.fileio import atomic_save_npy, atomic_write_json, check_sha256, sha256_file, stable_hash
from ..core.locks import entry_lock
from ..core.paths import cache_dir
from ..core.rotations import haar_uniform
from ..core.views import ObjectViews
from .bop import BOPFormatError, iter_scene_instances, load_bop_views, load_model_mesh, load_models_info
from .datasets import background_photos
from .manifest import Manifest, load_manifest
from .meshes import ObjectMesh, set_color
from .parts import load_part
from .render import apply_sensor, crop_view, query_style, render_reference
from .tabletop import ClutterFamily, render_tabletop

#: The T-LESS-like query style. Calibrated with HOG nearest neighbour only (never a trained model); see
#: docs/method.md for the calibration line. Parts are grey: no colour jitter beyond the lighting's.
TLESS_STYLE = dict(n_clutter=(2, 4), clutter_size=(0.7, 1.1), clutter_distance=(0.75, 1.3), color_scale=0.08)
#: Grey of every part (T-LESS parts are grey plastic).
PART_GREY = (0.62, 0.62, 0.6)
#: Per-query arrays stored for each part (besides its references).
_QUERY_ARRAYS = ("images", "masks", "rotations", "depth", "frames", "full", "visible")
SET_VERSION = 2  # 2: full frames and masks kept (BOP export)


@dataclass
class TlessSet:
    """The rendered set.

    Attributes:
        cfg: its configuration.
        parts: name -> ObjectMesh (metres, real size).
        refs: name -> references (n_references views at shared rotations).
        queries: name -> query crops with labels and symmetries.
        depth: name -> (n_queries, R, R) float16 scene depth, metres (R = render_size).
        frames: name -> (n_queries, R, R, 3) uint8 full-frame colour of each query scene (before the crop's
            sensor noise), and ``full``/``visible``: name -> (n_queries, R, R) bool silhouette of the part alone /
            its visible part (what BOP calls mask and mask_visib).
        key: the cache key of the rendered set (its folder's name).
        instances: a real BOP dataset's set only (:func:`load_bop_tless`): name -> the queries'
            :class:`helpers.data.bop.Instance` (camera, pose, image), whose depth images are read when scoring.
    """

    cfg: TlessConfig
    parts: dict[str, ObjectMesh]
    refs: dict[str, ObjectViews]
    queries: dict[str, ObjectViews]
    depth: dict[str, np.ndarray]
    frames: dict[str, np.ndarray] = field(default_factory=dict)
    full: dict[str, np.ndarray] = field(default_factory=dict)
    visible: dict[str, np.ndarray] = field(default_factory=dict)
    key: str = ""
    instances: dict[str, list] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return list(self.parts)


def _key(cfg: TlessConfig, m: Manifest) -> str:
    return stable_hash({"v": SET_VERSION, "cfg": asdict(cfg), "style": TLESS_STYLE, "grey": PART_GREY,
                        "parts": [p.sha256 for p in m.parts.items],
                        "photos": [b.file.sha256 for b in m.backgrounds if b.split == "test"]})


def _render_queries(obj: ObjectMesh, family: ClutterFamily, cfg: TlessConfig, photos: dict, rng) -> dict:
    style = query_style("linemod", **TLESS_STYLE)
    rc = cfg.render_config()
    out = {"images": [], "masks": [], "rotations": [], "depth": [], "frames": [], "full": [], "visible": []}
    tries = 0
    while len(out["images"]) < cfg.n_queries:
        tries += 1
        if tries > 20 * cfg.n_queries:
            raise RuntimeError(f"part {obj.name!r}: fewer than {cfg.n_queries} views with >= {cfg.min_visible:.0%} "
                               f"visible in {tries} tries; lower min_visible or the clutter")
        color, depth, full, visible, vp = render_tabletop(obj, rc, style, photos, rng, family)
        if visible.sum() < cfg.min_visible * max(1, full.sum()):
            continue
        img, vis = crop_view(color, visible, rc, style, rng)
        out["images"].append(apply_sensor(img, style, rng))
        out["masks"].append(vis)
        out["rotations"].append(vp.R_m2c.astype(np.float32))
        out["depth"].append(depth.astype(np.float32))
        out["frames"].append(color)
        out["full"].append(full)
        out["visible"].append(visible)
    return {k: np.stack(v) for k, v in out.items()}


def _build(d: Path, cfg: TlessConfig, m: Manifest, parts: dict[str, ObjectMesh], progress: bool) -> None:
    photos = background_photos(m, "test")
    R_refs = haar_uniform(cfg.n_references, seed=cfg.seed)
    sums = {}
    names = list(parts)
    bar = tqdm(total=len(names) * (cfg.n_references + cfg.n_queries), desc="T-LESS-like set", unit="view",
               disable=not progress)
    for i, name in enumerate(names):
        obj = parts[name]
        refs = [render_reference(obj, R, cfg.render_config())[0] for R in R_refs]
        bar.update(cfg.n_references)
        others = tuple(parts[n].mesh for n in names if n != name)
        family = ClutterFamily(f"tless-{name}", others, PART_GREY)
        q = _render_queries(obj, family, cfg, photos, np.random.default_rng([cfg.seed, 31337, i]))
        bar.update(cfg.n_queries)
        arrays = {"refs": np.stack(refs), **{k: q[k] for k in _QUERY_ARRAYS if k != "depth"},
                  "depth": q["depth"].astype(np.float16)}
        for k, a in arrays.items():
            f = atomic_save_npy(d / f"{name}.{k}.npy", a)
            sums[f.name] = sha256_file(f)
    bar.close()
    atomic_write_json(d / "meta.json", {"cfg": asdict(cfg), "style": TLESS_STYLE, "parts": names,
                                        "ref_seed": cfg.seed, "sha256": sums})


def load_tless(cfg: TlessConfig = TlessConfig(), cache: str | os.PathLike | None = None,
               manifest: Manifest | None = None, progress: bool = True) -> TlessSet:
    """The T-LESS-like set of ``cfg``: rendered once into ``<cache>/tless/<key>`` (under the entry's lock,
    files checksummed in meta.json), then loaded."""
    m = manifest or load_manifest()
    parts = {p.name: load_part(p.name, m, cache, PART_GREY) for p in m.parts.items}
    d = cache_dir(cache) / "tless" / _key(cfg, m)
    if not (d / "meta.json").exists():
        with entry_lock(d, f"T-LESS-like set {d.name}"):
            if not (d / "meta.json").exists():
                d.mkdir(parents=True, exist_ok=True)
                _build(d, cfg, m, parts, progress)
    meta = json.loads((d / "meta.json").read_text())
    R_refs = haar_uniform(cfg.n_references, seed=meta["ref_seed"]).astype(np.float32)
    refs, queries, depth, frames, full, visible = {}, {}, {}, {}, {}, {}
    for name, obj in parts.items():
        arr = {k: _load_checked(d / f"{name}.{k}.npy", meta["sha256"]) for k in ("refs", *_QUERY_ARRAYS)}
        refs[name] = ObjectViews(name, arr["refs"], R_refs, None, "reference", obj.symmetries)
        queries[name] = ObjectViews(name, arr["images"], arr["rotations"], arr["masks"], "query", obj.symmetries)
        depth[name] = arr["depth"]
        for k, store in (("frames", frames), ("full", full), ("visible", visible)):
            store[name] = arr[k]
    return TlessSet(cfg, parts, refs, queries, depth, frames, full, visible, d.name)


def _load_checked(f: Path, sums: dict) -> np.ndarray:
    check_sha256(f, sums.get(f.name, ""), f.parent / "meta.json",
                 f"delete {f.parent} (the next run renders it again)")
    return np.load(f)


def load_bop_tless(root: str | os.PathLike, split: str = "test_primesense", size: int = 64, render_size: int = 96,
                   n_references: int = 512, max_instances: int | None = None, min_visib: float = 0.1,
                   seed: int = 0, progress: bool = True) -> TlessSet:
    """A real T-LESS (or any BOP dataset with depth) as the same kind of set: queries cropped from ``split``
    (:func:`helpers.data.bop.load_bop_views`, at most ``max_instances`` per object), references rendered from its
    models (grey, model frame kept) at ``n_references`` Haar-uniform rotations; err_vsd then reads each
    query's depth image. Not cached (the references take about a minute per 10,000 renders)."""
    root = Path(root)
    infos = load_models_info(root)
    cfg = TlessConfig(image_size=size, render_size=render_size, n_references=n_references, seed=seed)
    R_refs = haar_uniform(n_references, seed=seed)
    parts, refs, queries, instances = {}, {}, {}, {}
    by_key = {(i.scene_id, i.im_id, i.gt_index): i for i in iter_scene_instances(root, split, None, min_visib)}
    present = {i.obj_id for i in by_key.values()}
    for oid, info in tqdm(sorted(infos.items()), desc="BOP objects", disable=not progress):
        if oid not in present:
            continue  # an object without test instances in this split
        name = f"obj_{oid:06d}"
        mesh = set_color(load_model_mesh(root, oid), PART_GREY)
        mesh.apply_scale(0.001)  # mm -> m, model frame kept (BOP poses refer to it)
        obj = ObjectMesh(name, mesh, info.diameter / 1000.0, False, sha256_file(root / "models" / f"{name}.ply"),
                         info.symmetries)
        q = load_bop_views(root, split, oid, size, max_instances, min_visib=min_visib, name=name)
        parts[name] = obj
        refs[name] = ObjectViews(name, np.stack([render_reference(obj, R, cfg.render_config())[0] for R in R_refs]),
                                 R_refs.astype(np.float32), None, "reference", info.symmetries)
        queries[name] = q
        instances[name] = [by_key[k] for k in q.meta["instances"]]
    if not parts:
        raise BOPFormatError(f"{root / split}: no object has test instances with visib_fract >= {min_visib}")
    key = "bop-" + stable_hash([str(root.resolve()), split, size, render_size, n_references, max_instances,
                                min_visib, seed])
    return TlessSet(cfg, parts, refs, queries, {}, key=key, instances=instances)
