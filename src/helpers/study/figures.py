"""Figures of the study written as PNG files (matplotlib, Agg backend chosen at call time)."""

from __future__ import annotations

import io
import os
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..core.device import resolve_device
from ..core.fileio import atomic_write_bytes
from ..core.views import ObjectViews
from ..search.features import encode_views

if TYPE_CHECKING:  # annotations only: figures must not import the study layer
    from .pipeline import StudyData


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


def bars(df: pd.DataFrame, label_col: str, value_col: str, path: Path, title: str,
         paper_col: str | None = None, ci_cols: tuple[str, str] | None = None) -> Path:
    """Bar chart of one metric per variant, with the paper's values hatched beside (``paper_col``) and 95 %
    intervals as error bars (``ci_cols``: the columns of the lower and upper bound, same unit as the value).
    The legend sits below the axes so it never hides a bar."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(max(4, 0.9 * len(df) + 1.5), 3.6))
    x = np.arange(len(df))
    w = 0.38 if paper_col else 0.6
    vals = pd.to_numeric(df[value_col], errors="coerce").to_numpy()
    err = None
    if ci_cols:
        lo, hi = (pd.to_numeric(df[c], errors="coerce").to_numpy() for c in ci_cols)
        err = np.vstack([vals - lo, hi - vals])
    ax.bar(x - (w / 2 if paper_col else 0), vals, w, yerr=err, capsize=3,
           label="ours" + (" (95 % interval over queries)" if ci_cols else ""))
    if paper_col:
        pv = pd.to_numeric(df[paper_col], errors="coerce")
        ax.bar(x + w / 2, pv.fillna(0), w, label="paper (LineMOD)", color="lightgrey", edgecolor="k", hatch="//")
    if paper_col or ci_cols:
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=2, frameon=False)
    ax.set_xticks(x, df[label_col], rotation=20, fontsize=8)
    ax.set_ylabel(value_col)
    ax.set_title(title, fontsize=9)
    return save(fig, path)


def bar_chart(t1: pd.DataFrame, path: Path) -> Path:
    """Ours (unseen, seen, occluded) per split beside the paper's unseen LineMOD numbers."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.4))
    x = np.arange(len(t1))
    cols = [("unseen rot_acc", "ours unseen"), ("seen rot_acc", "ours seen"),
            ("occluded unseen rot_acc", "ours occluded unseen"), ("paper LineMOD unseen rot_acc", "paper unseen (LineMOD)")]
    w = 0.2
    for i, (c, lab) in enumerate(cols):
        vals = pd.to_numeric(t1[c], errors="coerce").fillna(0).to_numpy()
        ax.bar(x + (i - 1.5) * w, vals, w, label=lab, hatch="//" if "paper" in lab else None,
               color=None if "paper" not in lab else "lightgrey", edgecolor="k" if "paper" in lab else None)
    ax.set_xticks(x, t1["split"])
    ax.set_ylabel("Rota. Acc. (%)  [err < 30°, class right]")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("Rotation accuracy per split (ours: rendered benchmark; paper: real LineMOD)", fontsize=9)
    return save(fig, path)


