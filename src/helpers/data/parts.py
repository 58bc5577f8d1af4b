"""T-LESS-like textureless industrial parts, generated procedurally (no file is downloaded).

T-LESS holds 30 electrical parts: grey, textureless, similar to each other, many with discrete or continuous
symmetries. This module builds a family of that kind from primitives and boolean operations (trimesh with the
manifold3d engine, both pinned in ``environment.lock``): boxes with holes and bosses, connectors with pins,
sockets, flanged cylinders, nuts, rings, brackets. Sizes are millimetres, as in T-LESS; each part's dimensions
are drawn from a generator seeded by ``seed + index`` so the family is reproducible. ``data_manifest.yaml``
(section ``parts``) lists the generator, its seed and the sha256 of every PLY file it writes; :func:`part_file`
regenerates a part into the cache and refuses one whose checksum differs.

Vertices are rounded to 1 micrometre before writing: floating-point results that differ in the last bit between
CPUs (SIMD paths of numpy's trigonometry) then give the same file.

Symmetries are given the BOP way (``models_info.json``): ``symmetries_discrete`` as 4x4 row-major transforms
and ``symmetries_continuous`` as {axis, offset}, in the part's model frame (bounding-box centre at the origin).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ..core.fileio import atomic_write_bytes, sha256_file
from ..core.paths import cache_dir
from .bop import symmetry_rotations
from .manifest import Manifest, ManifestError, load_manifest
from .meshes import ObjectMesh, load_mesh_file, mesh_diameter, normalise, set_color

GENERATOR = "helpers.data.parts"
VERSION = 1  # bump when a build function changes (the manifest's sha256 then change too)
SECTIONS = 64  # facets around a cylinder: smooth in 64-96 px renders


def _cyl(r: float, h: float, z: float = 0.0, x: float = 0.0, y: float = 0.0, sections: int = SECTIONS) -> trimesh.Trimesh:
    """Cylinder of radius r and height h along z, centred at (x, y, z)."""
    return trimesh.creation.cylinder(radius=r, height=h, sections=sections,
                                     transform=trimesh.transformations.translation_matrix([x, y, z]))


def _box(dx: float, dy: float, dz: float, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> trimesh.Trimesh:
    return trimesh.creation.box((dx, dy, dz), transform=trimesh.transformations.translation_matrix([x, y, z]))


def _union(*parts: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.boolean.union(list(parts), engine="manifold")


def _minus(base: trimesh.Trimesh, *cuts: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.boolean.difference([base, *cuts], engine="manifold")


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A dimension in [lo, hi] mm, rounded to 0.5 mm like a drawing."""
    return round(float(rng.uniform(lo, hi)) * 2) / 2


# --------------------------------------------------------------------------- the family
# Each builder takes a seeded generator and returns a watertight mesh in millimetres; its symmetry is stated in
# PARTS below (z is the axis of turned parts and the "up" of boxes).

def box_two_holes(g):
    w, d, h, r = _u(g, 70, 90), _u(g, 34, 42), _u(g, 24, 32), _u(g, 5, 7)
    return _minus(_box(w, d, h), _cyl(r, h + 2, x=-w / 4), _cyl(r, h + 2, x=w / 4))


def box_boss(g):
    s, h = _u(g, 48, 56), _u(g, 20, 26)
    return _union(_box(s, s, h), _cyl(_u(g, 10, 13), _u(g, 10, 14) + 1, z=h / 2 + 5))


def box_slot(g):
    w, d, h = _u(g, 70, 84), _u(g, 36, 44), _u(g, 22, 28)
    return _minus(_box(w, d, h), _box(w * 0.55, _u(g, 8, 11), h + 2))


def socket_square(g):
    s, h, r = _u(g, 50, 58), _u(g, 24, 30), _u(g, 4, 5.5)
    off = s / 4
    holes = [_cyl(r, h, z=h / 2, x=sx * off, y=sy * off) for sx in (-1, 1) for sy in (-1, 1)]
    return _minus(_box(s, s, h), *holes)


