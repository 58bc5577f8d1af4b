"""Bring your own object from the command line: ``python -m helpers.study.cli.byo MESH CROP`` prints the
rotation ``R_m2c`` (model -> OpenCV camera), its quaternion, the retrieval score, the next best references and
the mesh's symmetries; ``--json`` prints one object instead. The work is :func:`helpers.study.byo.estimate_rotation`."""

from __future__ import annotations

import numpy as np

from .. import zoo
from ..byo import ByoResult, estimate_rotation, overlay_figure

DEFAULT_MODELS = ("all", "split1", "split2", "split3")


def _default_model(available: dict) -> str:
    for name in DEFAULT_MODELS:
        if name in available:
            return name
    raise ValueError(f"no zoo model among {DEFAULT_MODELS} in models/zoo.yaml; pass --model NAME "
                     f"(available: {sorted(available)})")


def _quaternion_wxyz(R: np.ndarray) -> list[float]:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return [float(w), float(x), float(y), float(z)]


def _print_symmetries(res: ByoResult) -> None:
    sym = res.symmetries or {"discrete": [], "continuous": []}
    if not sym["discrete"] and not sym["continuous"]:
        print("symmetries (helpers.data.symmetry's rule on the mesh): none; the answer is the only right one")
        return
    turns = [f"{d['angle_deg']:g} deg about {d['axis']}" for d in sym["discrete"]]
    turns += [f"any turn about {c['axis']}" for c in sym["continuous"]]
    print("symmetries (helpers.data.symmetry's rule on the mesh, model frame): " + "; ".join(turns))
    for R, d in zip(res.equivalents, sym["discrete"]):
        print(f"  equally right, R_m2c @ ({d['angle_deg']:g} deg about {d['axis']}):")
        for row in R:
            print("    " + "  ".join(f"{v:+.4f}" for v in row))


def main(argv: list[str] | None = None) -> int:
    """``python -m helpers.study.cli.byo MESH CROP [--model NAME] [--refs N] [--out overlay.png] [--json]``."""
    import argparse
    import json
    import sys
    import time

    ap = argparse.ArgumentParser(prog="python -m helpers.study.cli.byo",
                                 description="Rotation of the object in CROP (an image) from its mesh MESH.")
    ap.add_argument("mesh", help="mesh file (OBJ, PLY, STL, GLB...)")
    ap.add_argument("crop", help="image of the object, cropped around it (PNG/JPEG; transparency is black)")
    ap.add_argument("--model", default=None, help=f"zoo model (default: the first of {', '.join(DEFAULT_MODELS)})")
    ap.add_argument("--refs", type=int, default=1024, help="references rendered from the mesh (default 1024)")
    ap.add_argument("--out", default=None, help="write the query | retrieved | overlay figure here (PNG)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    ap.add_argument("--device", default="auto")
    ap.add_argument("--cache", default=None, help="cache root (default: $HELPERS_CACHE_DIR or <repo>/cache)")
    a = ap.parse_args(argv)
    if a.refs < 1:
        ap.error(f"--refs: expected a positive number of references, got {a.refs}")
    t0 = time.perf_counter()
    try:
        name = a.model or _default_model(zoo.entries())
        model, _ = zoo.load(name, device=a.device)
        res = estimate_rotation(model, a.mesh, a.crop, n_refs=a.refs, device=a.device, cache=a.cache)
    except (FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if a.out:
        overlay_figure(res, a.out)
    out = {"model": name, "R_m2c": res.R_m2c.tolist(), "quaternion_wxyz": _quaternion_wxyz(res.R_m2c),
           "score": res.score, "reference": res.ref_index, "n_references": a.refs,
           "alternatives": res.alternatives, "symmetries": res.symmetries, "equivalent_R_m2c": res.equivalents,
           "seconds": time.perf_counter() - t0,
           **({"overlay": a.out} if a.out else {})}
    if a.json:
        print(json.dumps(out, indent=1))
        return 0
    print(f"model {name}; best of {a.refs} references: #{res.ref_index}, score {res.score:.3f}")
    print("R_m2c (model -> OpenCV camera):")
    for row in res.R_m2c:
        print("  " + "  ".join(f"{v:+.4f}" for v in row))
    print("quaternion (w, x, y, z): " + ", ".join(f"{v:+.4f}" for v in out["quaternion_wxyz"]))
    print("next best: " + "; ".join(f"#{x['index']} score {x['score']:.3f} at {x['deg_from_best']:.0f} deg"
                                    for x in res.alternatives))
    _print_symmetries(res)
    if a.out:
        print(f"overlay: {a.out}")
    print(f"{out['seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
