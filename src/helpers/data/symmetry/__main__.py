"""``python -m helpers.data.symmetry``: apply the symmetry rule and declare what it finds.

    python -m helpers.data.symmetry                    # every manifest object: print the verdicts
    python -m helpers.data.symmetry cereal milk        # some of them
    python -m helpers.data.symmetry --write            # ... and write data_manifest.yaml's section + figures
    python -m helpers.data.symmetry --mesh my.obj      # any mesh file (untextured grey)
    python -m helpers.data.symmetry --parts            # the T-LESS-like parts against their stated symmetries

Exit code 2 on bad input (a message names the object or file), 1 when ``--parts`` finds a stated symmetry that
the rule does not declare.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tqdm.auto import tqdm

from ...core.paths import REPO_ROOT
from ..manifest import ManifestError, load_manifest
from ..meshes import ObjectMesh, custom_object, load_object
from ..parts import PARTS, load_part, spec
from .figure import write_figure
from .manifest_io import write_section
from .rule import SymmetryResult, SymmetryRule, find_symmetries, manifest_block
from .verdicts import check_stated, summary_line

#: Where ``--write`` puts one figure per object (R beside R @ S for every candidate).
FIGURE_DIR = Path("docs") / "symmetry"


def _objects(names: list[str]) -> list[ObjectMesh]:
    m = load_manifest()
    known = [o.name for o in m.objects]
    bad = [n for n in names if n not in known]
    if bad:
        raise SystemExit(_fail(f"unknown object(s) {bad}; the manifest has {known}"))
    return [load_object(n, m) for n in (names or known)]


def _fail(msg: str) -> int:
    print(f"symmetry: {msg}", file=sys.stderr)
    return 2


def _mesh_object(path: str) -> ObjectMesh:
    try:
        return custom_object(path)
    except (OSError, ValueError) as e:
        raise SystemExit(_fail(str(e))) from None


def run_parts(rule: SymmetryRule) -> int:
    """Apply the rule to every T-LESS-like part; 0 when each part's stated symmetries pass it (the rule declares
    them). Symmetries the rule declares beyond the stated ones are listed, not failed: the parts' statements
    are exact geometry, the rule sees 64 px renders."""
    worst = 0
    for name in tqdm([p.name for p in PARTS], desc="parts", unit="part"):
        part = load_part(name)
        res = find_symmetries(part, rule)
        ok, missed, extra = check_stated(res, spec(name).symmetry_entry(), part)
        print(f"{name:18s} stated {'pass' if ok else 'FAIL: ' + str(missed)}; rule declares beyond them: "
              f"{extra or 'nothing'}  ({summary_line(res)})")
        worst = max(worst, 0 if ok else 1)
    return worst


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m helpers.data.symmetry", description=__doc__.split("\n")[0])
    ap.add_argument("objects", nargs="*", help="manifest object names (default: all)")
    ap.add_argument("--write", action="store_true", help="write data_manifest.yaml's symmetries section and figures")
    ap.add_argument("--mesh", help="a mesh file instead of manifest objects")
    ap.add_argument("--parts", action="store_true", help="check the T-LESS-like parts' stated symmetries")
    ap.add_argument("--views", type=int, default=SymmetryRule.n_views, help="viewpoints of the appearance stage")
    a = ap.parse_args(argv)
    if a.views < 8:
        return _fail(f"--views: expected an int >= 8, got {a.views}")
    rule = SymmetryRule(n_views=a.views)
    if a.parts:
        return run_parts(rule)
    try:
        objs = [_mesh_object(a.mesh)] if a.mesh else _objects(a.objects)
    except ManifestError as e:
        return _fail(str(e))
    results: dict[str, SymmetryResult] = {}
    for obj in tqdm(objs, desc="symmetry rule", unit="object"):
        results[obj.name] = find_symmetries(obj, rule)
        print(f"{obj.name:14s} {summary_line(results[obj.name])}")
    if a.write and not a.mesh:
        root = REPO_ROOT
        for name, res in results.items():
            write_figure(res, name, root / FIGURE_DIR / f"{name}.png")
        write_section(load_manifest().path, {n: manifest_block(r) for n, r in results.items()}, rule)
        print(f"wrote {load_manifest().path} (symmetries) and {len(results)} figures in {FIGURE_DIR}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
