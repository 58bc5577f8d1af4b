"""Extra training objects (issue #44, screen e): the committed list of extra meshes, the recipes that train on them,
and the curve over N."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from helpers.core.configs import ExtraConfig
from helpers.data.extra_objects import (EXTRA_FILE, build, candidate_meshes, load_extras, mesh_problem, parse,
                                        with_extras, write)
from helpers.data.manifest import ManifestError, load_manifest
from helpers.data.meshes import load_mesh_file
from helpers.study import zoo
from helpers.study.protocols.extra_objects import extra_counts, extra_curve
from helpers.study.protocols.screens import CURRENT, changes
from helpers.study.protocols.variants import Trained

from test_zoo import TINY


def test_the_extras_file_is_what_the_rule_writes_and_keeps_its_lists_apart(tmp_path):
    m = load_manifest()
    extras = load_extras()
    used = {o.mesh.path for o in m.objects}
    assert not used & {o.mesh.path for o in extras.objects.values()}  # no benchmark or held-out mesh
    assert set(candidate_meshes(m)) == {o.mesh.path for o in extras.objects.values()}
    assert len(extras.validation) == 24 and not set(extras.validation) & set(extras.training)
    assert set(extras.validation) | set(extras.training) | set(extras.excluded) == set(extras.objects)
    # pybullet_data's one unrenderable mesh (every vertex nan) is in neither list, with its reason.
    assert extras.excluded == {"extra_168": "35 of 35 vertices are not finite numbers"}
    # The file is what `--write` makes from the installed package (checksums, colours, both lists, exclusions).
    raw = yaml.safe_load(EXTRA_FILE.read_text())
    fresh = build(len(extras.validation), extras.seed, m)
    assert fresh["validation"] == raw["validation"] and fresh["training"] == raw["training"]
    assert fresh["excluded"] == raw["excluded"]
    assert [{k: o[k] for k in ("name", "path", "sha256", "color")} for o in raw["objects"]] == fresh["objects"]
    # Every validation mesh carries the symmetry rule's declaration; the nested training sets.
    assert all("symmetries" in o for o in raw["objects"] if o["name"] in extras.validation)
    assert write(raw, tmp_path / "again.yaml").read_text() == EXTRA_FILE.read_text()  # header and layout too
    assert extras.first(3) == list(extras.training[:3]) and extras.first(100)[:3] == extras.first(3)
    with pytest.raises(ValueError, match="asked for 5000"):
        extras.first(5000)


def test_a_damaged_extras_file_is_refused_naming_it(tmp_path):
    m = load_manifest()
    raw = yaml.safe_load(EXTRA_FILE.read_text())
    where = tmp_path / "extras.yaml"
    overlap = {**raw, "training": raw["training"] + raw["validation"][:1]}
    with pytest.raises(ManifestError, match="extras.yaml: validation and training must be disjoint"):
        parse(overlap, where, m)
    cut = {**raw, "objects": [{k: v for k, v in o.items() if k != "symmetries"} for o in raw["objects"]]}
    with pytest.raises(ManifestError, match="no symmetry declaration .* it resumes"):
        parse(cut, where, m)
    assert len(parse(cut, where, m, require_symmetries=False).validation) == 24
    bad = {**raw, "objects": [{**raw["objects"][0], "sha256": "abc"}] + raw["objects"][1:]}
    with pytest.raises(ManifestError, match=r"objects\[0\]: expected a 64-character sha256"):
        parse(bad, where, m)
    with pytest.raises(ManifestError, match="does not exist"):
        load_extras(tmp_path / "missing.yaml")
    listed = {**raw, "excluded": [{"name": raw["training"][0], "reason": "test"}]}
    with pytest.raises(ManifestError, match="excluded meshes must be objects of the file and in neither list"):
        parse(listed, where, m)


def test_a_mesh_of_nan_vertices_is_refused_naming_the_file(tmp_path):
    """A file of nan vertices loads without complaint in trimesh and would render as nothing (an empty
    silhouette, far from its cause): it is refused on loading and kept out of the extras' lists."""
    good = tmp_path / "good.obj"
    good.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    bad = tmp_path / "bad.obj"
    bad.write_text(good.read_text().replace("v 1 0 0", "v nan nan nan"))
    flat = tmp_path / "flat.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    assert mesh_problem(good) is None and load_mesh_file(good).faces.shape == (4, 3)
    assert mesh_problem(bad) == "1 of 4 vertices are not finite numbers"
    assert mesh_problem(flat) == "zero surface area"
    with pytest.raises(ValueError, match=r"bad\.obj cannot be rendered: 1 of 4 vertices are not finite"):
        load_mesh_file(bad)


def test_extras_join_a_manifest_without_changing_its_splits():
    m = load_manifest()
    extras = load_extras(manifest=m)
    names = extras.first(2) + list(extras.validation[:1])
    mx = with_extras(m, extras, names)
    assert mx.seen_objects(1) == m.seen_objects(1) and mx.held_out_objects() == m.held_out_objects()
    assert [mx.object(n).role for n in names] == ["extra"] * 3
    v = mx.object(extras.validation[0])
    assert isinstance(v.symmetry_group(), np.ndarray)  # declared by the rule (the identity at least)
    with pytest.raises(ValueError, match="not in"):
        with_extras(m, extras, ["extra_nope"])


