"""Figures written as PNG files (matplotlib, Agg backend chosen at call time)."""

from __future__ import annotations

import io
import os
from pathlib import Path

from .fileio import atomic_write_bytes
from .views import ObjectViews


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Save a figure atomically (rendered in memory, then :func:`atomic_write_bytes`) and close it."""
    path = Path(path)
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, bbox_inches="tight", format=path.suffix.lstrip(".") or "png")
    _plt().close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return path


def view_grid(rows: dict[str, list[ObjectViews]], n_per_set: int, path: str | os.PathLike,
              titles: list[str] | None = None) -> Path:
    """One row per object: the first ``n_per_set`` views of each of its view sets side by side.

    Args:
        rows: {object name: [ObjectViews, ...]} (e.g. references then queries).
        titles: optional label per view set, shown above the first row.
    """
    plt = _plt()
    names = list(rows)
    n_sets = max(len(v) for v in rows.values())
    ncols = n_sets * n_per_set
    fig, axes = plt.subplots(len(names), ncols, figsize=(ncols * 1.1, len(names) * 1.1 + 0.3), squeeze=False)
    for r, name in enumerate(names):
        for s, vs in enumerate(rows[name]):
            for j in range(n_per_set):
                ax = axes[r, s * n_per_set + j]
                if j < len(vs):
                    ax.imshow(vs.images[j])
                ax.set_xticks([])
                ax.set_yticks([])
                if r == 0 and j == 0 and titles:
                    ax.set_title(titles[s], fontsize=8, loc="left")
        axes[r, 0].set_ylabel(name, fontsize=8, rotation=0, ha="right", va="center")
    fig.subplots_adjust(wspace=0.03, hspace=0.03)
    return save(fig, path)
