"""LineMOD and LineMOD-Occluded in BOP format, as the paper uses them: object ids, the three splits of unseen
objects, the crop rule and how one object's real views are separated into training, validation and test.

* Objects: the 13 LineMOD objects of the paper by BOP id (bowl, 3, and cup, 7, have no good models and are not used).
  LineMOD-O annotates eight of them in one scene.
* Splits of unseen objects (the paper's): #1 ape, benchvise, cam, can; #2 cat, driller, duck, eggbox; #3 glue,
  holepuncher, iron, lamp, phone. A split's model trains on the other objects.
* Crops, as the authors': the object's tight ground-truth box made square without margin (``bbox_obj`` for
  LineMOD; LineMOD-O's visible box, ``bbox_visib``, since its objects are occluded).
* Views of a SEEN object (:func:`partition_views`): every tenth image of the sorted list is a test view (the paper's
  10 % seen test split), ``n_val`` of the rest, spread evenly, are held-out validation views for model selection,
  and the remainder trains. An unseen object's views are all test views; no model trains or selects on them.

Symmetries come from the dataset's ``models_info.json`` (:func:`helpers.data.bop.load_models_info`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..core.fileio import sha256_file
from ..core.rotations import Symmetries
from .bop import BOPFormatError, _models_info_path, load_models_info
from .manifest import FileEntry, Manifest, ObjectEntry, Source

#: BOP object id -> name, the 13 LineMOD objects of the paper.
LM_OBJECTS: dict[int, str] = {1: "ape", 2: "benchvise", 4: "cam", 5: "can", 6: "cat", 8: "driller", 9: "duck",
                              10: "eggbox", 11: "glue", 12: "holepuncher", 13: "iron", 14: "lamp", 15: "phone"}
#: The objects LineMOD-O annotates (BOP ids).
LMO_OBJECT_IDS: tuple[int, ...] = (1, 5, 6, 8, 9, 10, 11, 12)
#: The paper's splits of unseen objects, by name.
PAPER_SPLITS: dict[int, tuple[str, ...]] = {1: ("ape", "benchvise", "cam", "can"),
                                            2: ("cat", "driller", "duck", "eggbox"),
                                            3: ("glue", "holepuncher", "iron", "lamp", "phone")}
#: The BOP dataset names this module reads, with the box their crops are taken from and their test split folder.
DATASETS: dict[str, dict[str, str]] = {"lm": {"box": "obj", "split": "test"},
                                       "lmo": {"box": "visib", "split": "test"}}
#: Every tenth view of a seen object is a test view (the paper's 10 % seen test split).
SEEN_TEST_EVERY = 10


def object_name(obj_id: int) -> str:
    """The LineMOD name of a BOP object id; an id outside the paper's 13 objects is an error naming them."""
    if int(obj_id) not in LM_OBJECTS:
        raise ValueError(f"LineMOD object id {obj_id} is not one of the paper's 13 objects "
                         f"({', '.join(f'{i}: {n}' for i, n in LM_OBJECTS.items())})")
    return LM_OBJECTS[int(obj_id)]


def object_id(name: str) -> int:
    """The BOP id of a LineMOD object name (an unknown name is an error listing the 13)."""
    ids = {n: i for i, n in LM_OBJECTS.items()}
    if name not in ids:
        raise ValueError(f"{name!r} is not one of the paper's LineMOD objects: {sorted(ids)}")
    return ids[name]


def unseen_objects(split: int) -> tuple[str, ...]:
    """The unseen (test) objects of the paper's split #``split`` (1-3)."""
    if split not in PAPER_SPLITS:
        raise ValueError(f"split {split}: the paper's LineMOD splits are {sorted(PAPER_SPLITS)}")
    return PAPER_SPLITS[split]


def seen_objects(split: int) -> tuple[str, ...]:
    """The objects split #``split``'s model trains on: the 13 minus its unseen ones, in id order."""
    unseen = set(unseen_objects(split))
    return tuple(n for n in LM_OBJECTS.values() if n not in unseen)


def dataset_objects(dataset: str) -> tuple[str, ...]:
    """The paper's objects annotated in ``dataset`` ("lm": all 13; "lmo": its eight)."""
    if dataset not in DATASETS:
        raise ValueError(f"dataset {dataset!r}: expected one of {sorted(DATASETS)}")
    return tuple(LM_OBJECTS[i] for i in (LM_OBJECTS if dataset == "lm" else LMO_OBJECT_IDS))


