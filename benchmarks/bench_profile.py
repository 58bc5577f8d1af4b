"""Section ``train_profile`` (opt-in: ``bench.py --sections train_profile``): where one training step's time goes.

Each step of ``helpers.training.train`` is split into its phases, timed one after another in this process on
batches the real batch builder makes from a synthetic set (as ``train_ab``): building the batch (data and
augmentation), the uint8 -> float tensor, encoding the 3B images (forward, under the precision ``"auto"``
picks), the B x 2B fusion scores, the loss (pair weights and weighted infoNCE), the backward pass and the optimiser
step. Validation (``helpers.training.validation.validate`` on held-out views against the references of all
objects) runs once per ``val_every`` epochs of ``steps_per_epoch`` steps, so its cost is also given per training
step at the zoo's recipe (400 steps per epoch, every epoch) and the quick preset's (40 per epoch, every second).
Each phase: the median over ``profile_steps`` steps after one untimed step, at every size of ``sizes``. Heavy
imports inside the function (see ``bench.py`` on spawned workers).
"""

from __future__ import annotations

import statistics
import time

from bench_config import BenchConfig
from bench_train import _model, synthetic_train_views

PHASES = ("batch", "to_tensor", "encode", "score", "loss", "backward", "optimizer")
#: (steps per epoch, validate every N epochs) of the recipes whose validation share is reported.
RECIPES = {"zoo": (400, 1), "quick": (40, 2)}


def _phases_of_step(model, opt, batcher, picks, rng, symmetry_aware: bool = False) -> dict[str, float]:
    """One training step, phase by phase (seconds)."""
    import torch

    from helpers.net.model import images_to_tensor
    from helpers.training.losses import pair_weights, weighted_info_nce

    t: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        t[name] = now - clock
        clock = now

    imgs, q_obj, q_rot, r_obj, r_rot = batcher.make(picks, rng)
    lap("batch")
    images = images_to_tensor(imgs)
    lap("to_tensor")
    b = len(q_obj)
    feats = model.encode(images)
    lap("encode")
    scores = model.score(feats[:b], feats[b:])
    lap("score")
    weights = pair_weights(q_obj, q_rot, r_obj, r_rot, batcher.symmetries if symmetry_aware else None)
    loss = weighted_info_nce(scores, torch.arange(b), weights, 0.1)
    lap("loss")
    opt.zero_grad(set_to_none=True)
    loss.backward()
    lap("backward")
    opt.step()
    lap("optimizer")
    return t


def _validation_seconds(model, refs, queries, n_views: int, n_refs: int) -> float:
    """Wall seconds of one ``validate`` call on ``n_views`` views and ``n_refs`` references per object."""
    from helpers.core.views import ObjectViews
    from helpers.training.validation import validate

    size = model.cfg.image_size
    vr = {n: ObjectViews(n, v.images[:n_refs], v.rotations[:n_refs]) for n, v in refs.items()}
    c = (queries[next(iter(queries))].images.shape[1] - size) // 2  # centre crops of the stored query side
    vq = {n: ObjectViews(n, v.images[:n_views, c:c + size, c:c + size], v.rotations[:n_views], kind="query")
          for n, v in queries.items()}
    t0 = time.perf_counter()
    validate(model, vr, vq, device="cpu")
    return time.perf_counter() - t0


def bench_train_profile(cfg: BenchConfig) -> dict:
    """Per phase, per size: median seconds per step and share of the step; validation per call and per step."""
    import numpy as np
    import torch

    from helpers.core.configs import AugmentConfig
    from helpers.core.precision import resolve_precision
    from helpers.training.batches import _Batcher, _order_stream

    precision = resolve_precision("auto", torch.device("cpu"))
    out: dict = {"precision": precision, "batch_queries": cfg.train_ab_batch, "steps": cfg.profile_steps,
                 "validation": {"views_per_object": cfg.profile_val_views, "refs_per_object": cfg.profile_val_refs,
                                "objects": cfg.train_ab_objects}, "sizes": {}}
    for size in cfg.sizes:
        refs, queries = synthetic_train_views(cfg.train_ab_objects, max(cfg.train_ab_refs_per_object,
                                                                        cfg.profile_val_refs),
                                              max(cfg.train_ab_queries_per_object, cfg.profile_val_views), size,
                                              cfg.train_ab_context, cfg.seed)
        batcher = _Batcher(sorted(refs), refs, queries, AugmentConfig(), size, "own")
        rng = np.random.default_rng(cfg.seed)
        b = cfg.train_ab_batch
        order = _order_stream(rng, len(batcher), (cfg.profile_steps + 1) * b)
        model = _model(size, cfg.seed).train()
        model.precision = precision
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)
        steps = [_phases_of_step(model, opt, batcher, order[i * b:(i + 1) * b], rng)
                 for i in range(cfg.profile_steps + 1)][1:]  # the first step warms up
        med = {p: statistics.median(s[p] for s in steps) for p in PHASES}
        total = sum(med.values())
        val_s = _validation_seconds(model, refs, queries, cfg.profile_val_views, cfg.profile_val_refs)
        out["sizes"][str(size)] = {
            "median_s": med, "step_s": total, "share": {p: med[p] / total for p in PHASES},
            "images_per_s": 3 * b / total,
            "not_encoder_share": 1.0 - (med["encode"] + med["backward"]) / total,
            "validation_s_per_call": val_s,
            "validation_share_per_step": {k: val_s / (spe * every) / (total + val_s / (spe * every))
                                          for k, (spe, every) in RECIPES.items()}}
    return out
