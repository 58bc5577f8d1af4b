"""One query under the microscope: what the explorer notebook (``notebooks/10_explore.ipynb``) shows.

:func:`build_explorer` encodes a reference bank (every benchmark object of a split's
evaluation) and the test queries once; :func:`inspect_query` then answers, for one query:
which references score best (object, score, rotation error, verdict), how the fusion weighs
the locations of the query against its best reference at each scale, and how the score of
the query against every reference of its TRUE object varies with the geodesic distance
between that reference's rotation and the true one (a well-trained model peaks at 0 deg).
:func:`query_figure` draws all of it; the widgets of :mod:`helpers.study.explorer.panels` call these.
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...core.device import resolve_device
from ...core.paths import is_checkpoint_choice, repo_path
from ...core.rotations import symmetric_geodesic_deg
from ...search.bank import ReferenceBank
from ...search.retrieval import model_scorer
from ...training.train import load_model
from ..figures import _plt, save
from ..pipeline import StudyData, encode_queries, reference_bank
from ..zoo import ZOO_DIR, entries, load

#: Rotation accuracy threshold of the study (degrees), as in every report.
THRESHOLD_DEG = 30.0


def model_choices(image_size: int, zoo_dir: Path = ZOO_DIR) -> list[str]:
    """Zoo model names whose input side is ``image_size`` pixels (the ones that fit the data)."""
    try:
        zoo = entries(zoo_dir)
    except FileNotFoundError:
        return []
    return sorted(n for n, e in zoo.items() if e["data"]["image_size"] == image_size)


def load_choice(choice: str, device: str = "auto", zoo_dir: Path = ZOO_DIR) -> tuple[Any, str]:
    """A model by zoo name (sha256 checked) or by checkpoint path (e.g. a cache run's ``best.pt``).

    Returns (model in eval mode, the choice as its label). A relative checkpoint path is read from the
    repository root. ValueError names the choice and what exists when it is neither a zoo model nor a file.
    """
    if is_checkpoint_choice(choice):
        path = repo_path(choice)
        if not path.is_file():
            raise FileNotFoundError(f"model {choice!r}: no checkpoint file {path} (expected a zoo name or a .pt file)")
        model, _ = load_model(path, device=device)
        return model, choice
    model, _ = load(choice, device=device, zoo_dir=zoo_dir)
    return model, choice


@dataclass
class Explorer:
    """A model with its encoded bank and queries.

    Attributes:
        model: the network (eval mode).
        label: its name for titles.
        data: the rendered study data the bank and queries come from.
        bank: reference features of ``bank.names`` at shared rotations (R, 3, 3).
        query_feats: object -> (N, C, L) float32 features of its test queries.
        device: where scoring runs.
    """

    model: Any
    label: str
    data: StudyData
    bank: ReferenceBank
    query_feats: dict[str, torch.Tensor]
    device: torch.device
    _scores: dict[tuple[str, int], np.ndarray] = field(default_factory=dict, repr=False)

    def scores(self, obj: str, i: int) -> np.ndarray:
        """(K, R) scores of query ``i`` of ``obj`` against every reference of the bank (cached)."""
        key = (obj, i)
        if key not in self._scores:
            scorer = model_scorer(self.model, self.device)
            q = self.query_feats[obj][i:i + 1]
            rows = [scorer(q, self.bank.chunk(o, 0, self.bank.n_refs)).reshape(-1).numpy()
                    for o in range(self.bank.n_objects)]
            self._scores[key] = np.stack(rows).astype(np.float64)
        return self._scores[key]


def build_explorer(model: Any, label: str, data: StudyData, bank_objects: list[str], query_objects: list[str],
                   device: str = "auto") -> Explorer:
    """Encode the references of ``bank_objects`` (cached float16 features) and the test queries of
    ``query_objects`` with ``model``."""
    missing = [n for n in query_objects if n not in data.test_q]
    if missing:
        raise ValueError(f"build_explorer: no test queries rendered for {missing}")
    size = getattr(getattr(model, "cfg", None), "image_size", data.cfg.image_size)
    if size != data.cfg.image_size:
        raise ValueError(f"build_explorer: model {label!r} takes {size} px crops, the data are "
                         f"{data.cfg.image_size} px (set image_size to {size})")
    dev = resolve_device(device)
    bank = reference_bank(model, data, bank_objects, device=device, progress=False)
    feats = {n: encode_queries(model, data.test_q[n], device) for n in query_objects}
    return Explorer(model, label, data, bank, feats, dev)


@dataclass
class QueryView:
    """Everything shown for one query.

    Attributes:
        obj, index: the query (object name, index among its test queries).
        top: the best references, best first: {"obj", "ref", "score", "err_deg", "ok"}
            (``err_deg``: geodesic error of its rotation, symmetries included; ``ok``: right
            object and error < 30 deg).
        dist_deg: (R,) geodesic distance of each reference of the TRUE object to the true rotation.
        true_scores: (R,) the query's score against each of those references.
        maps: scale -> (h, w) fusion weights of the query against its best reference (sum 1).
    """

    obj: str
    index: int
    top: list[dict]
    dist_deg: np.ndarray
    true_scores: np.ndarray
    maps: dict[int, np.ndarray]

    def record(self) -> dict:
        """JSON-ready summary (no arrays but the score peak)."""
        near = int(np.argmin(self.dist_deg))
        return {"query": f"{self.obj}:{self.index}", "top": self.top,
                "best_true_object_ref_deg": float(self.dist_deg[int(np.argmax(self.true_scores))]),
                "nearest_ref_deg": float(self.dist_deg[near]), "nearest_ref_score": float(self.true_scores[near])}

    def summary(self) -> str:
        """One line: the query, its top-1 answer and its verdict."""
        t = self.top[0]
        verdict = "correct" if t["ok"] else ("wrong rotation" if t["obj"] == self.obj else "wrong object")
        return (f"query {self.obj} #{self.index}: top-1 {t['obj']} ref {t['ref']} score {t['score']:.3f}, "
                f"error {t['err_deg']:.1f} deg, {verdict}")


def inspect_query(ex: Explorer, obj: str, i: int, top_k: int = 5, maps: bool = True) -> QueryView:
    """Top-``top_k`` references, fusion maps (``maps=False``: none, for records) and score-vs-distance
    curve of query ``i`` of ``obj``."""
    views = ex.data.test_q[obj]
    if not 0 <= i < len(views):
        raise IndexError(f"query {i} of {obj!r}: it has {len(views)} test queries")
    R_gt = np.asarray(views.rotations[i], dtype=np.float64)
    S = ex.scores(obj, i)
    # (R,) symmetry-aware distance of every reference rotation to the true one (all objects share them).
    dist = symmetric_geodesic_deg(ex.bank.rotations, np.broadcast_to(R_gt, ex.bank.rotations.shape),
                                  views.symmetries)
    order = np.argsort(-S.reshape(-1), kind="stable")[:top_k]
    top = []
    for flat in order:
        o, r = divmod(int(flat), ex.bank.n_refs)
        name = ex.bank.names[o]
        err = float(dist[r])
        top.append({"obj": name, "ref": r, "score": float(S[o, r]), "err_deg": err,
                    "ok": bool(name == obj and err < THRESHOLD_DEG)})
    t_obj = ex.bank.names.index(obj)
    fusion = {}
    if maps and hasattr(ex.model, "fusion_maps"):
        o0 = ex.bank.names.index(top[0]["obj"])
        r0 = top[0]["ref"]
        ref = ex.bank.chunk(o0, r0, r0 + 1).float().to(ex.device)
        with torch.inference_mode():
            m = ex.model.fusion_maps(ex.query_feats[obj][i:i + 1].to(ex.device), ref)
        fusion = {lv: a[0].float().cpu().numpy() for lv, a in m.items()}
    return QueryView(obj, i, top, dist, S[t_obj].copy(), fusion)


def query_figure(ex: Explorer, v: QueryView, path: str | os.PathLike | None = None):
    """Query | top-k references (titles: object, score, error; green = within 30 deg) on the first row;
    fusion weight maps of the top-1 pair and the score-vs-distance plot on the second.
    Saved to ``path`` (PNG) and closed when given; else the open figure is returned."""
    plt = _plt()
    k = len(v.top)
    ncol = max(k + 1, len(v.maps) + 3)
    fig = plt.figure(figsize=(1.75 * ncol, 3.9))
    grid = fig.add_gridspec(2, ncol)
    q_img = ex.data.test_q[v.obj].images[v.index]
    ax = fig.add_subplot(grid[0, 0])
    ax.imshow(q_img)
    ax.set_title(f"query\n{v.obj} #{v.index}", fontsize=7)
    for j, t in enumerate(v.top):
        ax = fig.add_subplot(grid[0, j + 1])
        ax.imshow(ex.data.refs[t["obj"]].images[t["ref"]])
        ax.set_title(f"#{j + 1} {t['obj']}\ns={t['score']:.2f} {t['err_deg']:.0f}°", fontsize=7,
                     color="green" if t["ok"] else "red")
    for c, (lv, m) in enumerate(v.maps.items()):
        ax = fig.add_subplot(grid[1, c])
        ax.imshow(q_img, alpha=0.5)
        ax.imshow(m, cmap="inferno", alpha=0.6, extent=(0, q_img.shape[1], q_img.shape[0], 0))
        ax.set_title(f"fusion weights @{lv}", fontsize=7)
    for a in fig.axes:
        a.set_xticks([])
        a.set_yticks([])
    ax = fig.add_subplot(grid[1, len(v.maps):])
    ax.scatter(v.dist_deg, v.true_scores, s=6, alpha=0.6)
    ax.axvline(THRESHOLD_DEG, color="grey", lw=0.8, ls="--")
    ax.set_xlabel(f"geodesic distance to the true rotation (deg), {v.obj}'s references", fontsize=7)
    ax.set_ylabel("score", fontsize=7)
    ax.tick_params(labelsize=6)
    fig.suptitle(f"{ex.label}: {v.summary()}", fontsize=8)
    fig.tight_layout()
    if path is None:
        return fig
    return save(fig, path)


def figure_png(ex: Explorer, v: QueryView) -> bytes:
    """:func:`query_figure` as PNG bytes (for an image widget)."""
    fig = query_figure(ex, v)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    _plt().close(fig)
    return buf.getvalue()
