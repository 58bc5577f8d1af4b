"""Stage 1: render the benchmark's reference and query sets and show them."""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import pandas as pd

from .fileio import atomic_write_json
from .figures import view_grid
from .manifest import load_manifest, verify
from .render import gl_platform
from .study import DataConfig, prepare_data
from .tables import write_table


def object_table(manifest=None) -> pd.DataFrame:
    """One row per manifest object: role, split, source package/version, file, sha256 prefix."""
    m = manifest or load_manifest()
    rows = [{"object": o.name, "role": o.role, "split": o.split if o.split else "-", "source": o.source.package,
             "version": o.source.version, "file": o.mesh.path, "sha256": o.mesh.sha256[:12],
             "textured": o.color is None, "licence": o.licence, "description": o.description} for o in m.objects]
    return pd.DataFrame(rows)


def run_render_stage(cfg: DataConfig, out_dir: Path, n_show: int = 4) -> dict:
    """Render (or load) every view set the study needs and show them.

    Writes into ``out_dir``: objects.csv/.md (the manifest), views.png (per
    object: references, training queries, test queries, occluded test
    queries), render_summary.json. Returns the summary dict.
    """
    m = load_manifest()
    t0 = time.perf_counter()
    verify(m)
    t_verify = time.perf_counter() - t0
    t0 = time.perf_counter()
    data = prepare_data(cfg, manifest=m)
    t_render = time.perf_counter() - t0
    write_table(object_table(m), out_dir / "objects")
    rows = {}
    for n in m.object_names():
        rows[n] = [data.refs[n], data.train_q.get(n, data.test_q[n]), data.test_q[n], data.occluded_q[n]]
    view_grid(rows, n_show, out_dir / "views.png",
              titles=["references", "train queries (held-out objects: test)", "test queries", "occluded test queries"])
    sets = [vs for kind in ("refs", "train_q", "val_q", "test_q", "occluded_q") for vs in getattr(data, kind).values()]
    ref_bytes = sum(v.meta["bytes"] for v in data.refs.values())
    n_obj = len(data.refs)
    summary = {
        "data_config": asdict(cfg), "objects": list(data.refs), "views": sum(len(s) for s in sets),
        "verify_seconds": t_verify, "render_or_load_seconds": t_render,
        "gl_platform": gl_platform(),  # the headless GL backend renders used (probed if nothing rendered)
        "reference_bytes_per_object": ref_bytes / n_obj,
        "reference_bytes_per_10000_per_object": ref_bytes / n_obj / cfg.n_references * 10000,
        "cache_keys": {f"{kind}/{n}": vs.meta["key"] for kind in ("refs", "train_q", "val_q", "test_q", "occluded_q")
                       for n, vs in getattr(data, kind).items()},
    }
    atomic_write_json(out_dir / "render_summary.json", summary)
    return summary
