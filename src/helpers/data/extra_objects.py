"""Extra training objects (issue #44, screen e): package meshes that are not benchmark, held-out or clutter objects.

The pool is pybullet_data's ``random_urdfs`` (1,000 procedurally made shapes, zlib licence), less every mesh the data
manifest already uses (two of them are held-out objects). ``data_extra_objects.yaml`` (written by
``python -m helpers.data.extra_objects --write``) names each extra mesh by its path and sha256, gives it a flat
colour, and fixes two disjoint lists, both drawn with the file's seed:

- ``validation``: extra meshes kept out of every training run, the unseen-object validation set that decides
  whether extra objects pay (never the benchmark's test or held-out objects). Their symmetries are declared by
  the project's symmetry rule (:mod:`helpers.data.symmetry`) and scored with.
- ``training``: the training order; a recipe with N extra objects trains on the first N, so the sets are nested
  (N = 100 is inside N = 1,000) and a curve over N changes one thing.
- ``excluded``: meshes in neither list because they cannot be rendered, each with the reason
  (:func:`mesh_problem`).

Training extras have no declared symmetries (the rule costs about 30 s per mesh on a 2-core CPU and the current
recipe is symmetry-blind); a recipe that is symmetry-aware and uses extra objects is refused
(:func:`helpers.study.zoo.recipes`).
"""

from __future__ import annotations

import argparse
import colorsys
import sys
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh
import yaml
from tqdm.auto import tqdm

from ..core.fileio import atomic_write_text, sha256_file
from ..core.paths import REPO_ROOT
from .manifest import FileEntry, Manifest, ManifestError, ObjectEntry, load_manifest, module_dir
from .meshes import load_object, mesh_defect
from .symmetry.rule import find_symmetries, manifest_block

#: The committed list of extra meshes.
EXTRA_FILE = REPO_ROOT / "data_extra_objects.yaml"
#: The manifest source (package) the extra meshes come from, and the folder inside it.
SOURCE, FOLDER = "pybullet", "random_urdfs"
#: Role of an extra object in a manifest built by :func:`with_extras` (never in data_manifest.yaml itself).
ROLE = "extra"


@dataclass(frozen=True)
class ExtraObjects:
    """The extra meshes of ``data_extra_objects.yaml``.

    Attributes:
        path: the file read.
        seed: seed of the colours and of both lists.
        objects: every extra mesh as a manifest entry (role ``extra``), by name.
        validation: names kept out of training (the unseen-object validation set), in file order.
        training: names in training order (a recipe with N extras takes the first N).
        excluded: names in neither list (meshes that cannot be rendered) -> the reason.
    """

    path: Path
    seed: int
    objects: dict[str, ObjectEntry]
    validation: tuple[str, ...]
    training: tuple[str, ...]
    excluded: dict[str, str] = field(default_factory=dict)

    def first(self, n: int) -> list[str]:
        """The first ``n`` training extras (ValueError naming the file when it holds fewer)."""
        if not 0 <= n <= len(self.training):
            raise ValueError(f"extra objects: asked for {n}, {self.path} lists {len(self.training)} training meshes")
        return list(self.training[:n])


def _entry(d: dict, manifest: Manifest, where: str) -> ObjectEntry:
    try:
        name, path, sha, color = d["name"], d["path"], d["sha256"], d["color"]
    except (KeyError, TypeError):
        raise ManifestError(f"{where}: expected name, path, sha256 and color, got {d!r}") from None
    if len(str(sha)) != 64 or len(color) != 3 or not all(0 <= float(c) <= 1 for c in color):
        raise ManifestError(f"{where}: expected a 64-character sha256 and three colour values in [0, 1], got {d!r}")
    src = manifest.sources[SOURCE]
    sym = d.get("symmetries") or {}
    return ObjectEntry(name, ROLE, None, src, FileEntry(src.module, path, sha), (), tuple(float(c) for c in color),
                       src.licence, f"procedural random object ({path})",
                       tuple(tuple(float(x) for x in r) for r in sym.get("discrete", []) or []),
                       tuple(tuple(float(x) for x in c["axis"]) for c in sym.get("continuous", []) or []))


def load_extras(path: str | Path | None = None, manifest: Manifest | None = None) -> ExtraObjects:
    """Parse ``data_extra_objects.yaml`` (ManifestError naming the file and entry on a schema problem).
    Checksums are checked when a mesh is rendered, as for the manifest's objects."""
    path = Path(path) if path else EXTRA_FILE
    if not path.exists():
        raise ManifestError(f"extra objects: {path} does not exist (write it with "
                            "`python -m helpers.data.extra_objects --write`)")
    try:  # a thousand entries: the C loader where PyYAML has it (about 10x faster), the same safe schema
        raw = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except yaml.YAMLError as e:
        raise ManifestError(f"{path}: not valid YAML: {e}") from None
    return parse(raw, path, manifest or load_manifest())


