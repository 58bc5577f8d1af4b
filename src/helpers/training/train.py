"""Training loop with resumable, deterministic checkpoints and seen-object validation.

One step: B training queries (over all training objects) are augmented; each
gets its positive (the reference of its object with the nearest rotation,
found *after* augmentation since in-plane rotation changes the label) and one
random reference of its OWN object (the authors' batch; ``random_ref="any"``
draws it from a random training object instead). The B queries and 2B
references are encoded together, scored into a (B, 2B) matrix and trained
with the (weighted) infoNCE of :mod:`helpers.training.losses`.

Model selection uses only held-out views of the *training* objects (never the
unseen test objects): each validation query is scored against a small set of
references of every training object.

Files in ``out_dir``: ``last.pt`` (everything needed to resume), ``best.pt``
(weights of the best validation epoch), ``history.json``, ``history.png``.
"""

from __future__ import annotations

import io
import json
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel
from tqdm.auto import tqdm

from ..core.configs import LATER_DEFAULTS, ModelConfig, TrainConfig
from ..core.device import resolve_device
from ..core.fileio import DamagedEntry, atomic_write_bytes, atomic_write_text
from ..core.views import ObjectViews
from ..net.model import OrientationNet, images_to_tensor
from .batches import _Batcher, _order_stream
from .distributed import barrier, distributed_world, sharded_encoder
from .losses import pair_weights, weighted_info_nce
from .validation import plot_history, selection_metric, validate

# Fields that may change between an interrupted run and its resumption
# without changing the trajectory of the weights.
# precision: a run resumed on a machine without native bf16 goes on in float32 (each history entry
# records the precision its epoch used).
_RESUMABLE_CHANGES = {"epochs", "device", "num_threads", "val_every", "progress", "val_batch_size", "precision"}


@dataclass
class TrainResult:
    """Outcome of :func:`train`.

    Attributes:
        best_path: best.pt (best validation ``select_on`` metric; the last epoch if no
            validation data was given).
        last_path: last.pt.
        history: per-epoch dicts (see :func:`train`).
        train_images_per_s: images encoded per second (forward + backward +
            optimiser step, data preparation included), mean over the epochs
            run in this call (NaN if none ran).
    """

    best_path: Path
    last_path: Path
    history: list[dict]
    train_images_per_s: float


# --------------------------------------------------------------------------- helpers

def _atomic_torch_save(obj, path: Path) -> None:
    """torch.save through a temporary file; a failed write (full disk) leaves ``path`` as it was."""
    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write_bytes(path, buf.getvalue())


def _check_views(views: dict[str, ObjectViews], what: str, size: int, context_ok: bool = False) -> None:
    """Images must be size x size (or, for training queries with ``context_ok``, square and
    larger: the crop with context around it)."""
    for name, v in views.items():
        if not isinstance(v, ObjectViews):
            raise ValueError(f"{what}[{name!r}]: expected ObjectViews, got {type(v).__name__}")
        if not len(v):
            continue
        h, w = v.images.shape[1:3]
        if (h, w) != (size, size) and not (context_ok and h == w and h > size):
            raise ValueError(f"{what}[{name!r}]: images are {h}x{w}, model expects {size}x{size}"
                             f"{' (or a larger square with context)' if context_ok else ''}")


def train_step(model: OrientationNet, optimizer: torch.optim.Optimizer, images: torch.Tensor,
               q_obj, q_rot, r_obj, r_rot, tau: float = 0.1, weighted: bool = True, encode=None,
               symmetries=None) -> float:
    """One optimiser step on a prepared batch; returns the loss.

    Args:
        images: (3B, 3, S, S) float in [0, 1]: B queries then their B
            positives then B random references.
        q_obj, q_rot, r_obj, r_rot: labels for :func:`helpers.training.losses.pair_weights`
            ((B,), (B,3,3), (2B,), (2B,3,3)).
        encode: images -> features of all 3B images (default ``model.encode``; the
            distributed run encodes its shard and gathers, see :func:`sharded_encoder`).
        symmetries: per object id, the groups of a symmetry-aware run (:func:`pair_weights`), else None.
    """
    b = len(q_obj)
    feats = (encode or model.encode)(images)
    scores = model.score(feats[:b], feats[b:])  # (B, 2B); column i is query i's positive
    weights = pair_weights(q_obj, q_rot, r_obj, r_rot, symmetries).to(scores.device) if weighted else None
    loss = weighted_info_nce(scores, torch.arange(b, device=scores.device), weights, tau)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    return float(loss.detach())