def _tiny_recipes(tmp_path: Path) -> dict:
    spec = {**TINY, "models": {"tiny": {"split": 1},
                               "tiny-extra": {"split": 1, "extra": {"n": 2, "n_references": 8, "n_train_queries": 2}}}}
    path = tmp_path / "zoo.yaml"
    path.write_text(yaml.safe_dump(spec))
    return zoo.recipes(path, cache_dir=str(tmp_path / "cache"), device="cpu")


def test_a_recipe_with_extra_objects_trains_on_them_and_is_published_by_name_only(tmp_path):
    rs = _tiny_recipes(tmp_path)
    r, rx = rs["tiny"], rs["tiny-extra"]
    assert rx.extra == ExtraConfig(2, 8, 2) and rx.by_name_only and not r.by_name_only
    zdir = tmp_path / "models"
    _, run, _, data = zoo.train_recipe(r, zoo_dir=zdir)
    _, run_x, info, data_x = zoo.train_recipe(rx, zoo_dir=zdir)
    extras = load_extras()
    assert data_x.extra == extras.first(2)
    assert data_x.training_objects(1) == data.manifest.seen_objects(1) + data_x.extra
    assert run_x != run and info["extra"] == 2 and info["seen"] == data.manifest.seen_objects(1)
    assert len(data_x.refs[data_x.extra[0]]) == 8 and len(data_x.train_q[data_x.extra[0]]) == 2
    zoo.publish(r, run, data, zoo_dir=zdir)
    zoo.publish(rx, run_x, data_x, zoo_dir=zdir)
    e = zoo.entry("tiny-extra", zdir)
    assert e["extra"]["n"] == 2 and len(e["extra"]["objects_sha256"]) == 64 and e["by_name_only"]
    assert e["seen_objects"] == data.manifest.seen_objects(1)  # validated on the benchmark's seen objects only
    assert zoo.find(1, r.train, zdir) == "tiny"  # same network and training: the by-name-only model is skipped
    with pytest.raises(ValueError, match="symmetry_aware"):
        bad = tmp_path / "bad.yaml"
        bad.write_text(yaml.safe_dump({**TINY, "models": {"x": {"split": 1, "extra": {"n": 2},
                                                                 "train": {"symmetry_aware": True}}}}))
        zoo.recipes(bad)
    t = {CURRENT: [Trained(None, run, {"zoo_entry": zoo.entry("tiny", zdir)})],
         "extra-2": [Trained(None, run_x, {"zoo_entry": e})]}
    assert changes(t)["extra-2"] == "extra.n: 0 -> 2; extra.n_references: 256 -> 8; extra.n_train_queries: 32 -> 2"
    assert extra_counts(t) == {CURRENT: 0, "extra-2": 2}


def _entry(n: int) -> Trained:
    return Trained(None, Path("."), {"zoo_entry": {"extra": {"n": n}} if n else {}})


def test_extra_counts_refuse_what_is_not_a_curve():
    assert list(extra_counts({"b": [_entry(100)], CURRENT: [_entry(0)], "a": [_entry(10)]})) == [CURRENT, "a", "b"]
    with pytest.raises(ValueError, match="different numbers of extra objects"):
        extra_counts({CURRENT: [_entry(0)], "a": [_entry(10), _entry(20)]})
    with pytest.raises(ValueError, match="expected none"):
        extra_counts({CURRENT: [_entry(5)]})
    with pytest.raises(ValueError, match=r"N = \[10\]"):
        extra_counts({CURRENT: [_entry(0)], "a": [_entry(10)], "b": [_entry(10)]})


def _result(ok: list[int]) -> dict:
    pq = pd.DataFrame({"obj": ["x"] * len(ok), "query_id": [f"x:{i}" for i in range(len(ok))], "rot_ok": ok,
                       "class_ok": [1] * len(ok)})
    return {"per_query": pq, "means": {"rot_acc": 100.0 * np.mean(ok)}}


def test_the_curve_is_in_order_of_n_with_seed_means_and_intervals():
    counts = {CURRENT: 0, "extra-100": 100}
    val = {CURRENT: [_result([0, 1, 0, 1]), _result([0, 0, 0, 1])], "extra-100": [_result([1, 1, 1, 1])] * 2}
    c = extra_curve(counts, val)
    assert list(c["N extra objects"]) == [0, 100] and list(c["seeds"]) == [2, 2]
    assert c.loc[0, "validation rot_acc"] == pytest.approx(37.5) and c.loc[1, "validation rot_acc"] == 100.0
    assert (c["validation ci95 lo"] <= c["validation rot_acc"]).all() and c["unseen test rot_acc"].isna().all()
    u = extra_curve(counts, val, {k: v[:1] for k, v in val.items()})
    assert list(u["unseen test rot_acc"]) == [50.0, 100.0]
