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
from ..evaluation.stats import accuracy_ci
from ..search.features import encode_views

if TYPE_CHECKING:  # annotations only: figures must not import the study layer
    from .pipeline import StudyData


#: One style for every figure of the study: the colour of each method (ours, the baselines, the paper's numbers,
#: which are hatched grey bars), and the text sizes (points) that :func:`_plt` installs.
COLOURS = {"ours": "tab:blue", "ours seen": "#9ecae1", "ours occluded": "#08519c", "hog": "tab:orange",
           "global": "tab:purple", "paper": "lightgrey", "up": "tab:green", "down": "tab:red"}
PAPER_BAR = {"color": COLOURS["paper"], "edgecolor": "k", "hatch": "//"}
TEXT_PT = {"font.size": 8, "axes.titlesize": 9, "axes.labelsize": 8, "xtick.labelsize": 8, "ytick.labelsize": 8,
           "legend.fontsize": 7, "legend.frameon": False}


def _plt():
    """pyplot on the Agg backend with the study's text sizes (:data:`TEXT_PT`); chosen at call time, so importing
    this module touches no matplotlib state."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update(TEXT_PT)
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
        rows: {object name: [ObjectViews or None, ...]} (e.g. references then queries; None: a set the object
            does not have, drawn blank).
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
                if vs is not None and j < len(vs):
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
    ax.bar(x - (w / 2 if paper_col else 0), vals, w, yerr=err, capsize=3, color=COLOURS["ours"],
           label="ours" + (" (95 % interval over queries)" if ci_cols else ""))
    if paper_col:
        pv = pd.to_numeric(df[paper_col], errors="coerce")
        ax.bar(x + w / 2, pv.fillna(0), w, label="paper (LineMOD)", **PAPER_BAR)
    if paper_col or ci_cols:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=2)
    ax.set_xticks(x, df[label_col], rotation=20)
    ax.set_ylabel(value_col)
    ax.set_title(title)
    return save(fig, path)


#: Table 1's bars: (column of the table, part of the per-query table, legend label, colour).
TABLE1_BARS = (("unseen rot_acc", "unseen", "ours unseen", COLOURS["ours"]),
               ("seen rot_acc", "seen", "ours seen", COLOURS["ours seen"]),
               ("occluded unseen rot_acc", "occluded", "ours occluded unseen", COLOURS["ours occluded"]))


def table1_intervals(t1: pd.DataFrame, per_query: pd.DataFrame) -> pd.DataFrame:
    """95 % bootstrap intervals (object-averaged, as every claim's) of Table 1's Rota. Acc. bars: one row per
    row of ``t1`` (``#1``.. and ``mean``, all splits together), columns ``<column> lo`` / ``<column> hi`` in %.
    ``per_query``: notebook 03's ``per_query_ours.csv`` (columns split, obj, part, rot_ok)."""
    rows = []
    for label in t1["split"]:
        pq = per_query if label == "mean" else per_query[per_query["split"].astype(str) == str(label).lstrip("#")]
        row = {"split": label}
        for col, part, _, _ in TABLE1_BARS:
            sub = pq[pq["part"] == part]
            lo, hi = accuracy_ci(sub)[1] if len(sub) else (np.nan, np.nan)
            row[f"{col} lo"], row[f"{col} hi"] = lo, hi
        rows.append(row)
    return pd.DataFrame(rows)


def bar_chart(t1: pd.DataFrame, path: Path, per_query: pd.DataFrame | None = None) -> Path:
    """Ours (unseen, seen, occluded) per split beside the paper's unseen LineMOD numbers; with ``per_query``
    (notebook 03's per-query table) each of ours carries its 95 % interval (:func:`table1_intervals`)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.4))
    x = np.arange(len(t1))
    ci = table1_intervals(t1, per_query) if per_query is not None else None
    w = 0.2
    for i, (col, _, label, colour) in enumerate(TABLE1_BARS):
        vals = pd.to_numeric(t1[col], errors="coerce").to_numpy()
        err = None if ci is None else np.vstack([vals - ci[f"{col} lo"], ci[f"{col} hi"] - vals])
        ax.bar(x + (i - 1.5) * w, np.nan_to_num(vals), w, yerr=err, capsize=2, label=label, color=colour)
    paper_vals = pd.to_numeric(t1["paper LineMOD unseen rot_acc"], errors="coerce").fillna(0).to_numpy()
    ax.bar(x + 1.5 * w, paper_vals, w, label="paper unseen (LineMOD)", **PAPER_BAR)
    ax.set_xticks(x, t1["split"])
    ax.set_ylabel("Rota. Acc. (%)  [err < 30°, class right]")
    ax.set_ylim(0, 100)
    ax.legend(ncol=2, title="error bars: 95 % interval over queries" if ci is not None else None)
    ax.set_title("Rotation accuracy per split (ours: rendered benchmark; paper: real LineMOD)")
    return save(fig, path)


def methods_figure(per_query: dict[tuple[str, str], pd.DataFrame], path: Path) -> Path:
    """Table 1 like with like as bars: unseen Rota. Acc. of each method (colour, :data:`COLOURS`) under each search
    (group), with its 95 % interval over queries. ``per_query``: (method, search) -> the method's per-query table
    of unseen queries (columns split, obj, rot_ok), as :func:`helpers.study.protocols.linemod.searches_table`."""
    plt = _plt()
    methods = list(dict.fromkeys(m for m, _ in per_query))
    searches = list(dict.fromkeys(s for _, s in per_query))
    fig, ax = plt.subplots(figsize=(max(4.5, 1.6 * len(searches) * len(methods) / 2 + 1.5), 3.4))
    w = 0.8 / len(methods)
    for i, method in enumerate(methods):
        x, vals, err = [], [], [[], []]
        for j, s in enumerate(searches):
            pq = per_query.get((method, s))
            if pq is None:
                continue
            point, (lo, hi) = accuracy_ci(pq)
            x.append(j + (i - (len(methods) - 1) / 2) * w)
            vals.append(point)
            err[0].append(point - lo)
            err[1].append(hi - point)
        splits = sorted({str(v) for pq in (per_query[(m, s)] for m, s in per_query if m == method)
                         for v in pq["split"]})
        ax.bar(x, vals, w, yerr=err, capsize=3, color=COLOURS.get(method.lower(), "grey"),
               label=f"{method} (split{'s' if len(splits) > 1 else ''} #{', #'.join(splits)})")
    ax.set_xticks(range(len(searches)), [f"{s} search" for s in searches])
    ax.set_ylabel("unseen Rota. Acc. (%)")
    ax.set_ylim(0, 100)
    ax.legend(loc="upper right", title="error bars: 95 % interval over queries")
    ax.set_title("Table 1 like with like: the same references, queries and search for every method")
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
    ax.legend(loc="upper left")
    ax.set_title(f"Reference count, split #{split} unseen (cf. paper Fig. 7)")
    return save(fig, path)


def curves_figure(curves: dict, path: str | os.PathLike, title: str) -> Path:
    """Validation Rota. Acc. (%) against optimiser steps, one line per variant ({label: (steps, acc)})."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    for label, (x, y) in curves.items():
        ax.plot(x, y, marker="o" if len(x) <= 3 else ".", label=label)  # a short run's few points stay visible
    ax.set(xlabel="optimiser steps", ylabel="validation Rota. Acc. (%)", title=title)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2))  # below the axes: covers no curve
    ax.grid(alpha=0.3)
    return save(fig, path)


