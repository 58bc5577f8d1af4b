"""Stage 1: render the benchmark's reference and query sets and show them."""

from __future__ import annotations

import time
from pathlib import Path

import pandas as pd

from .datasets import ViewSetSpec, render_sets
from .fileio import atomic_write_json
from .figures import view_grid
from .manifest import load_manifest, verify
from .render import QueryStyle, RenderConfig
from .tables import write_table


def resolve_objects(spec: list[str] | str, manifest=None) -> list[str]:
    """``"all"``, ``"benchmark"`` (LineMOD-like 13), ``"held-out"``, ``"split1"``..``"split3"``
    or an explicit list of manifest names."""
    m = manifest or load_manifest()
    if isinstance(spec, str):
        if spec == "all":
            return m.object_names()
        if spec == "benchmark":
            return m.object_names("train")
        if spec == "held-out":
            return m.held_out_objects()
        if spec.startswith("split") and spec[5:] in ("1", "2", "3"):
            return m.split_objects(int(spec[5:]))
        raise ValueError(f"objects: expected 'all', 'benchmark', 'held-out', 'split1'..'split3' or a list of "
                         f"names, got {spec!r}")
    for n in spec:
        m.object(n)
    return list(spec)


def object_table(manifest=None) -> pd.DataFrame:
    """One row per manifest object: role, split, source package/version, file, sha256 prefix."""
    m = manifest or load_manifest()
    rows = [{"object": o.name, "role": o.role, "split": o.split if o.split else "-", "source": o.source.package,
             "version": o.source.version, "file": o.mesh.path, "sha256": o.mesh.sha256[:12],
             "textured": o.color is None, "licence": o.licence, "description": o.description} for o in m.objects]
    return pd.DataFrame(rows)


def run_render_stage(objects: list[str] | str, n_references: int, n_queries: int, image_size: int, render_size: int,
                     seed: int, occlusion: float, workers: int, cache_dir: str | None, out_dir: Path,
                     n_show: int = 4) -> dict:
    """Render references, training queries and test queries for ``objects``.

    Writes into ``out_dir``: objects.csv/.md (the manifest), views.png (a grid
    of references / train queries / test queries), render_summary.json.
    Returns the summary dict.
    """
    m = load_manifest()
    t0 = time.perf_counter()
    verify(m)
    t_verify = time.perf_counter() - t0
    names = resolve_objects(objects, m)
    rc = RenderConfig(size=image_size, render_size=render_size)
    specs = []
    for n in names:
        specs.append(ViewSetSpec(n, "reference", n_references, seed, rc))
        specs.append(ViewSetSpec(n, "query", n_queries, seed, rc, QueryStyle(occlusion=occlusion), "train"))
        specs.append(ViewSetSpec(n, "query", n_queries, seed + 1, rc, QueryStyle(occlusion=occlusion), "test"))
    t0 = time.perf_counter()
    sets = render_sets(specs, cache=cache_dir or None, workers=workers, manifest=m)
    t_render = time.perf_counter() - t0
    write_table(object_table(m), out_dir / "objects")
    rows = {n: sets[3 * i:3 * i + 3] for i, n in enumerate(names)}
    view_grid(rows, n_show, out_dir / "views.png", titles=["references", "train queries", "test queries"])
    ref_bytes = sum(s.meta["bytes"] for s in sets if s.kind == "reference")
    summary = {
        "objects": names, "n_references": n_references, "n_queries": n_queries, "image_size": image_size,
        "verify_seconds": t_verify, "render_or_load_seconds": t_render,
        "views": sum(len(s) for s in sets),
        "reference_bytes_per_object": ref_bytes / max(1, len(names)),
        "reference_bytes_per_10000_per_object": ref_bytes / max(1, len(names)) / n_references * 10000,
        "cache_keys": {f"{s.name}/{s.kind}/{s.meta.get('background_split') or '-'}": s.meta["key"] for s in sets},
    }
    atomic_write_json(out_dir / "render_summary.json", summary)
    return summary
