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

import numpy as np

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