def extra_objects_figure(curve: pd.DataFrame, path: str | os.PathLike, split: int) -> Path:
    """Rota. Acc. against N extra training objects, with 95 % intervals: the validation extras (deciding) and the
    split's unseen test objects (afterwards, dashed). N on a symlog axis (N = 0 is a point of the curve)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.2, 3.4))
    for col, style, what in (("validation", "o-", "validation extras (decides)"),
                             ("unseen test", "s--", f"split #{split} unseen test (afterwards)")):
        y = pd.to_numeric(curve[f"{col} rot_acc"], errors="coerce")
        if y.isna().all():
            continue
        lo, hi = (pd.to_numeric(curve[f"{col} ci95 {b}"], errors="coerce") for b in ("lo", "hi"))
        ax.errorbar(curve["N extra objects"], y, yerr=[y - lo, hi - y], fmt=style, capsize=3, label=what)
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator  # after _plt picks Agg

    ns = sorted({int(n) for n in curve["N extra objects"]})
    ax.set_xscale("symlog", linthresh=10)
    ax.xaxis.set_major_locator(FixedLocator(ns))  # one plain label per N measured (symlog's own read 5.5x10^-2)
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:,.0f}"))
    ax.xaxis.set_minor_locator(NullLocator())
    if len(ns) == 1:
        ax.set_xlim(ns[0] - 1, ns[0] + 10)
    ax.set(xlabel="extra training objects N", ylabel="Rota. Acc. (%)",
           title=f"Extra training objects, split #{split} (not in the paper)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2))
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
            ax.bar(i, r.rot_acc, color=COLOURS["ours"])
            ax.errorbar(i, r.rot_acc, yerr=[[r.rot_acc - r.ci95_lo], [r.ci95_hi - r.rot_acc]], color="k", capsize=3)
        elif r.verdict == "not measured":
            ax.bar(i, r.change_pts, bottom=level, color="white", edgecolor="grey", hatch="//")
        else:
            ax.bar(i, r.change_pts, bottom=level, color=COLOURS["up" if r.change_pts >= 0 else "down"])
            top = level + r.change_pts
            ax.errorbar(i, top, yerr=[[r.change_pts - r.change_lo], [r.change_hi - r.change_pts]], color="k",
                        capsize=3)
        level = r.rot_acc
        ax.text(i + 0.42, level, f"{level:.1f}", ha="right", va="bottom", fontsize=7)  # clear of the error bar
    ax.set_xticks(range(len(table)))
    ax.set_xticklabels([textwrap.fill(str(s), 16) for s in table["label"]], fontsize=6)
    ax.set_ylabel("unseen Rota. Acc. (%)")
    ax.set_ylim(0, 100)
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return save(fig, path)