def parse(raw: dict, path: Path, m: Manifest, require_symmetries: bool = True) -> ExtraObjects:
    """:class:`ExtraObjects` from the file's content ``raw`` (``path`` names it in errors); with
    ``require_symmetries``, every validation mesh must carry the rule's declaration (a ``--write`` cut short
    leaves some without)."""
    try:
        seed, items = int(raw["seed"]), raw["objects"]
        val, order = [str(n) for n in raw["validation"]], [str(n) for n in raw["training"]]
    except (KeyError, TypeError, ValueError) as e:
        raise ManifestError(f"{path}: expected seed, objects, validation and training ({type(e).__name__}: {e})") \
            from None
    objects = {}
    for i, d in enumerate(items):
        e = _entry(d, m, f"{path}: objects[{i}]")
        objects[e.name] = e
    excluded = {str(d["name"]): str(d.get("reason", "")) for d in raw.get("excluded") or []
                if isinstance(d, dict) and "name" in d}
    if set(excluded) & set(val + order) or set(excluded) - set(objects):
        raise ManifestError(f"{path}: excluded meshes must be objects of the file and in neither list "
                            f"(in a list: {sorted(set(excluded) & set(val + order))[:5]})")
    unknown = sorted(set(val + order) - set(objects))
    if unknown or set(val) & set(order) or len(set(order)) != len(order):
        raise ManifestError(f"{path}: validation and training must be disjoint lists of its objects "
                            f"(unknown: {unknown[:5]}, in both: {sorted(set(val) & set(order))[:5]})")
    undeclared = [d.get("name") for d in items if d.get("name") in set(val) and "symmetries" not in d]
    if require_symmetries and undeclared:
        raise ManifestError(f"{path}: validation meshes {undeclared[:5]} have no symmetry declaration (a --write "
                            "was cut short: run `python -m helpers.data.extra_objects --write` again, it resumes)")
    taken = set(m.object_names())
    if taken & set(objects):
        raise ManifestError(f"{path}: names {sorted(taken & set(objects))} are data manifest objects")
    return ExtraObjects(path, seed, objects, tuple(val), tuple(order), excluded)


def with_extras(manifest: Manifest, extras: ExtraObjects, names: list[str]) -> Manifest:
    """``manifest`` with the extra objects ``names`` added (role ``extra``): what renders and scores them. The
    benchmark's splits are unchanged (``seen_objects``, ``split_objects`` and ``held_out_objects`` skip extras)."""
    missing = [n for n in names if n not in extras.objects]
    if missing:
        raise ValueError(f"extra objects {missing[:5]} are not in {extras.path}")
    have = set(manifest.object_names())
    return replace(manifest, objects=manifest.objects + tuple(extras.objects[n] for n in names if n not in have))


# ----------------------------------------------------------------------------- writing the file

def candidate_meshes(manifest: Manifest | None = None) -> list[str]:
    """Paths (inside pybullet_data) of the ``random_urdfs`` meshes no manifest object uses, sorted."""
    m = manifest or load_manifest()
    used = {o.mesh.path for o in m.objects if o.source.name == SOURCE}
    root = module_dir(m.sources[SOURCE].module)
    paths = sorted(str(p.relative_to(root)) for p in (root / FOLDER).glob("*/*.obj"))
    if not paths:
        raise ManifestError(f"extra objects: no meshes under {root / FOLDER} (is pybullet installed?)")
    return [p for p in paths if p not in used]


def _colour(rng: np.random.Generator) -> list[float]:
    """A flat colour: any hue, mid saturation and value (the benchmark's untextured objects span about the same)."""
    rgb = colorsys.hsv_to_rgb(rng.random(), rng.uniform(0.3, 0.8), rng.uniform(0.45, 0.9))
    return [round(float(c), 3) for c in rgb]


def mesh_problem(path: Path) -> str | None:
    """Why the mesh file at ``path`` cannot be rendered (:func:`helpers.data.meshes.mesh_defect`; None when it
    can), without the path, so the committed file reads the same on every machine. pybullet_data 3.2.7 ships one
    such file (``random_urdfs/168/168.obj``, every vertex ``nan``)."""
    with warnings.catch_warnings():  # trimesh warns on the very meshes this function is here to reject
        warnings.simplefilter("ignore")
        mesh = trimesh.load(path, force="mesh", process=False, skip_materials=True)
        return mesh_defect(mesh) if isinstance(mesh, trimesh.Trimesh) else "no triangles"