def socket_round(g):
    R, h, r = _u(g, 28, 33), _u(g, 22, 28), _u(g, 4, 5.5)
    holes = [_cyl(r, h, z=h / 2, x=R / 2 * math.cos(a), y=R / 2 * math.sin(a)) for a in (0, 2 * math.pi / 3, 4 * math.pi / 3)]
    return _minus(_cyl(R, h), *holes)


def flanged_cylinder(g):
    r, h = _u(g, 14, 18), _u(g, 45, 60)
    return _union(_cyl(r, h), _cyl(r * 1.8, _u(g, 5, 7), z=-h / 2 + 3))


def flanged_bore(g):
    r, h = _u(g, 15, 19), _u(g, 40, 52)
    return _minus(_union(_cyl(r, h), _cyl(r * 1.9, _u(g, 5, 7), z=-h / 2 + 3)), _cyl(r * 0.5, h + 2))


def flange_four_holes(g):
    R, t = _u(g, 34, 40), _u(g, 7, 9)
    boss = _cyl(R * 0.45, _u(g, 14, 20), z=t / 2 + 6)
    holes = [_cyl(_u(g, 3.5, 4.5), t + 2, x=0.75 * R * math.cos(a), y=0.75 * R * math.sin(a))
             for a in np.arange(4) * math.pi / 2]
    return _minus(_union(_cyl(R, t), boss), *holes)


def hex_nut(g):
    R, h = _u(g, 22, 27), _u(g, 16, 22)
    return _minus(_cyl(R, h, sections=6), _cyl(R * 0.5, h + 2))


def ring(g):
    R, h = _u(g, 28, 34), _u(g, 10, 14)
    return _minus(_cyl(R, h), _cyl(R * _u(g, 0.55, 0.7), h + 2))


def stepped_shaft(g):
    r, h = _u(g, 10, 13), _u(g, 18, 24)
    return _union(_cyl(r * 1.9, h, z=-h), _cyl(r * 1.4, h), _cyl(r, h, z=h))


def dome_cap(g):
    r, h = _u(g, 22, 27), _u(g, 18, 24)
    dome = trimesh.creation.icosphere(subdivisions=4, radius=r)
    dome.apply_translation([0, 0, h / 2])
    return _minus(_union(_cyl(r, h), dome), _box(3 * r, 3 * r, 2 * r, z=-h / 2 - r))


def connector_row(g):
    w, d, h = _u(g, 62, 74), _u(g, 26, 32), _u(g, 18, 24)
    pins = [_cyl(_u(g, 3, 3.5), 16, z=h / 2 + 7, x=x) for x in (-w / 3, 0, w / 3)]
    return _union(_box(w, d, h), *pins)


def connector_offset(g):
    w, d, h = _u(g, 60, 70), _u(g, 30, 36), _u(g, 20, 26)
    pins = [_cyl(3.2, 14, z=h / 2 + 6, x=-w / 4, y=d / 5), _cyl(3.2, 14, z=h / 2 + 6, x=w / 8, y=-d / 5)]
    return _union(_box(w, d, h), *pins)


def l_bracket(g):
    a, t, d = _u(g, 60, 72), _u(g, 9, 12), _u(g, 30, 38)
    body = _union(_box(a, d, t, z=-a / 2 + t / 2), _box(t, d, a, x=-a / 2 + t / 2))
    return _minus(body, _cyl(_u(g, 4, 5), t + 2, z=-a / 2 + t / 2, x=a / 6))


def t_block(g):
    w, s, d = _u(g, 70, 80), _u(g, 18, 24), _u(g, 26, 32)
    return _union(_box(w, d, s, z=_u(g, 20, 26)), _box(s, d, _u(g, 40, 48)))


def switch_box(g):
    w, d, h = _u(g, 60, 70), _u(g, 38, 46), _u(g, 26, 32)
    body = _minus(_box(w, d, h), _box(w * 0.5, d * 0.45, 8, x=-w / 8, z=h / 2 - 3))
    return _union(body, _box(6, d * 0.3, 14, x=-w / 8, z=h / 2))


def plug(g):
    w, d, h = _u(g, 44, 52), _u(g, 30, 36), _u(g, 28, 34)
    prongs = [_box(2.5, 9, 16, x=x, z=h / 2 + 7) for x in (-9, 9)]
    return _union(_box(w, d, h), _cyl(d / 2 - 2, 14, x=0, z=-h / 2 - 6), *prongs)


