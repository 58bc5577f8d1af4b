"""Section ``precision`` (opt-in: ``bench.py --sections precision``): bf16 autocast (B) against float32 (A) for
training, in one run on one machine.

1. Speed: the real training step (``helpers.training.train.train_step``: encode 3B images, B x 2B fusion
   scores, weighted infoNCE, backward, Adam) at 64 px, A and B interleaved, median of
   ``precision_repeats`` timings each; images/s and the ratio B/A.
2. Fidelity: split #1's model trained twice on the quick benchmark's data (same seed, same
   batches), once per precision, ``precision_steps`` optimiser steps with the quick recipe (cosine),
   validated on held-out views of SEEN objects (256 references per object). The verdict uses
   tolerances fixed before the run: per-epoch training loss within ``LOSS_TOL`` and final
   validation Class./Rota. Acc. within ``VAL_TOL_POINTS`` (about 1.5 binomial standard errors of
   the 216 validation queries at 50 %).

The CPU's bf16 support is detected and recorded; on a CPU without native bf16 the ratio shows the slowdown that
makes ``precision="auto"`` pick fp32. About 15 min on 2 cores with native bf16 (``FULL``). Heavy imports inside
the functions (see ``bench.py`` on spawned workers).
"""

from __future__ import annotations

import statistics
import time

from bench_config import BenchConfig

LOSS_TOL = 0.10
VAL_TOL_POINTS = 5.0


def speed(repeats: int, batch: int = 16, size: int = 64) -> dict:
    """Interleaved A/B of one training step on random images; images/s per precision."""
    import numpy as np
    import torch

    from helpers.core.configs import ModelConfig
    from helpers.core.rotations import haar_uniform
    from helpers.net.model import OrientationNet
    from helpers.training.train import train_step

    torch.manual_seed(0)
    model = OrientationNet(ModelConfig(image_size=size)).train()
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    rng = np.random.default_rng(0)
    images = torch.rand(3 * batch, 3, size, size, generator=torch.Generator().manual_seed(0))
    q_obj = rng.integers(0, 9, batch)
    r_obj = np.concatenate([q_obj, q_obj])
    q_rot = haar_uniform(batch, seed=0)
    r_rot = np.concatenate([q_rot, haar_uniform(batch, seed=1)])
    times: dict[str, list[float]] = {"fp32": [], "bf16": []}
    for i in range(repeats + 1):  # the first round warms up both
        for p in ("fp32", "bf16"):
            model.precision = p
            t0 = time.perf_counter()
            train_step(model, opt, images, q_obj, q_rot, r_obj, r_rot)
            if i:
                times[p].append(time.perf_counter() - t0)
    ips = {p: 3 * batch / statistics.median(t) for p, t in times.items()}
    return {"image_size": size, "images_per_step": 3 * batch, "repeats": repeats,
            "median_s": {p: statistics.median(t) for p, t in times.items()},
            "images_per_s": ips, "ratio_bf16_over_fp32": ips["bf16"] / ips["fp32"]}


def fidelity(steps: int, tiny: bool) -> dict:
    """Two trainings of split #1 (fp32, bf16): per-epoch loss, validation, images/s, and the verdict."""
    from helpers.core.configs import AugmentConfig, DataConfig, ModelConfig, TrainConfig
    from helpers.study.pipeline import prepare_data, train_or_load

    if tiny:
        dcfg = DataConfig(render_size=64, n_references=8, n_train_queries=4, n_val_queries=2, n_test_queries=1,
                          workers=0)
        per_epoch, val_refs = max(1, steps // 2), 6
    else:
        dcfg = DataConfig(n_references=512, n_train_queries=160, n_val_queries=24, n_test_queries=100)
        per_epoch, val_refs = 50, 256
    from helpers.data.manifest import load_manifest

    data = prepare_data(dcfg, objects=load_manifest().seen_objects(1), occluded=False, test=False)
    epochs = max(1, steps // per_epoch)
    runs = {}
    for p in ("fp32", "bf16"):
        cfg = TrainConfig(epochs=epochs, steps_per_epoch=per_epoch, batch_size=2 if tiny else 16, lr=1e-3,
                          lr_schedule="cosine", warmup_steps=25, clean_steps=80, val_every=2, seed=0,
                          precision=p, model=ModelConfig(image_size=64), augment=AugmentConfig())
        _, run, info = train_or_load(1, cfg, data, val_refs_per_object=val_refs)
        hist = info["history"]["history"]
        runs[p] = {"run": run.name, "loss": [h["train_loss"] for h in hist],
                   "images_per_s": statistics.median(h["images_per_s"] for h in hist),
                   "val": [None if not h["val"] else {k: 100 * h["val"][k] for k in ("class_acc", "rot_acc")}
                           for h in hist]}
    a, b = runs["fp32"], runs["bf16"]
    loss_diff = max(abs(x - y) for x, y in zip(a["loss"], b["loss"]))
    val_diff = {k: b["val"][-1][k] - a["val"][-1][k] for k in ("class_acc", "rot_acc")}
    return {"steps": epochs * per_epoch, "val_refs_per_object": val_refs, "runs": runs,
            "max_epoch_loss_diff": loss_diff, "final_val_diff_points": val_diff,
            "tolerance": {"loss": LOSS_TOL, "val_points": VAL_TOL_POINTS},
            "within_tolerance": bool(loss_diff <= LOSS_TOL and all(abs(v) <= VAL_TOL_POINTS
                                                                   for v in val_diff.values()))}


def bench_precision(cfg: BenchConfig) -> dict:
    """Both parts of the A/B with the run's sizes, the CPU's bf16 support and what ``precision="auto"`` picks."""
    import torch

    from helpers.core.precision import describe, resolve_precision

    cpu = torch.device("cpu")
    return {"cpu": describe(cpu), "auto_picks": resolve_precision("auto", cpu),
            "speed": speed(cfg.precision_repeats, batch=cfg.train_ab_batch),
            "fidelity": fidelity(cfg.precision_steps, cfg.precision_tiny_data)}
