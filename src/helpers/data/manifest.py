"""The data manifest: every mesh, texture and background photo the study uses.

``data_manifest.yaml`` names each file by the PyPI package that ships it, the
package version, the path inside the package, its sha256, its licence and its
role. This module reads it, finds the files in the installed packages
(without importing them: some have heavy import-time side effects) and checks
the checksums. Nothing is ever downloaded.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np
import yaml

from ..core.fileio import sha256_file
from ..core.rotations import Symmetries
from ..core.paths import default_manifest

ROLES_OBJECT = ("train", "held-out")
ROLES_BACKGROUND = ("background",)


class ManifestError(ValueError):
    """The manifest or a file it names is missing, malformed or altered."""


@dataclass(frozen=True)
class FileEntry:
    """One file inside an installed package, or (``root`` set) inside a data set folder the user gives."""

    module: str  # importable top-level module that holds the file, e.g. "pybullet_data" ("" with root)
    path: str  # path relative to the module directory (or to root)
    sha256: str
    root: str = ""  # a data set folder (e.g. a BOP copy of LineMOD) instead of a package

    def resolve(self) -> Path:
        return Path(self.root) / self.path if self.root else module_dir(self.module) / self.path


@dataclass(frozen=True)
class Source:
    """A PyPI distribution the files come from."""

    name: str
    package: str  # PyPI name
    version: str
    licence: str
    module: str


@dataclass(frozen=True)
class ObjectEntry:
    """A mesh with its role in the benchmark.

    ``split`` is 1, 2 or 3 for the LineMOD-like benchmark objects (role
    ``train``: seen in training for the other two splits, unseen for their own)
    and ``None`` for ``held-out`` objects, which are never trained on.
    """

    name: str
    role: str
    split: int | None
    source: Source
    mesh: FileEntry
    extra_files: tuple[FileEntry, ...]
    color: tuple[float, float, float] | None
    licence: str
    description: str
    symmetries: tuple = field(default=())
    symmetry_axes: tuple = field(default=())

    def files(self) -> tuple[FileEntry, ...]:
        return (self.mesh,) + self.extra_files

    def symmetry_group(self) -> np.ndarray | Symmetries:
        """The declared symmetry group (model frame): (K, 3, 3) rotations with the identity first, or a
        :class:`helpers.core.rotations.Symmetries` when a continuous axis is declared."""
        disc = np.concatenate([np.eye(3)[None], np.asarray(self.symmetries, dtype=np.float64).reshape(-1, 3, 3)])
        return Symmetries(disc, np.asarray(self.symmetry_axes, np.float64)) if self.symmetry_axes else disc


@dataclass(frozen=True)
class BackgroundEntry:
    """A photo used behind real-like queries; ``split`` is ``train`` or ``test``."""

    name: str
    split: str
    source: Source
    file: FileEntry
    licence: str


@dataclass(frozen=True)
class PartEntry:
    """A generated T-LESS-like part (:mod:`helpers.data.parts`): its name, look and the sha256 of its PLY file."""

    name: str
    description: str
    sha256: str


@dataclass(frozen=True)
class PartsSection:
    """The manifest's ``parts``: generator module, its version, the seed and the pinned packages it needs."""

    generator: str
    version: int
    seed: int
    packages: dict
    items: tuple[PartEntry, ...]

    def part(self, name: str) -> PartEntry:
        for p in self.items:
            if p.name == name:
                return p
        raise KeyError(f"part {name!r} is not in the manifest's parts; known: {[p.name for p in self.items]}")


@dataclass(frozen=True)
class Manifest:
    path: Path
    sources: dict[str, Source]
    objects: tuple[ObjectEntry, ...]
    backgrounds: tuple[BackgroundEntry, ...]
    parts: PartsSection | None = None

    def object(self, name: str) -> ObjectEntry:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(f"object {name!r} is not in {self.path}; known: {[o.name for o in self.objects]}")

    def object_names(self, role: str | None = None) -> list[str]:
        return [o.name for o in self.objects if role is None or o.role == role]

    def split_objects(self, split: int) -> list[str]:
        """Unseen (test) objects of LineMOD-like split ``split`` (1, 2 or 3)."""
        if split not in (1, 2, 3):
            raise ValueError(f"split must be 1, 2 or 3, got {split!r}")
        return [o.name for o in self.objects if o.role == "train" and o.split == split]

    def seen_objects(self, split: int) -> list[str]:
        """Benchmark objects trained on for ``split`` (those of the other splits); split 0: all of
        them (the all-objects model, tested on the held-out objects)."""
        unseen = set() if split == 0 else set(self.split_objects(split))
        return [o.name for o in self.objects if o.role == "train" and o.name not in unseen]

    def held_out_objects(self) -> list[str]:
        return self.object_names("held-out")

    def background_names(self, split: str | None = None) -> list[str]:
        return [b.name for b in self.backgrounds if split is None or b.split == split]


