"""Notebook 01: the rendered benchmark (references and real-like queries of every object)."""

from __future__ import annotations

from pathlib import Path

from ..report_format import load_json
from .base import Experiment


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    s = load_json(d / "render_summary.json")
    if not s:
        return ["## 1 · Rendered benchmark", "", "_not run_", ""]
    c = s["data_config"]
    return ["## 1 · Rendered benchmark", "",
            f"{len(s['objects'])} objects, {s['views']} views rendered or loaded in {s['render_or_load_seconds']:.0f} s "
            f"({c['n_references']} references per object at {c['image_size']} px; "
            f"{c['n_train_queries']}/{c['n_val_queries']}/{c['n_test_queries']} train/val/test queries per object). "
            f"10,000 references of one object take {s['reference_bytes_per_10000_per_object'] / 1e6:.0f} MB on disk "
            f"at this size.", "", "![views](01_render/views.png)", ""]


EXPERIMENT = Experiment("01_render", "render the benchmark: references and real-like queries of every object",
                        section=section)