def lr_factor(cfg: TrainConfig, steps_per_epoch: int):
    """Multiplier of ``cfg.lr`` as a function of the optimiser step (0-based): linear
    warm-up over ``warmup_steps``, then milestones (per epoch) or a cosine to 0."""
    total = max(1, cfg.epochs * steps_per_epoch)
    milestones = list(cfg.lr_milestones)

    def f(step: int) -> float:
        warm = min(1.0, (step + 1) / cfg.warmup_steps) if cfg.warmup_steps else 1.0
        if cfg.lr_schedule == "cosine":
            return warm * 0.5 * (1.0 + math.cos(math.pi * min(step, total) / total))
        epoch = step // steps_per_epoch
        return warm * cfg.lr_gamma ** sum(epoch >= m for m in milestones)

    return f


def _rng_state() -> dict:
    state = {"torch": torch.get_rng_state()}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def _set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"].cpu())
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all([s.cpu() for s in state["cuda"]])


# ----------------------------------------------------------------------------- train

@dataclass
class _Run:
    """The state of one training run between its steps (what ``last.pt`` saves)."""

    model: OrientationNet
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LambdaLR
    rng: np.random.Generator
    batcher: _Batcher
    steps: int
    device: torch.device
    rank: int = 0
    world: int = 1
    encode: Any = None
    history: list[dict] = field(default_factory=list)
    start_epoch: int = 0
    global_step: int = 0
    best_metric: float = -math.inf
    best_epoch: int | None = None