def _turn(axis_z: bool = True) -> list[dict]:
    return [{"axis": [0, 0, 1], "offset": [0, 0, 0]}] if axis_z else []


def _rot(axis: str, deg: float) -> list[float]:
    """4x4 row-major transform of a rotation by ``deg`` about x, y or z (BOP's symmetries_discrete entry)."""
    R = trimesh.transformations.rotation_matrix(math.radians(deg), {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1]}[axis])
    return [round(float(v), 8) for v in R.reshape(-1)]


def _cn(n: int) -> list[list[float]]:
    """The n-fold rotations about z (identity excluded)."""
    return [_rot("z", 360 * k / n) for k in range(1, n)]


def _dn(n: int) -> list[list[float]]:
    """The dihedral group D_n (identity excluded): n-fold turns about z, and n half-turns about horizontal axes.
    BOP lists a discrete group in full, not by generators."""
    flips = []
    for k in range(n):
        Rz = np.array(_rot("z", 360 * k / n)).reshape(4, 4)
        flips.append([round(float(v), 8) for v in (Rz @ np.array(_rot("x", 180)).reshape(4, 4)).reshape(-1)])
    return _cn(n) + flips


D2 = _dn(2)


@dataclass(frozen=True)
class PartSpec:
    """One part: name, what it looks like, its builder and its symmetries (BOP style)."""

    name: str
    description: str
    build: Callable[[np.random.Generator], trimesh.Trimesh]
    symmetries_discrete: tuple = ()
    symmetries_continuous: tuple = ()

    def symmetry_entry(self) -> dict:
        """The part's ``models_info.json`` symmetry keys."""
        out: dict = {}
        if self.symmetries_discrete:
            out["symmetries_discrete"] = [list(s) for s in self.symmetries_discrete]
        if self.symmetries_continuous:
            out["symmetries_continuous"] = [dict(s) for s in self.symmetries_continuous]
        return out


PARTS: tuple[PartSpec, ...] = (
    PartSpec("box_two_holes", "box with two through-holes", box_two_holes, tuple(D2)),
    PartSpec("box_boss", "square box with a round boss", box_boss, tuple(_cn(4))),
    PartSpec("box_slot", "box with a through-slot", box_slot, tuple(D2)),
    PartSpec("socket_square", "square socket, four blind holes", socket_square, tuple(_cn(4))),
    PartSpec("socket_round", "round socket, three blind holes", socket_round, tuple(_cn(3))),
    PartSpec("flanged_cylinder", "cylinder with a flange", flanged_cylinder, (), tuple(_turn())),
    PartSpec("flanged_bore", "bored cylinder with a flange", flanged_bore, (), tuple(_turn())),
    PartSpec("flange_four_holes", "disc flange, boss and four bolt holes", flange_four_holes, tuple(_cn(4))),
    PartSpec("hex_nut", "hexagonal nut", hex_nut, tuple(_dn(6))),
    PartSpec("ring", "flat ring", ring, (_rot("x", 180),), tuple(_turn())),
    PartSpec("stepped_shaft", "three-step shaft", stepped_shaft, (), tuple(_turn())),
    PartSpec("dome_cap", "cylinder with a domed top", dome_cap, (), tuple(_turn())),
    PartSpec("connector_row", "connector, a row of three pins", connector_row, (_rot("z", 180),)),
    PartSpec("connector_offset", "connector, two offset pins", connector_offset),
    PartSpec("l_bracket", "L bracket with a hole", l_bracket),
    PartSpec("t_block", "T block", t_block, (_rot("z", 180),)),
    PartSpec("switch_box", "box with a recess and a lever", switch_box),
    PartSpec("plug", "plug: box, round collar, two prongs", plug, (_rot("z", 180),)),
)


def spec(name: str) -> PartSpec:
    for p in PARTS:
        if p.name == name:
            return p
    raise KeyError(f"no part {name!r}; the family: {[p.name for p in PARTS]}")


