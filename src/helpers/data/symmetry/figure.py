"""The evidence figure of one object: renders at R beside R @ S for every candidate the rule tested."""

from __future__ import annotations

import io
from pathlib import Path

from matplotlib.figure import Figure  # the object API: no pyplot state, no backend to choose

from ...core.fileio import atomic_write_bytes
from .rule import SymmetryResult

#: Viewpoints shown per figure (rows).
ROWS = 4


def _titles(res: SymmetryResult) -> list[str]:
    out = ["R (query-like view)"]
    for c in res.evidence["continuous"]:
        for a in c["angles"]:
            out.append(f"{a['angle_deg']:g} deg about axis\nshare {a['share_below_1']:.2f} "
                       f"{'declared' if c['declared'] else 'rejected'}")
    for c in res.evidence["candidates"]:
        out.append(f"R @ S: {c['angle_deg']:g} deg\nshare {c['share_below_1']:.2f}, "
                   f"{'declared' if c['declared'] else 'rejected'}")
    return out


def write_figure(res: SymmetryResult, name: str, path: Path) -> Path:
    """PNG: rows = the first :data:`ROWS` viewpoints; columns = R, then R @ S per candidate with its share of
    views in which S is closer than a small turn, and the verdict."""
    keys = list(res.renders)
    titles = _titles(res)
    fig = Figure(figsize=(1.6 * len(keys) + 0.4, 1.6 * ROWS + 0.8))
    axes = fig.subplots(ROWS, len(keys), squeeze=False)
    for j, k in enumerate(keys):
        for i in range(ROWS):
            ax = axes[i][j]
            ax.imshow(res.renders[k][i])
            ax.set_xticks([])
            ax.set_yticks([])
        axes[0][j].set_title(titles[j] if j < len(titles) else k, fontsize=7)
    fig.suptitle(f"{name}: symmetry candidates (share = views where R @ S is closer to R than a "
                 f"{res.evidence['rule']['small_turn_deg']:g} deg turn; declared at >= "
                 f"{res.evidence['rule']['min_share']:g})", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    atomic_write_bytes(path, buf.getvalue())
    return path