def examples_figure(data: StudyData, res: dict, path: Path, n: int = 6) -> Path:
    """Query | retrieved reference (predicted object) | error, for the first queries of each object."""
    plt = _plt()
    pq = res["per_query"]
    picks = pq.groupby("obj").head(max(1, n // max(1, pq["obj"].nunique()) + 1)).head(n)
    recs = {r.query_id: r for r in res["records"]}
    fig, axes = plt.subplots(2, len(picks), figsize=(1.8 * len(picks), 4), squeeze=False)
    for j, (_, row) in enumerate(picks.iterrows()):
        name, i = row["query_id"].rsplit(":", 1)
        axes[0, j].imshow(data.test_q[name].images[int(i)] if name in data.test_q else np.zeros((8, 8, 3)))
        axes[0, j].set_title(f"{name}", fontsize=7)
        rec = recs[row["query_id"]]
        axes[1, j].imshow(_retrieved_image(data, rec))
        axes[1, j].set_title(f"→ {rec.pred_obj}\n{row['err_deg']:.0f}°", fontsize=7,
                             color="green" if row["rot_ok"] else "red")
        for a in axes[:, j]:
            a.set_xticks([])
            a.set_yticks([])
    axes[0, 0].set_ylabel("query", fontsize=8)
    axes[1, 0].set_ylabel("retrieved", fontsize=8)
    return save(fig, path)


def _retrieved_image(data: StudyData, rec) -> np.ndarray:
    """The reference image a prediction retrieved: the predicted object's view at R_est."""
    refs = data.refs[rec.pred_obj]
    k = int(np.argmax(np.einsum("nij,ij->n", refs.rotations.astype(np.float64), rec.R_est)))
    return refs.images[k]


def fusion_maps_figure(model, data: StudyData, res: dict, path: Path, n: int = 4, device: str = "auto") -> Path | None:
    """Paper Fig. 6b: the fusion weight maps between queries and their retrieved references."""
    import torch

    if not hasattr(model, "fusion_maps"):
        return None
    plt = _plt()
    dev = resolve_device(device)
    recs = res["records"][:n]
    rows = []
    for rec in recs:
        name, i = rec.query_id.rsplit(":", 1)
        q_img = data.test_q[name].images[int(i):int(i) + 1]
        r_img = _retrieved_image(data, rec)[None]
        qf = next(encode_views(model, q_img, device=dev)).to(dev)
        rf = next(encode_views(model, r_img, device=dev)).to(dev)
        with torch.inference_mode():
            maps = model.fusion_maps(qf, rf)
        rows.append((q_img[0], r_img[0], {lvl: m[0].float().cpu().numpy() for lvl, m in maps.items()}))
    if not rows:
        return None
    levels = list(rows[0][2])
    ncol = 2 + len(levels)
    fig, axes = plt.subplots(len(rows), ncol, figsize=(1.7 * ncol, 1.7 * len(rows)), squeeze=False)
    for r, (qi, ri, maps) in enumerate(rows):
        axes[r, 0].imshow(qi)
        axes[r, 1].imshow(ri)
        for c, lvl in enumerate(levels):
            axes[r, 2 + c].imshow(qi, alpha=0.5)
            axes[r, 2 + c].imshow(maps[lvl], cmap="inferno", alpha=0.6, extent=(0, qi.shape[1], qi.shape[0], 0))
            if r == 0:
                axes[r, 2 + c].set_title(f"weights @{lvl}", fontsize=7)
        for a in axes[r]:
            a.set_xticks([])
            a.set_yticks([])
    axes[0, 0].set_title("query", fontsize=7)
    axes[0, 1].set_title("retrieved", fontsize=7)
    return save(fig, path)


def reference_count_figure(df, split: int, path: str | os.PathLike) -> Path:
    """Unseen Rota. Acc. (left axis, solid) and queries/s (right axis, dashed) against references per object, one
    colour per search (``search`` column; a table without it is greedy)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.4, 3.4))
    ax2 = ax.twinx()
    searches = df["search"] if "search" in df.columns else ["greedy"] * len(df)
    for (how, g), colour in zip(df.groupby(list(searches), sort=False), ("tab:blue", "tab:green")):
        ax.plot(g["refs_per_object"], g["unseen rot_acc"], "o-", color=colour, label=f"Rota. Acc., {how} (%)")
        ax2.plot(g["refs_per_object"], g["queries/s"], "s--", color=colour, alpha=0.6, label=f"queries/s, {how}")
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter, NullLocator  # after _plt picks Agg

    counts = sorted({int(c) for c in df["refs_per_object"]})
    ax.set_xscale("log", base=2)
    # One plain label per count measured, and no minor labels: log axes otherwise print "3x10^1 4x10^1 ..." over
    # each other on both axes.
    ax.xaxis.set_major_locator(FixedLocator(counts))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:,.0f}"))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xlabel("references per object")
    ax.set_ylabel("unseen Rota. Acc. (%)")
    ax2.set_yscale("log")
    ax2.yaxis.set_minor_formatter(NullFormatter())
    ax2.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax2.set_ylabel("queries/s (dashed)")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(f"Reference count, split #{split} unseen (cf. paper Fig. 7)", fontsize=9)
    return save(fig, path)


def curves_figure(curves: dict, path: str | os.PathLike, title: str) -> Path:
    """Validation Rota. Acc. (%) against optimiser steps, one line per variant ({label: (steps, acc)})."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    for label, (x, y) in curves.items():
        ax.plot(x, y, marker="o" if len(x) <= 3 else ".", label=label)  # a short run's few points stay visible
    ax.set(xlabel="optimiser steps", ylabel="validation Rota. Acc. (%)", title=title)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2))  # below the axes: covers no curve
    ax.grid(alpha=0.3)
    return save(fig, path)


def waterfall_figure(table, path: str | os.PathLike, title: str) -> Path:
    """The gap account as a waterfall: the first step's Rota. Acc. as a bar, each later step as a floating bar
    of its paired change (green up, red down) with the change's 95 % interval, a hatched bar for what is not
    measured, and the final level. ``table``: :func:`helpers.evaluation.gap.account`'s rows."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.2, 3.8))
    level = 0.0
    for i, r in enumerate(table.itertuples()):
        if i == 0:
            ax.bar(i, r.rot_acc, color="tab:blue")
            ax.errorbar(i, r.rot_acc, yerr=[[r.rot_acc - r.ci95_lo], [r.ci95_hi - r.rot_acc]], color="k", capsize=3)
        elif r.verdict == "not measured":
            ax.bar(i, r.change_pts, bottom=level, color="white", edgecolor="grey", hatch="//")
        else:
            ax.bar(i, r.change_pts, bottom=level, color="tab:green" if r.change_pts >= 0 else "tab:red")
            top = level + r.change_pts
            ax.errorbar(i, top, yerr=[[r.change_pts - r.change_lo], [r.change_hi - r.change_pts]], color="k",
                        capsize=3)
        level = r.rot_acc
        ax.text(i + 0.42, level, f"{level:.1f}", ha="right", va="bottom", fontsize=7)  # clear of the error bar
    ax.set_xticks(range(len(table)))
    ax.set_xticklabels([textwrap.fill(str(s), 16) for s in table["label"]], fontsize=6)
    ax.set_ylabel("unseen Rota. Acc. (%)")
    ax.set_ylim(0, 100)
    ax.set_title(title, fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return save(fig, path)