def partition_views(n: int, n_val: int) -> dict[str, np.ndarray]:
    """Indices (into a seen object's views sorted by scene and image) of its train, val and test views.

    Test: every :data:`SEEN_TEST_EVERY`-th view (0, 10, 20, ...); val: ``n_val`` of the others, spread evenly;
    train: the rest. The three are disjoint and cover ``range(n)``; deterministic, so every run and notebook
    separates the same views.
    """
    if n < 1 or n_val < 0:
        raise ValueError(f"partition_views: expected n >= 1 views and n_val >= 0, got n={n}, n_val={n_val}")
    idx = np.arange(n)
    test = idx[idx % SEEN_TEST_EVERY == 0]
    rest = idx[idx % SEEN_TEST_EVERY != 0]
    if n_val >= len(rest):
        raise ValueError(f"partition_views: {n_val} validation views leave none to train on ({n} views, "
                         f"{len(test)} of them test views)")
    pick = np.unique(np.linspace(0, len(rest) - 1, n_val).round().astype(int)) if n_val else np.array([], int)
    val = rest[pick]
    train = np.setdiff1d(rest, val)
    return {"train": train, "val": val, "test": test}


def _symmetry_fields(group) -> tuple[tuple, tuple]:
    """(discrete rotations without the identity, continuous axes) of a models_info group, as ObjectEntry holds them."""
    disc = group.discrete if isinstance(group, Symmetries) else np.asarray(group)
    axes = tuple(map(tuple, group.axes)) if isinstance(group, Symmetries) else ()
    rots = tuple(tuple(map(tuple, R)) for R in disc if not np.allclose(R, np.eye(3)))
    return rots, axes


def bop_manifest(root: str | os.PathLike, dataset: str = "lm") -> Manifest:
    """The paper's LineMOD objects present in a BOP folder as a :class:`helpers.data.manifest.Manifest`: role
    ``train``, each with its paper split, its mesh ``models/obj_XXXXXX.ply`` (sha256 taken here) and the
    symmetries ``models_info.json`` declares; objects outside the paper's 13 (bowl, cup) are left out.

    Errors (:class:`helpers.data.bop.BOPFormatError`) name the folder or file: no ``models_info.json``, a mesh of
    the paper's objects without its ``models_info.json`` entry, an entry without its mesh, none of the objects.
    """
    if dataset not in DATASETS:
        raise ValueError(f"dataset {dataset!r}: expected one of {sorted(DATASETS)}")
    root = Path(root).resolve()
    info_path = _models_info_path(root)
    infos = load_models_info(root)
    wanted = {object_id(n) for n in dataset_objects(dataset)}
    meshes = {int(p.stem.split("_")[1]) for p in (root / "models").glob("obj_*.ply") if p.stem[4:].isdigit()}
    orphans = sorted((meshes & wanted) - set(infos))
    if orphans:
        raise BOPFormatError(f"{info_path}: no entry for the mesh(es) of object id(s) {orphans} "
                             f"({', '.join(LM_OBJECTS[i] for i in orphans)}); every mesh needs its symmetries entry")
    source = Source(name=f"BOP {dataset}", package="", version="", licence="the data set's own", module="")
    objects = []
    for obj_id in sorted(wanted & set(infos)):
        mesh = root / "models" / f"obj_{obj_id:06d}.ply"
        if not mesh.is_file():
            raise BOPFormatError(f"{mesh}: file does not exist (expected the mesh of object {obj_id}, "
                                 f"{LM_OBJECTS[obj_id]}, listed in {info_path})")
        name = LM_OBJECTS[obj_id]
        split = next(s for s, names in PAPER_SPLITS.items() if name in names)
        rots, axes = _symmetry_fields(infos[obj_id].exact_symmetries)
        objects.append(ObjectEntry(name, "train", split, source,
                                   FileEntry("", str(mesh.relative_to(root)), sha256_file(mesh), str(root)), (), None,
                                   source.licence, f"LineMOD {name} (BOP {dataset} object {obj_id})", rots, axes))
    if not objects:
        raise BOPFormatError(f"{info_path}: none of the paper's LineMOD objects is listed "
                             f"(expected BOP ids among {sorted(wanted)})")
    return Manifest(info_path, {source.name: source}, tuple(objects), ())
