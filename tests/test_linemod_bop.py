"""The paper's LineMOD conventions for real BOP data: object ids, splits, and the seen views' separation."""

from __future__ import annotations

import numpy as np
import pytest

from helpers.data import linemod_bop as lm


def test_the_paper_splits_partition_the_13_objects():
    unseen = [n for s in (1, 2, 3) for n in lm.unseen_objects(s)]
    assert sorted(unseen) == sorted(lm.LM_OBJECTS.values()) and len(unseen) == 13  # each object unseen once
    assert lm.unseen_objects(1) == ("ape", "benchvise", "cam", "can")
    assert lm.unseen_objects(3) == ("glue", "holepuncher", "iron", "lamp", "phone")
    for s in (1, 2, 3):
        assert set(lm.seen_objects(s)).isdisjoint(lm.unseen_objects(s))
        assert len(lm.seen_objects(s)) + len(lm.unseen_objects(s)) == 13
    assert lm.object_id("eggbox") == 10 and lm.object_name(15) == "phone"
    assert set(lm.dataset_objects("lmo")) == {"ape", "can", "cat", "driller", "duck", "eggbox", "glue", "holepuncher"}


@pytest.mark.parametrize("call, match", [
    (lambda: lm.object_name(3), "not one of the paper's 13 objects"),  # bowl
    (lambda: lm.object_name(7), "not one of the paper's 13 objects"),  # cup
    (lambda: lm.object_id("bowl"), "not one of the paper's LineMOD objects"),
    (lambda: lm.unseen_objects(4), "the paper's LineMOD splits are"),
    (lambda: lm.dataset_objects("tless"), "expected one of"),
])
def test_ids_and_names_outside_the_table_are_refused(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_seen_views_separate_into_train_val_and_a_ten_percent_test_split():
    p = lm.partition_views(1200, 24)
    assert len(p["test"]) == 120 and (p["test"] % 10 == 0).all()  # the paper's 10 % seen test split
    assert len(p["val"]) == 24 and len(p["train"]) == 1200 - 120 - 24
    allv = np.concatenate([p["train"], p["val"], p["test"]])
    assert sorted(allv) == list(range(1200))  # disjoint, and every view is used once
    assert np.ptp(p["val"]) > 900  # spread over the sequence, not its first images
    assert {k: list(v) for k, v in lm.partition_views(1200, 24).items()} == {k: list(v) for k, v in p.items()}
    with pytest.raises(ValueError, match="leave none to train on"):
        lm.partition_views(20, 18)


def test_a_bop_folder_becomes_a_manifest_with_the_papers_splits_and_declared_symmetries(tmp_path):
    import json

    import trimesh
    from test_bop import make_bop  # the hand-made BOP folder: objects 1 (ape) and 2 (benchvise)

    from helpers.core.fileio import sha256_file
    from helpers.core.rotations import Symmetries
    from helpers.data.bop import BOPFormatError

    root = make_bop(tmp_path / "lm")
    m = lm.bop_manifest(root)
    assert m.object_names() == ["ape", "benchvise"] and m.split_objects(1) == ["ape", "benchvise"]
    assert m.split_objects(2) == [] and m.seen_objects(2) == ["ape", "benchvise"] and m.held_out_objects() == []
    ape = m.object("ape")
    assert ape.mesh.resolve() == (root / "models" / "obj_000001.ply").resolve()
    assert ape.mesh.sha256 == sha256_file(ape.mesh.resolve())
    g = ape.symmetry_group()  # identity and the declared 180 deg turn about z
    assert g.shape == (2, 3, 3) and np.allclose(g[1], np.diag([-1.0, -1.0, 1.0]))
    bv = m.object("benchvise").symmetry_group()  # a continuous axis, kept exact
    assert isinstance(bv, Symmetries) and np.allclose(bv.axes, [[0, 0, 1]])

    trimesh.creation.box(extents=(5, 5, 5)).export(root / "models" / "obj_000004.ply")  # cam: mesh, no entry
    with pytest.raises(BOPFormatError, match=r"no entry for the mesh\(es\) of object id\(s\) \[4\] \(cam\)"):
        lm.bop_manifest(root)
    (root / "models" / "obj_000004.ply").unlink()
    (root / "models" / "obj_000001.ply").unlink()
    with pytest.raises(BOPFormatError, match="obj_000001.ply: file does not exist.*ape"):
        lm.bop_manifest(root)
    with pytest.raises(BOPFormatError, match="no models_info.json"):
        lm.bop_manifest(tmp_path)
    bowl = tmp_path / "bowl"
    (bowl / "models").mkdir(parents=True)
    (bowl / "models" / "models_info.json").write_text(json.dumps({"3": {"diameter": 10.0}}))
    with pytest.raises(BOPFormatError, match="none of the paper's LineMOD objects"):
        lm.bop_manifest(bowl)
    with pytest.raises(ValueError, match="expected one of"):
        lm.bop_manifest(root, "ycbv")