def module_dir(module: str) -> Path:
    """Directory of an installed top-level module, found without importing it."""
    spec = importlib.util.find_spec(module)
    if spec is None or not spec.submodule_search_locations:
        raise ManifestError(
            f"package module {module!r} is not installed; run the setup script "
            f"(scripts/setup.sh) which installs it from environment.lock")
    return Path(list(spec.submodule_search_locations)[0])


def _req(d: dict, key: str, where: str, typ: type | tuple = str):
    if not isinstance(d, dict) or key not in d:
        raise ManifestError(f"{where}: missing key {key!r}")
    v = d[key]
    if not isinstance(v, typ):
        raise ManifestError(f"{where}: key {key!r} should be {typ}, got {type(v).__name__}")
    return v


def _file(d: dict, module: str, where: str) -> FileEntry:
    sha = _req(d, "sha256", where)
    if len(sha) != 64:
        raise ManifestError(f"{where}: sha256 should be 64 hex characters")
    return FileEntry(module, _req(d, "path", where), sha)


def load_manifest(path: str | os.PathLike | None = None) -> Manifest:
    """Parse the manifest (default: the repository's ``data_manifest.yaml``).

    Raises ManifestError naming the file and the entry on any schema problem.
    Checksums are not verified here; see :func:`verify`.
    """
    path = Path(path) if path else default_manifest()
    return _load_manifest_cached(str(path.resolve()), path.stat().st_mtime_ns if path.exists() else 0)


@lru_cache(maxsize=4)
def _load_manifest_cached(path_s: str, _mtime: int) -> Manifest:
    path = Path(path_s)
    if not path.exists():
        raise ManifestError(f"data manifest {path} does not exist")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ManifestError(f"{path}: not valid YAML: {e}") from None
    where = str(path)
    srcs_raw = _req(raw, "sources", where, dict)
    sources = {}
    for name, s in srcs_raw.items():
        w = f"{where}: sources.{name}"
        sources[name] = Source(name, _req(s, "package", w), str(_req(s, "version", w, (str, int, float))),
                               _req(s, "licence", w), _req(s, "module", w))
    objects = []
    for i, o in enumerate(_req(raw, "objects", where, list)):
        w = f"{where}: objects[{i}]"
        name = _req(o, "name", w)
        w = f"{where}: object {name!r}"
        role = _req(o, "role", w)
        if role not in ROLES_OBJECT:
            raise ManifestError(f"{w}: role should be one of {ROLES_OBJECT}, got {role!r}")
        split = o.get("split")
        if role == "train" and split not in (1, 2, 3):
            raise ManifestError(f"{w}: role 'train' needs split 1, 2 or 3, got {split!r}")
        src_name = _req(o, "source", w)
        if src_name not in sources:
            raise ManifestError(f"{w}: unknown source {src_name!r}; known: {sorted(sources)}")
        src = sources[src_name]
        mesh = _file(_req(o, "mesh", w, dict), src.module, f"{w}.mesh")
        extras = tuple(_file(e, src.module, f"{w}.extra_files[{j}]") for j, e in enumerate(o.get("extra_files", []) or []))
        color = o.get("color")
        if color is not None and (len(color) != 3 or not all(0 <= float(c) <= 1 for c in color)):
            raise ManifestError(f"{w}: color should be three floats in [0, 1]")
        objects.append(ObjectEntry(name, role, split, src, mesh, extras,
                                   None if color is None else tuple(float(c) for c in color),
                                   o.get("licence", src.licence), o.get("description", "")))
    names = [o.name for o in objects]
    if len(set(names)) != len(names):
        raise ManifestError(f"{where}: duplicate object names")
    objects = _with_symmetries(objects, raw.get("symmetries"), where)
    backgrounds = []
    for i, b in enumerate(raw.get("backgrounds", []) or []):
        w = f"{where}: backgrounds[{i}]"
        src_name = _req(b, "source", w)
        if src_name not in sources:
            raise ManifestError(f"{w}: unknown source {src_name!r}")
        split = _req(b, "split", w)
        if split not in ("train", "test"):
            raise ManifestError(f"{w}: split should be 'train' or 'test', got {split!r}")
        src = sources[src_name]
        backgrounds.append(BackgroundEntry(_req(b, "name", w), split, src, _file(_req(b, "file", w, dict), src.module, w),
                                           b.get("licence", src.licence)))
    return Manifest(path, sources, tuple(objects), tuple(backgrounds), _parts(raw.get("parts"), where))