def train(cfg: TrainConfig, train_refs: dict[str, ObjectViews], train_queries: dict[str, ObjectViews],
          val_refs: dict[str, ObjectViews], val_queries: dict[str, ObjectViews], out_dir: Path,
          resume: bool = True, clean_queries: dict[str, ObjectViews] | None = None) -> TrainResult:
    """Train (or resume training) and return checkpoint paths and history.

    Args:
        cfg: training configuration (embeds the model configuration).
        train_refs: training object name -> references (N, S, S, 3) uint8;
            all training objects, the pool of positives and random references.
        train_queries: name -> training queries (a subset of the objects above).
        val_refs: name -> a small subset of references per training object
            (cover every training object: validation classifies among them).
        val_queries: name -> held-out views of training objects (not in
            train_queries). Empty dicts skip validation.
        out_dir: where checkpoints and history go (created).
        resume: continue from ``out_dir/last.pt`` when it exists; the result
            is identical to an uninterrupted run with the same seed (CPU).
        clean_queries: name -> clean renders (reference style) of training objects at
            rotations other than the references', for the ``clean_steps`` curriculum.

    History entries: epoch (1-based), global_step, lr, train_loss, seconds,
    images_per_s, cpu_share (process CPU seconds / (seconds x torch threads): about 1
    on cores of its own, lower when shared or paused), precision, val (None or
    validate() summary without per_object).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = cfg.resolved()
    names = _check_inputs(cfg, train_refs, train_queries, val_refs, val_queries)
    do_val = any(len(v) for v in val_queries.values())
    old_threads = torch.get_num_threads()
    if cfg.num_threads is not None:
        torch.set_num_threads(cfg.num_threads)
    try:
        run = _setup(cfg, names, train_refs, train_queries, clean_queries)
        if resume and (out_dir / "last.pt").exists():
            _resume(run, cfg, out_dir / "last.pt")
        speeds = []
        for epoch in range(run.start_epoch, cfg.epochs):
            lr = run.optimizer.param_groups[0]["lr"]
            cpu0 = time.process_time()
            losses, seconds = _train_epoch(run, cfg, epoch)
            # CPU seconds of this process per wall second per thread: about 1 when the epoch had the
            # threads' cores to itself, lower when it shared them or was paused (its speed is then not the machine's)
            cpu_share = (time.process_time() - cpu0) / (seconds * torch.get_num_threads())
            speeds.append(run.steps * 3 * cfg.batch_size / seconds)
            if run.rank > 0:  # only the first process validates and writes; the others wait for its files
                run.history.append({"epoch": epoch + 1, "global_step": run.global_step})
                barrier()
                continue
            val = None
            if do_val and ((epoch + 1) % cfg.val_every == 0 or epoch + 1 == cfg.epochs):
                val = validate(run.model, val_refs, val_queries, run.device, cfg.val_batch_size)
                val.pop("per_object")
            run.history.append({"epoch": epoch + 1, "global_step": run.global_step, "lr": float(lr),
                                "train_loss": float(np.mean(losses)), "seconds": float(seconds),
                                "images_per_s": float(speeds[-1]), "cpu_share": round(cpu_share, 3),
                                "precision": cfg.precision, "val": val})
            _save_epoch(run, cfg, epoch, val, do_val, out_dir)
        if run.rank == 0 and run.history:
            plot_history(run.history, out_dir / "history.png")
        return TrainResult(out_dir / "best.pt", out_dir / "last.pt", run.history,
                           float(np.mean(speeds)) if speeds else float("nan"))
    finally:
        torch.set_num_threads(old_threads)


def _check_inputs(cfg: TrainConfig, train_refs: dict[str, ObjectViews], train_queries: dict[str, ObjectViews],
                  val_refs: dict[str, ObjectViews], val_queries: dict[str, ObjectViews]) -> list[str]:
    """The training objects' names, sorted, after checking that the views fit together (ValueError naming
    the argument otherwise): queries and validation use training objects only, images fit the model."""
    names = sorted(train_refs)
    if not names:
        raise ValueError("train_refs: expected at least one training object")
    if not set(train_queries) <= set(names):
        raise ValueError(f"train_queries: objects {sorted(set(train_queries) - set(names))} have no references")
    if not set(val_refs) <= set(names) or not set(val_queries) <= set(names):
        raise ValueError("val_refs/val_queries: validation must use training (seen) objects only, got "
                         f"{sorted((set(val_refs) | set(val_queries)) - set(names))}")
    if not set(val_queries) <= set(val_refs):
        raise ValueError(f"val_queries: objects {sorted(set(val_queries) - set(val_refs))} have no "
                         "validation references in val_refs")
    for views, what in ((train_refs, "train_refs"), (train_queries, "train_queries"),
                        (val_refs, "val_refs"), (val_queries, "val_queries")):
        _check_views(views, what, cfg.model.image_size, context_ok=what == "train_queries")
    if any(len(train_refs[n]) == 0 for n in names):
        raise ValueError("train_refs: every training object needs at least one reference")
    return names


def _setup(cfg: TrainConfig, names: list[str], train_refs: dict[str, ObjectViews],
           train_queries: dict[str, ObjectViews], clean_queries: dict[str, ObjectViews] | None) -> _Run:
    """Batches, the network (seeded), data parallelism when launched with several processes, Adam and the
    learning-rate schedule. The order of the random draws is part of the run's identity: keep it."""
    aug = replace(cfg.augment, occlusion=cfg.augment.occlusion or cfg.occlusion)
    if cfg.clean_steps and not clean_queries:
        raise ValueError("TrainConfig.clean_steps > 0 needs clean_queries (clean renders of the training objects)")
    batcher = _Batcher(names, train_refs, train_queries, aug, cfg.model.image_size, cfg.random_ref, clean_queries,
                       cfg.symmetry_aware)
    if len(batcher) == 0:
        raise ValueError("train_queries: expected at least one training query")
    steps = cfg.steps_per_epoch or math.ceil(len(batcher) / cfg.batch_size)
    rank, world = distributed_world()
    if world > 1 and (3 * cfg.batch_size) % world:
        raise ValueError(f"TrainConfig.batch_size: 3 x {cfg.batch_size} images per step do not split evenly "
                         f"over {world} processes")
    device = resolve_device(cfg.device)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    model = OrientationNet(cfg.model).to(device)
    model.precision = cfg.precision
    encode = None
    if world > 1:  # every process holds the same weights; gradients are averaged by DDP
        net = DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)
        encode = sharded_encoder(net, rank, world)
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lr_factor(cfg, steps))
    return _Run(model, optimizer, scheduler, rng, batcher, steps, device, rank, world, encode)


def _resume(run: _Run, cfg: TrainConfig, last_path: Path) -> None:
    """Continue from ``last.pt``: weights, optimiser, schedule, history, best epoch and both random streams."""
    ck = read_checkpoint(last_path, run.device)
    old, new = {**LATER_DEFAULTS, **ck["config"]}, cfg.to_dict()
    diff = sorted(k for k in new if k not in _RESUMABLE_CHANGES and old.get(k) != new[k])
    if diff:
        raise ValueError(f"resume: {last_path} was trained with a different config "
                         f"(fields {diff}); use resume=False or another out_dir")
    run.model.load_state_dict(ck["model"])
    run.optimizer.load_state_dict(ck["optimizer"])
    run.scheduler.load_state_dict(ck["scheduler"])
    run.start_epoch, run.global_step = ck["epoch"], ck["global_step"]
    run.history = list(ck["history"])
    run.best_metric, run.best_epoch = ck["best_metric"], ck["best_epoch"]
    run.rng.bit_generator.state = ck["numpy_rng"]
    _set_rng_state(ck["rng"])


