"""The T-LESS-like parts (helpers.data.parts): reproducible files, true symmetries, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from scipy.spatial import cKDTree

from helpers.core.fileio import sha256_file
from helpers.data.bop import symmetry_rotations
from helpers.data.manifest import ManifestError, load_manifest
from helpers.data.meshes import mesh_diameter
from helpers.data.parts import PARTS, build_part, load_part, part_file, spec


def _surface_gap_mm(mesh: trimesh.Trimesh, R: np.ndarray) -> float:
    """99th percentile distance (mm) from the surface turned by R to the surface: ~0 for a symmetry."""
    dense = trimesh.sample.sample_surface_even(mesh, 40000, seed=1)[0]
    pts = trimesh.sample.sample_surface(mesh, 3000, seed=0)[0]
    return float(np.percentile(cKDTree(dense).query(pts @ R.T)[0], 99))


def test_the_family_is_t_less_like():
    assert len(PARTS) >= 15 and len({p.name for p in PARTS}) == len(PARTS)
    sym = [p for p in PARTS if p.symmetries_discrete or p.symmetries_continuous]
    assert len(sym) >= 10 and sum(bool(p.symmetries_continuous) for p in PARTS) >= 4
    m = load_manifest()
    assert [p.name for p in m.parts.items] == [p.name for p in PARTS]


def test_every_part_regenerates_to_its_manifest_sha256(tmp_path):
    m = load_manifest()
    for entry in m.parts.items:
        path = part_file(entry.name, m, cache=tmp_path)
        assert sha256_file(path) == entry.sha256, entry.name
        mesh = trimesh.load(path, process=False)
        assert mesh.is_watertight and 60 < np.linalg.norm(mesh.extents) < 130, entry.name  # millimetres


@pytest.mark.parametrize("name", [p.name for p in PARTS])
def test_listed_symmetries_hold_and_a_quarter_turn_about_x_is_not_one(name):
    mesh = build_part(name, 0)
    for R in symmetry_rotations(spec(name).symmetry_entry(), Path(name), name, step_deg=45):
        assert _surface_gap_mm(mesh, R) < 1.5, (name, R.round(3))
    quarter = trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])[:3, :3]
    assert _surface_gap_mm(mesh, quarter) > 4.0, name


def test_load_part_has_its_real_size_and_symmetries(tmp_path):
    obj = load_part("hex_nut", cache=tmp_path)
    assert 0.05 < obj.diameter < 0.08 and not obj.textured  # metres
    assert np.allclose(obj.symmetries[0], np.eye(3)) and len(obj.symmetries) == 12  # D6
    assert np.isclose(mesh_diameter(obj.mesh.vertices), obj.diameter, rtol=1e-6)  # the source's size, kept


def test_a_changed_manifest_checksum_is_named(tmp_path):
    raw = yaml.safe_load(load_manifest().path.read_text())
    raw["parts"]["items"][0]["sha256"] = "0" * 64
    bad = tmp_path / "manifest.yaml"
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(ManifestError, match=r"part 'box_two_holes': generated file .* has sha256 .* the manifest says 0{64}"):
        part_file("box_two_holes", load_manifest(bad), cache=tmp_path)
    with pytest.raises(KeyError, match="part 'teapot' is not in the manifest's parts"):
        part_file("teapot", load_manifest(bad), cache=tmp_path)