def _with_symmetries(objects: list[ObjectEntry], raw: dict | None, where: str) -> list[ObjectEntry]:
    """Attach the ``symmetries`` section (written by ``python -m helpers.data.symmetry --write``) to the objects."""
    if raw is None:
        return objects
    w = f"{where}: symmetries"
    decl = _req(raw, "objects", w, dict)
    names = {o.name for o in objects}
    unknown = sorted(set(decl) - names)
    if unknown:
        raise ManifestError(f"{w}: objects {unknown} are not in the manifest's objects")
    out = []
    for o in objects:
        d = decl.get(o.name) or {}
        disc = d.get("discrete", []) or []
        axes = [c.get("axis") if isinstance(c, dict) else None for c in d.get("continuous", []) or []]
        for i, r in enumerate(disc):
            m = np.asarray(r, dtype=np.float64).reshape(-1)
            if m.size != 9 or not np.allclose(m.reshape(3, 3) @ m.reshape(3, 3).T, np.eye(3), atol=1e-4):
                raise ManifestError(f"{w}.objects.{o.name}.discrete[{i}]: expected a 3x3 rotation (9 numbers, "
                                    f"row-major), got {r!r}")
        for i, a in enumerate(axes):
            if a is None or len(a) != 3 or not np.linalg.norm(np.asarray(a, dtype=np.float64)) > 0:
                raise ManifestError(f"{w}.objects.{o.name}.continuous[{i}]: expected {{axis: [x, y, z]}} with a "
                                    f"non-zero axis, got {d['continuous'][i]!r}")
        out.append(replace(o, symmetries=tuple(tuple(float(x) for x in r) for r in disc),
                           symmetry_axes=tuple(tuple(float(x) for x in a) for a in axes)))
    return out


def _parts(raw: dict | None, where: str) -> PartsSection | None:
    if raw is None:
        return None
    w = f"{where}: parts"
    items = []
    for i, p in enumerate(_req(raw, "items", w, list)):
        sha = _req(p, "sha256", f"{w}.items[{i}]")
        if len(sha) != 64:
            raise ManifestError(f"{w}.items[{i}]: sha256 should be 64 hex characters")
        items.append(PartEntry(_req(p, "name", f"{w}.items[{i}]"), p.get("description", ""), sha))
    return PartsSection(_req(raw, "generator", w), _req(raw, "version", w, int), _req(raw, "seed", w, int),
                        dict(_req(raw, "packages", w, dict)), tuple(items))


def verify_file(entry: FileEntry, what: str) -> Path:
    """Resolve a manifest file and check its sha256; returns its path.

    Raises ManifestError naming the file when it is absent or altered.
    """
    p = entry.resolve()
    if not p.is_file():
        raise ManifestError(f"{what}: file {p} (module {entry.module!r}, path {entry.path!r}) is missing; "
                            f"reinstall the package with scripts/setup.sh")
    got = sha256_file(p)
    if got != entry.sha256:
        raise ManifestError(f"{what}: checksum mismatch for {p}: expected sha256 {entry.sha256}, got {got}. "
                            f"The installed package differs from the one recorded in the manifest.")
    return p


def verify(manifest: Manifest | None = None) -> dict[str, Path]:
    """Verify every file of the manifest; returns {"object:name" / "background:name": path}."""
    m = manifest or load_manifest()
    out = {}
    for o in m.objects:
        for f in o.files():
            p = verify_file(f, f"object {o.name!r}")
            if f is o.mesh:
                out[f"object:{o.name}"] = p
    for b in m.backgrounds:
        out[f"background:{b.name}"] = verify_file(b.file, f"background {b.name!r}")
    return out


def object_table(manifest: "Manifest | None" = None):
    """One row per manifest object: role, split, source package/version, file, sha256 prefix."""
    import pandas as pd

    m = manifest or load_manifest()
    rows = [{"object": o.name, "role": o.role, "split": o.split if o.split else "-", "source": o.source.package,
             "version": o.source.version, "file": o.mesh.path, "sha256": o.mesh.sha256[:12],
             "textured": o.color is None, "licence": o.licence, "description": o.description} for o in m.objects]
    return pd.DataFrame(rows)