def _train_epoch(run: _Run, cfg: TrainConfig, epoch: int) -> tuple[list[float], float]:
    """One epoch of ``run.steps`` optimiser steps; returns (losses, wall seconds)."""
    run.model.train()
    order = _order_stream(run.rng, len(run.batcher), run.steps * cfg.batch_size)
    losses = []
    t0 = time.perf_counter()
    bar = tqdm(range(run.steps), desc=f"epoch {epoch + 1}/{cfg.epochs}", disable=not cfg.progress or run.rank > 0,
               leave=False)
    for step in bar:
        picks = order[step * cfg.batch_size:(step + 1) * cfg.batch_size]
        # clean-to-real curriculum: P(clean render) falls from 1 to 0 over clean_steps
        p_clean = max(0.0, 1.0 - run.global_step / cfg.clean_steps) if cfg.clean_steps else 0.0
        imgs, q_obj, q_rot, r_obj, r_rot = run.batcher.make(picks, run.rng, p_clean)
        loss = train_step(run.model, run.optimizer, images_to_tensor(imgs).to(run.device),
                          q_obj, q_rot, r_obj, r_rot, cfg.tau, cfg.weighted_loss, run.encode,
                          run.batcher.symmetries if cfg.symmetry_aware else None)
        if not math.isfinite(loss):
            raise FloatingPointError(f"non-finite training loss at epoch {epoch + 1}, step {step}")
        losses.append(loss)
        run.scheduler.step()
        run.global_step += 1
        bar.set_postfix(loss=f"{loss:.4f}")
    return losses, time.perf_counter() - t0


def _save_epoch(run: _Run, cfg: TrainConfig, epoch: int, val: dict | None, do_val: bool, out_dir: Path) -> None:
    """Model selection (``select_on`` on held-out views of seen objects) and this epoch's files:
    best.pt when it improved, then last.pt and history.json."""
    metric = None if val is None else selection_metric(val, cfg.select_on)
    if (metric is not None and metric >= run.best_metric) or not do_val:
        run.best_metric = metric if metric is not None else run.best_metric
        run.best_epoch = epoch + 1
        # best.pt first: if we die before last.pt, the resumed run redoes this epoch.
        _atomic_torch_save({"model": run.model.state_dict(), "model_config": cfg.model.to_dict(),
                            "config": cfg.to_dict(), "epoch": epoch + 1, "val": val,
                            "history": run.history}, out_dir / "best.pt")
    _atomic_torch_save({"model": run.model.state_dict(), "optimizer": run.optimizer.state_dict(),
                        "scheduler": run.scheduler.state_dict(), "epoch": epoch + 1,
                        "global_step": run.global_step, "rng": _rng_state(),
                        "numpy_rng": run.rng.bit_generator.state, "config": cfg.to_dict(),
                        "model_config": cfg.model.to_dict(), "history": run.history,
                        "best_metric": run.best_metric, "best_epoch": run.best_epoch}, out_dir / "last.pt")
    atomic_write_text(out_dir / "history.json",
                      json.dumps({"best_epoch": run.best_epoch, "history": run.history}, indent=1))
    if run.world > 1:
        barrier()


def read_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> dict:
    """torch.load of a checkpoint; an unreadable file is a :class:`DamagedEntry` that names it."""
    path = Path(path)
    try:
        return torch.load(path, map_location=device, weights_only=True)
    except FileNotFoundError:
        raise
    except (RuntimeError, EOFError, OSError, ValueError) as e:  # torch's zip reader, a truncated pickle
        raise DamagedEntry(f"{path}: unreadable checkpoint ({str(e).splitlines()[0][:200]}); delete the run "
                           f"folder {path.parent} (or `python -m helpers.study.cli.cache prune`) and rerun to retrain") from None


def load_model(path: str | Path, device: str | torch.device = "auto") -> tuple[OrientationNet, dict]:
    """Rebuild the network from a checkpoint's embedded config; returns (model in eval mode, checkpoint)."""
    device = resolve_device(device)
    ck = read_checkpoint(path, device)
    model = OrientationNet(ModelConfig.from_dict(ck["model_config"]))
    model.load_state_dict(ck["model"])
    return model.to(device).eval(), ck
