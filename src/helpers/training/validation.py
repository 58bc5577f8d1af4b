"""Model selection on held-out views of SEEN objects, and the learning-curve figure.

:func:`validate` retrieves each validation query among a small set of references of
every training object; :func:`selection_metric` is what picks ``best.pt``;
:func:`plot_history` draws loss and validation accuracy against steps and minutes.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import torch

from ..core.device import resolve_device
from ..core.fileio import atomic_write_bytes
from ..core.rotations import symmetric_geodesic_deg
from ..core.views import ObjectViews
from ..net.model import OrientationNet, images_to_tensor

ROT_THRESHOLD_DEG = 30.0


def _encode_views(model: OrientationNet, images: np.ndarray, device: torch.device, batch: int,
                  dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Encode (N, S, S, 3) uint8 in batches (no grad) -> (N, C, L) of ``dtype`` on ``device``."""
    out = []
    with torch.inference_mode():
        for s in range(0, len(images), batch):
            out.append(model.encode(images_to_tensor(images[s:s + batch]).to(device)).to(dtype))
    return torch.cat(out, 0) if out else torch.zeros(0, model.cfg.channels, model.feature_length,
                                                     dtype=dtype, device=device)


def validate(model: OrientationNet, val_refs: dict[str, ObjectViews], val_queries: dict[str, ObjectViews],
             device: str | torch.device = "auto", batch_size: int = 32) -> dict:
    """Retrieval accuracy of seen-object validation queries against validation references.

    Every query is scored against the references of *all* objects in
    ``val_refs``; the best one gives the predicted object and rotation.

    Returns:
        dict with ``class_acc`` and ``rot_acc`` (fractions in [0, 1]; rot_acc
        needs the right object and a symmetry-aware error < 30 degrees) and
        ``median_err_deg`` (median rotation error of the retrieved reference,
        whatever its object), each averaged per object then over objects,
        plus ``per_object`` {name: {class_acc, rot_acc, median_err_deg, n}}.
    """
    device = resolve_device(device)
    names = sorted(val_refs)
    missing = set(val_queries) - set(names)
    if missing:
        raise ValueError(f"val_queries: objects {sorted(missing)} have no validation references")
    was_training = model.training
    model.eval()
    try:
        ref_feats = _encode_views(model, np.concatenate([val_refs[n].images for n in names]), device,
                                  batch_size, torch.float16)  # float16 like the retrieval cache
        ref_obj = np.concatenate([np.full(len(val_refs[n]), i) for i, n in enumerate(names)])
        ref_rot = np.concatenate([np.asarray(val_refs[n].rotations, np.float64) for n in names])
        per_object = {}
        for name in sorted(val_queries):
            qv = val_queries[name]
            if len(qv) == 0:
                continue
            best = []
            for s in range(0, len(qv), batch_size):
                qf = _encode_views(model, qv.images[s:s + batch_size], device, batch_size)
                with torch.inference_mode():
                    best.append(model.score(qf, ref_feats).argmax(dim=1).cpu().numpy())
            best = np.concatenate(best)
            sym = qv.symmetries if qv.symmetries is not None else val_refs[name].symmetries
            err = symmetric_geodesic_deg(ref_rot[best], np.asarray(qv.rotations, np.float64), sym)
            correct = ref_obj[best] == names.index(name)
            per_object[name] = {"class_acc": float(correct.mean()),
                                "rot_acc": float((correct & (err < ROT_THRESHOLD_DEG)).mean()),
                                "median_err_deg": float(np.median(err)), "n": int(len(qv))}
    finally:
        model.train(was_training)
    keys = ("class_acc", "rot_acc", "median_err_deg")
    summary = {k: float(np.mean([m[k] for m in per_object.values()])) if per_object else float("nan")
               for k in keys}
    summary["per_object"] = per_object
    return summary


def selection_metric(val: dict, select_on: str) -> float:
    """The number model selection maximises, from a :func:`validate` summary."""
    if select_on == "rot_acc":
        return float(val["rot_acc"])
    return 0.5 * (float(val["class_acc"]) + float(val["rot_acc"]))


def plot_history(history: list[dict], path: str | Path) -> Path:
    """Save the learning curve as a PNG: training loss vs optimiser steps (left), validation
    accuracies (seen objects, %) vs steps (middle) and vs cumulative training minutes (right)."""
    # Figure + Agg canvas directly: no global pyplot/backend state is touched.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 3.5))
    FigureCanvasAgg(fig)
    ax1, ax2, ax3 = fig.subplots(1, 3)
    steps = [h.get("global_step", h["epoch"]) for h in history]
    minutes = np.cumsum([h.get("seconds", 0.0) for h in history]) / 60.0
    ax1.plot(steps, [h["train_loss"] for h in history], marker=".")
    ax1.set(xlabel="optimiser steps", ylabel="train loss (mean over the epoch)", title="training loss")
    val = [(st, mi, h["val"]) for st, mi, h in zip(steps, minutes, history) if h.get("val")]
    for ax, xi, xl in ((ax2, 0, "optimiser steps"), (ax3, 1, "training minutes (CPU wall, validation excluded)")):
        if val:
            x = [v[xi] for v in val]
            ax.plot(x, [100 * v[2]["class_acc"] for v in val], marker=".", label="Class. Acc.")
            ax.plot(x, [100 * v[2]["rot_acc"] for v in val], marker=".", label=f"Rota. Acc. (<{ROT_THRESHOLD_DEG:.0f} deg)")
            ax.legend(fontsize=8)
        ax.set(xlabel=xl, ylabel="%", title="validation: held-out views of SEEN objects")
    for ax in (ax1, ax2, ax3):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    buf = io.BytesIO()
    fig.savefig(buf, dpi=100, format="png")
    atomic_write_bytes(path, buf.getvalue())
    return path


def best_validation(hist: dict) -> dict | None:
    """Validation summary (accuracies in %) of the selected epoch, if any."""
    best = hist.get("best_epoch")
    for h in hist.get("history", []):
        if h.get("epoch") == best and h.get("val"):
            v = dict(h["val"])
            for k in ("class_acc", "rot_acc"):
                if k in v and v[k] is not None:
                    v[k] = 100.0 * v[k]
            return {"epoch": best, **v}
    return None
