"""Real LineMOD / LineMOD-O crops as view sets, cached: what the study's notebooks read when given ``bop_root``.

``bop_root`` is a folder of BOP data sets as the BOP toolkit lays them out: ``<bop_root>/lm`` (LineMOD: meshes,
and the images every split's training, validation and test views come from) and ``<bop_root>/lmo``
(LineMOD-Occluded: the occluded test views of the unseen objects). :func:`bop_folders` checks that layout.

:func:`real_views` crops every annotated instance of one object (the paper's crop rule,
:data:`helpers.data.linemod_bop.DATASETS`) at one size and caches the crops under
``<cache>/real/<dataset>/<name>-<key>``. The key hashes the annotations (every scene's ``scene_gt.json``,
``scene_gt_info.json`` and ``scene_camera.json``), the object, the crop size and the context; it does not hash
the colour images (15,000 PNGs): replacing images under unchanged annotations needs ``prune`` or a new cache.
Several processes asking for the same crops at once are safe (one builds under the entry's lock, the others
wait and load).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from ..core.fileio import atomic_save_npy, atomic_write_json, read_json, sha256_file, stable_hash
from ..core.locks import entry_lock, settle
from ..core.paths import cache_dir, repo_path
from ..core.views import ObjectViews
from .bop import BOPFormatError, crop_instance, iter_scene_instances, load_models_info
from .linemod_bop import DATASETS, object_id

#: Bumped when the crops of the same annotations change.
CROP_VERSION = 1
_ARRAYS = ("images", "masks", "rotations")


def bop_folders(bop_root: str | os.PathLike) -> dict[str, Path]:
    """{"lm": <bop_root>/lm, "lmo": <bop_root>/lmo}, each checked to hold ``models/`` and its test folder;
    ``lmo`` only where that folder exists (without it, the occluded part of the evaluation is left out).
    A relative ``bop_root`` is read from the repository root (as every notebook path parameter).

    Raises :class:`helpers.data.bop.BOPFormatError` naming the folder and the layout expected.
    """
    root = repo_path(bop_root)
    if not root.is_dir():
        raise BOPFormatError(f"bop_root {root}: not a folder (expected a folder of BOP data sets holding lm/ "
                             "(LineMOD) and, for the occluded part, lmo/ (LineMOD-Occluded), as the BOP toolkit "
                             "lays them out)")
    out = {}
    for name, spec in DATASETS.items():
        d = root / name
        if name != "lm" and not d.exists():
            continue
        for need in ("models", spec["split"]):
            if not (d / need).is_dir():
                raise BOPFormatError(f"{d / need}: folder does not exist (bop_root {root} must hold lm/ and may "
                                     f"hold lmo/, in the BOP layout: <dataset>/models/models_info.json, "
                                     f"obj_XXXXXX.ply and <dataset>/{spec['split']}/<scene>/...)")
        out[name] = d.resolve()
    return out


def _annotation_sums(root: Path, split: str) -> list[str]:
    """sha256 of every scene's annotation files, in scene order (what the crops' key covers)."""
    sums = []
    for scene in sorted(p for p in (root / split).iterdir() if p.is_dir() and p.name.isdigit()):
        for f in ("scene_gt.json", "scene_gt_info.json", "scene_camera.json"):
            sums.append(sha256_file(scene / f) if (scene / f).is_file() else "")
    return sums


def real_views(root: str | os.PathLike, dataset: str, name: str, size: int, context: float = 1.0,
               cache: str | os.PathLike | None = None, progress: bool = True) -> ObjectViews:
    """Every annotated instance of LineMOD object ``name`` in ``dataset``'s test folder as query views.

    Args:
        root: the data set folder (``<bop_root>/lm`` or ``<bop_root>/lmo``).
        dataset: ``"lm"`` (crops on the whole object's box, ``bbox_obj``) or ``"lmo"`` (the visible box).
        size: side of the crop the network sees, pixels.
        context: the stored image is ``round(size * context)`` pixels and covers ``context`` times the box (the
            training queries keep surroundings for the in-plane augmentation); 1 = the tight square crop.

    Returns:
        ObjectViews(kind="query"): images (N, C, C, 3) uint8, masks (N, C, C) bool (visible object), rotations
        (N, 3, 3) float32 ``R_m2c``, the object's symmetries from ``models_info.json``, and meta with
        ``key`` (the cache key, which training run keys include), ``instances`` [(scene_id, im_id, gt_index)]
        in sorted order and ``sorted_views`` (a sample of them is taken spread evenly).
    """
    if dataset not in DATASETS:
        raise ValueError(f"real_views: dataset must be one of {sorted(DATASETS)}, got {dataset!r}")
    root = Path(root)
    oid = object_id(name)
    infos = load_models_info(root)
    if oid not in infos:
        raise BOPFormatError(f"{root / 'models' / 'models_info.json'}: object {oid} ({name}) is not listed")
    split, box = DATASETS[dataset]["split"], DATASETS[dataset]["box"]
    side = int(round(size * context))
    key = stable_hash({"v": CROP_VERSION, "dataset": dataset, "obj_id": oid, "side": side, "context": context,
                       "box": box, "annotations": _annotation_sums(root, split)})
    d = cache_dir(cache) / "real" / dataset / f"{name}-{key}"
    if not (d / "meta.json").exists():
        with entry_lock(d, f"real crops {dataset}/{name}"):
            if not (d / "meta.json").exists():  # the instances are listed only to build (cached: from meta)
                insts = list(iter_scene_instances(root, split, [oid]))
                if not insts:
                    raise BOPFormatError(f"{root / split}: no annotated instance of object {oid} ({name})")
                _build(d, insts, side, context, box, f"{dataset} {name}", progress)
    settle(d)
    meta = read_json(d / "meta.json")
    arrays = {k: np.load(d / f"{k}.npy", mmap_mode="r") for k in _ARRAYS}
    return ObjectViews(name, arrays["images"], np.asarray(arrays["rotations"]), arrays["masks"], kind="query",
                       symmetries=infos[oid].exact_symmetries,
                       meta={"key": f"real-{dataset}-{key}", "source": f"BOP {dataset}", "obj_id": oid,
                             "sorted_views": True,  # in scene and image order: subsample evenly, not the first k
                             "box": box, "context": context, "instances": [tuple(i) for i in meta["instances"]]})


def _build(d: Path, insts: list, side: int, context: float, box: str, what: str, progress: bool) -> None:
    """Crop every instance (box made square without margin, times ``context``) and write the arrays, then meta."""
    d.mkdir(parents=True, exist_ok=True)
    images = np.empty((len(insts), side, side, 3), np.uint8)
    masks = np.empty((len(insts), side, side), bool)
    for i, inst in enumerate(tqdm(insts, desc=f"cropping {what}", unit="img", disable=not progress)):
        images[i], masks[i] = crop_instance(inst, side, context, box)
    rotations = np.stack([inst.R_m2c for inst in insts]).astype(np.float32)
    sums = {}
    for k, a in (("images", images), ("masks", masks), ("rotations", rotations)):
        sums[f"{k}.npy"] = sha256_file(atomic_save_npy(d / f"{k}.npy", a))
    atomic_write_json(d / "meta.json", {"instances": [[i.scene_id, i.im_id, i.gt_index] for i in insts],
                                        "sha256": sums})


def spread(n: int, k: int) -> np.ndarray:
    """Indices of ``k`` of ``n`` items spread evenly over the sorted list (all when ``k`` is 0 or >= n)."""
    if not k or k >= n:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, k).round().astype(int))