def build(n_validation: int = 24, seed: int = 0, manifest: Manifest | None = None) -> dict:
    """The file's content (without validation symmetries): every candidate mesh with its sha256 and colour, the
    validation names and the training order, drawn with ``seed``, and the meshes excluded from both lists with
    the reason (:func:`mesh_problem`). Colours and the draw cover every candidate, so excluding a mesh moves no
    other mesh's colour and keeps the others' relative order."""
    m = manifest or load_manifest()
    paths = candidate_meshes(m)
    if not 0 < n_validation < len(paths):
        raise ValueError(f"n_validation: expected 1..{len(paths) - 1}, got {n_validation}")
    rng = np.random.default_rng(seed)
    root = module_dir(m.sources[SOURCE].module)
    objects = [{"name": f"extra_{Path(p).stem}", "path": p, "sha256": sha256_file(root / p), "color": _colour(rng)}
               for p in paths]
    order = rng.permutation(len(objects))
    problems = {i: mesh_problem(root / p) for i, p in enumerate(paths)}
    usable = [int(i) for i in order if problems[int(i)] is None]
    val = sorted(usable[:n_validation])
    return {"seed": seed, "objects": objects, "validation": [objects[i]["name"] for i in val],
            "training": [objects[i]["name"] for i in usable[n_validation:]],
            "excluded": [{"name": objects[i]["name"], "reason": r} for i, r in problems.items() if r is not None]}


def write(content: dict, path: Path = EXTRA_FILE) -> Path:
    """Write the file with a header saying what it is and how it was made."""
    head = ("# Extra training objects (issue #44, screen e): pybullet_data random_urdfs meshes that no manifest\n"
            "# object uses. Written by `python -m helpers.data.extra_objects --write` (helpers.data.extra_objects); the\n"
            "# validation meshes are never trained on and carry the symmetry rule's declarations.\n")
    objects = content["objects"]
    body = {k: v for k, v in content.items() if k != "objects"}
    text = head + yaml.safe_dump(body, sort_keys=False, width=120) + "objects:\n" + "".join(
        "- " + yaml.safe_dump(o, default_flow_style=True, sort_keys=False, width=400) for o in objects)
    atomic_write_text(path, text)
    return path


def _declare_symmetries(content: dict, path: Path, old: dict) -> None:
    """Run the symmetry rule on each validation mesh that ``old`` (the file as it was) does not already declare for
    the same sha256, writing the file after each mesh: an interrupted ``--write`` resumes where it stopped."""
    m = load_manifest()
    done = {o["sha256"]: o["symmetries"] for o in old.get("objects", []) if "symmetries" in o}
    by_name = {o["name"]: o for o in content["objects"]}
    for name in tqdm(content["validation"], desc="symmetry rule (validation extras)", unit="mesh"):
        o = by_name[name]
        if o["sha256"] not in done:
            extras = parse(content, path, m, require_symmetries=False)
            block = manifest_block(find_symmetries(load_object(name, with_extras(m, extras, [name]))))
            done[o["sha256"]] = {k: block[k] for k in ("discrete", "continuous")}
        o["symmetries"] = done[o["sha256"]]
        write(content, path)


def main(argv: list[str] | None = None) -> int:
    """``python -m helpers.data.extra_objects [--write] [--validation N] [--seed S]``: list (or write) the extras."""
    ap = argparse.ArgumentParser(prog="python -m helpers.data.extra_objects", description=__doc__.split("\n")[0])
    ap.add_argument("--write", action="store_true", help=f"write {EXTRA_FILE.name} (and the validation symmetries)")
    ap.add_argument("--validation", type=int, default=24, help="extra meshes kept out of training for validation")
    ap.add_argument("--seed", type=int, default=0, help="seed of the colours and of both lists")
    a = ap.parse_args(argv)
    try:
        content = build(a.validation, a.seed)
    except (ManifestError, ValueError) as e:
        print(f"extra_objects: {e}", file=sys.stderr)
        return 2
    print(f"{len(content['objects'])} extra meshes: {len(content['validation'])} for validation, "
          f"{len(content['training'])} in training order, {len(content['excluded'])} excluded"
          + "".join(f"\n  excluded {e['name']}: {e['reason']}" for e in content["excluded"]))
    if a.write:
        old = yaml.safe_load(EXTRA_FILE.read_text()) if EXTRA_FILE.exists() else {}
        _declare_symmetries(content, EXTRA_FILE, old or {})
        print(f"wrote {EXTRA_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
