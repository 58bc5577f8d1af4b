from pathlib import Path

import pytest
import yaml

from helpers.data.manifest import ManifestError, load_manifest, verify, verify_file
from helpers.data.meshes import load_object


def test_manifest_has_the_benchmark(manifest):
    assert len(manifest.objects) >= 20
    for s in (1, 2, 3):
        assert len(manifest.split_objects(s)) in (4, 5)
    assert sum(len(manifest.split_objects(s)) for s in (1, 2, 3)) == 13
    assert len(manifest.held_out_objects()) >= 7
    assert set(manifest.background_names("train")) and set(manifest.background_names("test"))
    assert not set(manifest.background_names("train")) & set(manifest.background_names("test"))
    for o in manifest.objects:
        assert o.source.version and o.licence and len(o.mesh.sha256) == 64


def test_verify_all_files(manifest):
    paths = verify(manifest)
    assert len(paths) == len(manifest.objects) + len(manifest.backgrounds)
    assert all(Path(p).is_file() for p in paths.values())


def _write(tmp_path, doc):
    p = tmp_path / "m.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_checksum_mismatch_names_the_file(tmp_path, manifest):
    doc = yaml.safe_load(manifest.path.read_text())
    doc["objects"][0]["mesh"]["sha256"] = "0" * 64
    m = load_manifest(_write(tmp_path, doc))
    with pytest.raises(ManifestError, match=r"checksum mismatch for .*duck\.obj"):
        verify_file(m.objects[0].mesh, "object 'duck'")
    with pytest.raises(ManifestError, match="checksum mismatch"):
        load_object("duck", m)


def test_missing_file_and_package(tmp_path, manifest):
    doc = yaml.safe_load(manifest.path.read_text())
    doc["objects"][0]["mesh"]["path"] = "no/such/mesh.obj"
    m = load_manifest(_write(tmp_path, doc))
    with pytest.raises(ManifestError, match=r"no/such/mesh\.obj.*missing"):
        verify(m)
    doc = yaml.safe_load(manifest.path.read_text())
    doc["sources"]["pybullet"]["module"] = "no_such_module_xyz"
    m = load_manifest(_write(tmp_path, doc))
    with pytest.raises(ManifestError, match="no_such_module_xyz.*not installed"):
        verify(m)


def test_malformed_manifest(tmp_path, manifest):
    bad = tmp_path / "bad.yaml"
    bad.write_text("objects: [unclosed")
    with pytest.raises(ManifestError, match="bad.yaml.*not valid YAML"):
        load_manifest(bad)
    doc = yaml.safe_load(manifest.path.read_text())
    del doc["objects"][1]["mesh"]
    with pytest.raises(ManifestError, match="object 'bunny'.*missing key 'mesh'"):
        load_manifest(_write(tmp_path, doc))
    doc = yaml.safe_load(manifest.path.read_text())
    doc["objects"][1]["role"] = "test"
    with pytest.raises(ManifestError, match="role should be one of"):
        load_manifest(_write(tmp_path, doc))
    with pytest.raises(ManifestError, match="does not exist"):
        load_manifest(tmp_path / "nothing.yaml")


def test_meshes_are_normalised(manifest):
    for name in ("duck", "cereal", "airplane"):
        o = load_object(name, manifest)
        assert o.diameter == pytest.approx(0.2)
        assert abs(o.mesh.bounds.mean(axis=0)).max() < 1e-6
    assert load_object("duck", manifest).textured
    assert not load_object("bunny", manifest).textured


def test_corrupt_mesh_file(tmp_path):
    from helpers.data.meshes import load_mesh_file

    p = tmp_path / "broken.obj"
    p.write_text("this is not a mesh\n")
    with pytest.raises(ValueError, match="broken.obj"):
        load_mesh_file(p)
    with pytest.raises(FileNotFoundError, match="absent.obj"):
        load_mesh_file(tmp_path / "absent.obj")
