"""Bring-your-own-object timing: the first and the second query of the same mesh and model.

    .venv/bin/python benchmarks/bench_byo.py [--refs 1024] [--out benchmarks/results/bench_byo.json]

The first call renders the mesh's references and encodes them; the second (another
query crop of the same object) must only encode the query and search, since
renders and features are cached by (mesh sha256, reference set, model weights).
Uses a fresh cache folder, a randomly initialised 64 px model (timing does not
depend on the weights) and a held-out object of the manifest as "your" mesh.
Writes medians of ``--repeats`` second calls and the first call's time.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--refs", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "bench_byo.json"))
    a = ap.parse_args(argv)

    import torch

    from helpers.core.configs import ModelConfig
    from helpers.core.fileio import atomic_write_json
    from helpers.core.paths import portable_obj
    from helpers.data.manifest import load_manifest
    from helpers.net.model import OrientationNet
    from helpers.study.byo import estimate_rotation
    from helpers.study.provenance import run_record

    torch.set_num_threads(2)
    torch.manual_seed(0)
    m = load_manifest()
    name = m.held_out_objects()[0]
    entry = m.object(name)
    model = OrientationNet(ModelConfig(image_size=64)).eval()
    with tempfile.TemporaryDirectory(prefix="bench_byo_") as tmp:
        queries = []
        for i in range(a.repeats + 1):  # distinct crops: nothing about the query is cached
            img = np.zeros((80, 64, 3), np.uint8)
            cv2.circle(img, (32, 40), 10 + i, (200, 150 - 10 * i, 90), -1)
            p = Path(tmp) / f"q{i}.png"
            cv2.imwrite(str(p), img)
            queries.append(p)
        kw = dict(n_refs=a.refs, render_size=96, color=entry.color, device="cpu", cache=Path(tmp) / "cache")
        t0 = time.perf_counter()
        estimate_rotation(model, entry.mesh.resolve(), queries[0], **kw)
        first = time.perf_counter() - t0
        later = []
        for q in queries[1:]:
            t0 = time.perf_counter()
            estimate_rotation(model, entry.mesh.resolve(), q, **kw)
            later.append(time.perf_counter() - t0)
    res = {"object": name, "n_refs": a.refs, "image_size": 64, "first_call_s": first,
           "second_call_s_all": later, "second_call_s_median": float(np.median(later)),
           "speedup_second_vs_first": first / float(np.median(later)),
           "provenance": run_record("bench_byo", vars(a))}
    atomic_write_json(a.out, portable_obj(res))
    print(f"first call {first:.1f} s, later calls median {np.median(later):.3f} s "
          f"({res['speedup_second_vs_first']:.0f}x) -> {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