def build_part(name: str, seed: int) -> trimesh.Trimesh:
    """Part ``name`` of the family drawn with ``seed``: millimetres, bounding-box centre at the origin,
    vertices rounded to 1 um."""
    i = [p.name for p in PARTS].index(spec(name).name)
    mesh = spec(name).build(np.random.default_rng(seed + i))
    if not mesh.is_watertight or mesh.volume <= 0:
        raise RuntimeError(f"part {name!r} (seed {seed}): the generator made a mesh that is not a closed solid")
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return trimesh.Trimesh(np.round(mesh.vertices, 3), mesh.faces, process=False)


def part_bytes(name: str, seed: int) -> bytes:
    """Binary PLY of :func:`build_part` (what the manifest's sha256 is of)."""
    return build_part(name, seed).export(file_type="ply", encoding="binary")


def write_part(name: str, seed: int, path: str | Path) -> Path:
    """Write :func:`build_part` as binary PLY to ``path`` (through a temporary file: never half-written)."""
    path = Path(path)
    atomic_write_bytes(path, part_bytes(name, seed))
    return path


# --------------------------------------------------------------------------- the manifest's parts

def manifest_section(seed: int = 0) -> dict:
    """The ``parts`` section of ``data_manifest.yaml`` for ``seed``: generator, version, packages, sha256s."""
    import hashlib
    from importlib.metadata import version

    items = [{"name": p.name, "description": p.description,
              "sha256": hashlib.sha256(part_bytes(p.name, seed)).hexdigest()} for p in PARTS]
    return {"generator": GENERATOR, "version": VERSION, "seed": seed,
            "packages": {k: version(k) for k in ("trimesh", "manifold3d", "numpy")}, "items": items}


def part_file(name: str, manifest: Manifest | None = None, cache: str | Path | None = None) -> Path:
    """The PLY file of manifest part ``name``: generated into ``<cache>/parts/`` on first use, then checked
    against the manifest's sha256. ManifestError naming the part, both checksums and the pinned packages
    when the generator's output differs (another trimesh/manifold3d/numpy, or a changed builder)."""
    m = manifest or load_manifest()
    sec = m.parts
    if sec is None:
        raise ManifestError(f"{m.path}: no 'parts' section (regenerate it: python -m helpers.data.parts manifest)")
    if sec.generator != GENERATOR or sec.version != VERSION:
        raise ManifestError(f"{m.path}: parts were made by {sec.generator} v{sec.version}, this is {GENERATOR} "
                            f"v{VERSION}; regenerate the section with python -m helpers.data.parts manifest")
    entry = sec.part(name)
    path = cache_dir(cache) / "parts" / f"v{VERSION}-seed{sec.seed}" / f"{name}.ply"
    if not path.is_file() or sha256_file(path) != entry.sha256:
        write_part(name, sec.seed, path)  # atomic: concurrent writers write the same bytes
        got = sha256_file(path)
        if got != entry.sha256:
            raise ManifestError(f"part {name!r}: generated file {path} has sha256 {got}, the manifest says "
                                f"{entry.sha256}; the manifest was made with {sec.packages} (environment.lock pins "
                                "them): reinstall with scripts/setup.sh")
    return path


def load_part(name: str, manifest: Manifest | None = None, cache: str | Path | None = None,
              color: tuple[float, float, float] = (0.62, 0.62, 0.6)) -> ObjectMesh:
    """Manifest part ``name`` as an :class:`helpers.data.meshes.ObjectMesh`: grey (textureless), its real size
    (diameter in metres from the millimetre mesh), symmetries from its spec (identity first, continuous ones
    every 10 degrees)."""
    path = part_file(name, manifest, cache)
    mesh = load_mesh_file(path)
    diameter = mesh_diameter(mesh.vertices) / 1000.0
    mesh = normalise(set_color(mesh, color), diameter)
    sym = symmetry_rotations(spec(name).symmetry_entry(), path, name)

    return ObjectMesh(name, mesh, diameter, False, sha256_file(path), sym)


def main(argv: list[str] | None = None) -> int:
    """``python -m helpers.data.parts manifest [--seed N]``: print the manifest's ``parts`` section (YAML)."""
    import argparse

    import yaml

    ap = argparse.ArgumentParser(prog="python -m helpers.data.parts")
    ap.add_argument("command", choices=["manifest"])
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    print(yaml.safe_dump({"parts": manifest_section(a.seed)}, sort_keys=False), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
