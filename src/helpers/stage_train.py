"""Stage 2: train one model on the seen objects of a split (or load it) and report."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .fileio import atomic_write_json
from .study import DataConfig, StudyData, evaluate, prepare_data, reference_bank, summary_row, train_or_load
from .tables import write_table


def parse_scales(scales: str) -> tuple[int, ...] | str:
    """``"global"`` or a comma list of decoder levels such as ``"32,16,13"``."""
    s = scales.strip().lower()
    if s == "global":
        return "global"
    try:
        out = tuple(int(x) for x in s.split(",") if x.strip())
    except ValueError:
        raise ValueError(f"scales: expected 'global' or a comma list of 32/16/13, got {scales!r}") from None
    if not out or any(x not in (32, 16, 13) for x in out):
        raise ValueError(f"scales: expected 'global' or a comma list of 32/16/13, got {scales!r}")
    return out


def data_config(P: dict[str, Any]) -> DataConfig:
    """DataConfig from notebook parameters (names shared by every notebook)."""
    return DataConfig(image_size=P["image_size"], render_size=P["render_size"], n_references=P["n_references"],
                      n_train_queries=P["n_train_queries"], n_val_queries=P["n_val_queries"],
                      n_test_queries=P["n_test_queries"], query_style=P["query_style"],
                      train_context=P["train_context"], seed=P["seed"], workers=P["workers"],
                      cache_dir=P["cache_dir"])


def train_config(P: dict[str, Any], fusion: str | None = None, scales: str | None = None,
                 local_norm: bool | None = None, weighted_loss: bool | None = None, epochs: int | None = None):
    """TrainConfig (with its ModelConfig) from notebook parameters, with optional overrides
    for ablation variants."""
    from .augment import AugmentConfig
    from .model import ModelConfig
    from .train import TrainConfig

    mc = ModelConfig(image_size=P["image_size"], fusion=fusion or P["fusion"],
                     scales=parse_scales(scales or P["scales"]),
                     local_norm=P["local_norm"] if local_norm is None else local_norm,
                     norm_window=P["norm_window"])
    return TrainConfig(epochs=epochs or P["epochs"], steps_per_epoch=P["steps_per_epoch"] or None,
                       batch_size=P["batch_size"], lr=P["lr"], lr_milestones=tuple(P["lr_milestones"]),
                       lr_schedule=P["lr_schedule"], warmup_steps=P["warmup_steps"], clean_steps=P["clean_steps"],
                       random_ref=P["random_ref"],
                       weighted_loss=P["weighted_loss"] if weighted_loss is None else weighted_loss,
                       seed=P["seed"], device=P["device"], occlusion=P["train_occlusion"], augment=AugmentConfig(),
                       val_every=P["val_every"], model=mc)


def train_model(P: dict[str, Any], data: StudyData, split: int | None = None, **overrides: Any):
    """:func:`helpers.study.train_or_load` with the notebook's training parameters.

    ``split`` defaults to ``P["split"]``; ``overrides`` go to :func:`train_config`
    (ablation variants). Validation uses ``P["val_refs"]`` references per seen object.
    Returns (model, run folder, info) like ``train_or_load``.
    """
    if P["val_refs"] < 1:
        raise ValueError(f"val_refs: expected a positive number of references per seen object, got {P['val_refs']}")
    return train_or_load(P["split"] if split is None else split, train_config(P, **overrides), data,
                         val_refs_per_object=P["val_refs"])


def chance_levels(n_objects: int, threshold_deg: float = 30.0) -> dict[str, float]:
    """Accuracy (%) of guessing: class uniformly, rotation Haar-uniformly.

    P(angle < t) for a Haar rotation is (t - sin t) / pi.
    """
    t = np.radians(threshold_deg)
    p_rot = (t - np.sin(t)) / np.pi
    return {"class_acc": 100.0 / n_objects, "rot_acc": 100.0 * p_rot / n_objects}


def run_train_stage(P: dict[str, Any], out_dir: Path, data: StudyData | None = None) -> dict[str, Any]:
    """Train-or-load the split's model, plot its history, and check it on unseen objects.

    Writes into ``out_dir``: history.json, loss.png, unseen_per_object.csv/.md,
    train_metrics.json. Returns the metrics dict.
    """
    from .model import count_parameters
    from .train import plot_history

    data = data or prepare_data(data_config(P))
    cfg = train_config(P)
    model, run, info = train_model(P, data)
    hist = info.get("history", {}) or {}
    atomic_write_json(out_dir / "history.json", hist)
    plot_history(hist.get("history", []), out_dir / "loss.png")
    m = data.manifest
    bench = m.object_names("train")
    unseen = m.split_objects(P["split"])
    bank = reference_bank(model, data, bench, device=P["device"])
    res = evaluate(model, bank, {n: data.test_q[n] for n in unseen}, method="greedy", device=P["device"])
    write_table(res["per_object"].reset_index(), out_dir / "unseen_per_object")
    metrics = {
        "split": P["split"], "run_dir": str(run), "checkpoint": str(run / "best.pt"),
        "parameters": count_parameters(model), "train_images_per_s": info.get("train_images_per_s"),
        "train_seconds": info.get("seconds_this_session"),
        "best_val": _best_val(hist), "selection": cfg.select_on, "unseen_test": summary_row(f"split {P['split']} unseen", res),
        "chance": chance_levels(len(bench)), "bank": {"objects": bench, "refs_per_object": bank.n_refs},
    }
    atomic_write_json(out_dir / "train_metrics.json", metrics)
    return metrics


def _best_val(hist: dict) -> dict | None:
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
