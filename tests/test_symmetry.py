"""The symmetry rule (helpers.data.symmetry) on shapes made here, the manifest's declarations and the parts."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from PIL import Image

from helpers.core.rotations import Symmetries
from helpers.data.manifest import ManifestError, load_manifest
from helpers.data.meshes import ObjectMesh, normalise, set_color
from helpers.data.parts import load_part, spec
from helpers.data.symmetry.__main__ import main as symmetry_main
from helpers.data.symmetry.manifest_io import MARKER, write_section
from helpers.data.symmetry.rule import SymmetryRule, closure, describe, find_symmetries, manifest_block
from helpers.data.symmetry.surface import axis_angle, sample_surface, small_turn_distance, surface_distance
from helpers.data.symmetry.verdicts import check_stated

#: Lighter than the manifest's rule (fewer points, grid rotations and views): the same stages, seconds per shape.
FAST = SymmetryRule(n_points=1500, n_grid=800, n_views=24, max_candidates=6)


def _obj(mesh: trimesh.Trimesh, name: str, textured: bool = False) -> ObjectMesh:
    mesh = normalise(mesh)
    if not textured:
        mesh = set_color(mesh, (0.7, 0.7, 0.7))
    return ObjectMesh(name, mesh, 0.2, textured, name, np.eye(3)[None])


def _box() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(1.0, 0.7, 0.45))


def _box_with_printed_top() -> trimesh.Trimesh:
    """The same box, its +z face printed with an 'F' (no symmetry of its own), the rest plain grey."""
    box = _box()
    v, f, uv = [], [], []
    for fi, (normal, tris) in enumerate(_faces_by_normal(box)):
        corners = np.unique(box.vertices[np.unique(box.faces[tris])], axis=0)
        base = len(v)
        v.extend(corners)
        top = normal[2] > 0.9
        for c in corners:  # the top's corners span the printed half of the texture, other faces sit in the grey half
            uv.append([0.25 + 0.24 * np.sign(c[0]), 0.5 + 0.49 * np.sign(c[1])] if top else [0.75, 0.5])
        for t in box.faces[tris]:
            f.append([base + int(np.where((corners == box.vertices[k]).all(1))[0][0]) for k in t])
    img = np.full((128, 128, 3), 150, np.uint8)
    img[:, :64] = 230
    img[10:118, 12:26] = 20   # the F's stem
    img[10:24, 12:54] = 20    # its top bar
    img[56:70, 12:44] = 20    # its middle bar
    mesh = trimesh.Trimesh(np.array(v), np.array(f), process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.array(uv), image=Image.fromarray(img))
    return mesh


def _faces_by_normal(box: trimesh.Trimesh):
    normals = np.round(box.face_normals).astype(int)
    for n in np.unique(normals, axis=0):
        yield n, np.where((normals == n).all(1))[0]


def test_plain_box_has_three_two_fold_axes():
    res = find_symmetries(_obj(_box(), "box"), FAST)
    assert len(res.axes) == 0
    assert len(res.discrete) == 3
    axes = sorted(tuple(np.abs(np.round(describe(R)[0], 2))) for R in res.discrete)
    assert axes == [(0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0)]
    assert all(abs(describe(R)[1] - 180.0) < 1e-6 for R in res.discrete)  # snapped exactly


def test_printed_face_removes_symmetries():
    res = find_symmetries(_obj(_box_with_printed_top(), "printed", textured=True), FAST)
    assert len(res.evidence["candidates"]) == 3  # the surface alone still offers the three flips ...
    assert len(res.discrete) < 3  # ... the print tells some of them apart
    assert any(not c["declared"] for c in res.evidence["candidates"])


def test_asymmetric_shape_has_none():
    rng = np.random.default_rng(3)
    hull = trimesh.convex.convex_hull(rng.normal(size=(40, 3)) * [1.0, 0.6, 0.35])
    res = find_symmetries(_obj(hull, "blob"), FAST)
    assert len(res.discrete) == 0 and len(res.axes) == 0


def test_cylinder_is_continuous():
    # The rule's own 48 views: at 24 the share moves in steps of 1/24, and on one renderer (Mesa on an AVX2-only
    # CPU) 3 of 24 views fell short at 135-180 deg (share 0.875 < 0.9) while 44 of 48 pass (0.917). And the rule's
    # own 3,000 surface points: with FAST's 1,500 the axis came out 1.5 deg off the cylinder's (second moments of
    # fewer samples), and on an AVX512-BF16 VM 43 of 48 views passed at 180 deg (0.896); with 3,000, 0.7 deg and 46.
    import dataclasses

    rule = dataclasses.replace(FAST, n_views=48, n_points=SymmetryRule().n_points)
    res = find_symmetries(_obj(trimesh.creation.cylinder(radius=0.3, height=1.0, sections=64), "cyl"), rule)
    assert len(res.axes) == 1
    assert abs(abs(res.axes[0][2]) - 1.0) < 0.02  # about the cylinder's own axis
    assert isinstance(res.group(), Symmetries)
    # the end-over-end flip is kept as the discrete part of the group
    assert any(abs(describe(R)[1] - 180.0) < 1.0 and abs(describe(R)[0][2]) < 0.05 for R in res.discrete)


def test_surface_distance_is_zero_for_a_symmetry_and_grows_with_a_turn():
    s = sample_surface(_box(), 2000, 0)
    bar = small_turn_distance(s, 10.0)
    flip = surface_distance(s, axis_angle(np.array([[0.0, 0.0, 1.0]]), 180.0))[0]
    quarter = surface_distance(s, axis_angle(np.array([[0.0, 0.0, 1.0]]), 90.0))[0]
    noise = surface_distance(s, np.eye(3))[0]  # two independent samples of the same surface
    assert abs(flip - noise) < 0.1 * noise  # a symmetry costs nothing beyond the sampling noise
    assert flip < bar < quarter


def test_closure_builds_the_group():
    flips = axis_angle(np.eye(3)[:2], 180.0)  # two flips generate the third
    g = closure(flips)
    assert len(g) == 3
    assert len(closure(axis_angle(np.array([[0.0, 0.0, 1.0]]), 90.0))) == 3  # C4 without the identity


@pytest.mark.parametrize("name", ["hex_nut", "ring", "l_bracket"])
def test_parts_stated_symmetries_pass_the_rule(name):
    part = load_part(name)
    ok, missed, extra = check_stated(find_symmetries(part, FAST), spec(name).symmetry_entry(), part)
    assert ok, missed
    if name == "hex_nut":  # exactly D6 in geometry and in the renders: nothing beyond it
        assert not extra


def test_manifest_declarations_are_read(tmp_path):
    m = load_manifest()
    group = {o.name: o.symmetry_group() for o in m.objects}
    for name, g in group.items():
        d = g.discrete if isinstance(g, Symmetries) else g
        assert np.allclose(d[0], np.eye(3)), name
        assert np.allclose(np.einsum("kij,klj->kil", d, d), np.eye(3), atol=1e-4), name
    # the section round-trips: written for one object, read back as its group
    path = tmp_path / "manifest.yaml"
    path.write_text(m.path.read_text().partition(MARKER)[0])
    res = find_symmetries(_obj(_box(), "box"), FAST)
    write_section(path, {"bunny": manifest_block(res)}, FAST)
    g = load_manifest(path).object("bunny").symmetry_group()
    assert len(g) == 4 and np.allclose(g[1:], res.discrete, atol=1e-5)


def test_manifest_section_errors_name_the_problem(tmp_path):
    base = load_manifest().path.read_text().partition(MARKER)[0]
    path = tmp_path / "manifest.yaml"
    path.write_text(base + "\nsymmetries:\n  rule: {}\n  objects:\n    nosuch: {discrete: []}\n")
    with pytest.raises(ManifestError, match="nosuch"):
        load_manifest(path)
    path.write_text(base + "\nsymmetries:\n  rule: {}\n  objects:\n    duck: {discrete: [[1, 2, 3]]}\n")
    with pytest.raises(ManifestError, match="duck.discrete"):
        load_manifest(path)


def test_command_rejects_bad_input(capsys):
    with pytest.raises(SystemExit) as e:
        symmetry_main(["nosuch"])
    assert e.value.code == 2 and "nosuch" in capsys.readouterr().err
    assert symmetry_main(["--views", "3"]) == 2
    with pytest.raises(SystemExit) as e:
        symmetry_main(["--mesh", "/nonexistent/x.obj"])
    assert e.value.code == 2 and "x.obj" in capsys.readouterr().err
