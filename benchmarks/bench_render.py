"""Section 1 of the CPU benchmark: rendering speed (references/s).

``render_sets`` with 1 and 2 spawned workers (process start-up included), the
same work in this process (``workers=0``), and a bare ``render_reference``
loop. Called by ``benchmarks/bench.py``; the result is the JSON's ``render``.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from timing import log, measure, wait_quiet

if TYPE_CHECKING:
    from bench_config import BenchConfig


def bench_render(cfg: BenchConfig, tmp_root: str | None = None) -> dict:
    """References/s of ``render_sets`` with 1 and 2 spawned workers (start-up included),
    of ``render_sets(workers=0)`` and of a bare ``render_reference`` loop in this process."""
    from helpers.core.configs import RenderConfig
    from helpers.core.rotations import haar_uniform
    from helpers.data.datasets import ViewSetSpec, render_sets
    from helpers.data.gl import gl_platform
    from helpers.data.manifest import load_manifest
    from helpers.data.meshes import load_object
    from helpers.data.render import render_reference

    platform = gl_platform()  # probe once here so every worker inherits PYOPENGL_PLATFORM
    manifest = load_manifest()
    objects = manifest.object_names("train")[:cfg.render_objects]
    rc = RenderConfig(size=cfg.render_size)
    specs = [ViewSetSpec(o, "reference", cfg.render_refs_per_object, cfg.seed, rc) for o in objects]
    n_total = len(specs) * cfg.render_refs_per_object
    out: dict[str, Any] = {"objects": objects, "refs_per_object": cfg.render_refs_per_object,
                           "n_renders": n_total, "render_config": asdict(rc), "gl_platform": platform,
                           "note": "fresh empty cache folder per run (nothing cached); worker runs include "
                                   "process spawn, imports, GL context creation, mesh loading, chunk "
                                   "writing and consolidation"}

    def setup() -> str:
        return tempfile.mkdtemp(prefix="bench_render_", dir=tmp_root)

    def teardown(d: str) -> None:
        shutil.rmtree(d, ignore_errors=True)

    for w in (*cfg.render_workers, 0):
        wait_quiet()
        t = measure(lambda d, w=w: render_sets(specs, cache=d, workers=w, progress=False),
                    cfg.render_repeats, cfg.render_warmup, setup, teardown)
        out[f"render_sets_workers_{w}"] = {**t, "renders_per_s": n_total / t["median_s"]}
        log(f"render_sets workers={w}: {n_total / t['median_s']:.1f} renders/s")

    # Bare renderer loop in this process (GL context created in the warm-up).
    obj = load_object(objects[0], manifest)
    rots = haar_uniform(cfg.inproc_renders, seed=cfg.seed + 1)
    wait_quiet()
    t = measure(lambda _: [render_reference(obj, R, rc) for R in rots], cfg.render_repeats, 1)
    out["render_reference_in_process"] = {**t, "n_renders": len(rots), "object": objects[0],
                                          "renders_per_s": len(rots) / t["median_s"]}
    w_rates = {w: out[f"render_sets_workers_{w}"]["renders_per_s"] for w in cfg.render_workers}
    if 1 in w_rates and 2 in w_rates:
        out["speedup_2_vs_1_workers"] = w_rates[2] / w_rates[1]
    if 1 in cfg.render_workers:
        # Worker start-up estimate: the 1-worker run minus the in-process run of the same work.
        out["worker_startup_estimate_s"] = (out["render_sets_workers_1"]["median_s"]
                                            - out["render_sets_workers_0"]["median_s"])
    return out
