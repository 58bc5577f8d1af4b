"""Shared measurement core and the train / train_step / encode / fusion sections of bench_gpu.py.

The run's clock, ``Ctx``, the timing loop, the CUDA memory helpers and the npz
loader live here because every section uses them; the retrieval section is in
``gpu_retrieval.py`` and the CLI, budget watchdog and JSON in ``bench_gpu.py``.
Each section fills the dict it is given as it goes (so the watchdog can write
what it got done) and stops between timed runs at its cap. Only the standard
library and numpy are imported at module level.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

# The run's clock: set when bench_gpu.py imports this module at its top (after stdlib and numpy).
T_START = time.perf_counter()
NPZ_NAME = "gpu_data.npz"
RESERVE_S = 8.0  # kept back from the total budget for writing the JSON


def _log(msg: str) -> None:
    print(f"[bench_gpu {time.perf_counter() - T_START:6.1f}s] {msg}", flush=True)


# =========================================================================== data and helpers

def load_data(data_dir: Path) -> dict:
    """npz -> {"meta", "names", "refs", "train_q", "val_q", "clean_q"} (dicts of ObjectViews)."""
    from helpers.core.views import ObjectViews

    path = data_dir / NPZ_NAME if data_dir.is_dir() else data_dir
    z = np.load(path, allow_pickle=False)
    meta = json.loads(str(z["meta_json"]))
    names = [str(n) for n in z["names"]]
    kinds = meta.get("kinds", {})
    out: dict[str, Any] = {"meta": meta, "names": names, "path": str(path), "bytes": path.stat().st_size}
    for kind, attr in (("ref", "refs"), ("train", "train_q"), ("val", "val_q"), ("clean", "clean_q")):
        d = {}
        for n in names:
            if f"{kind}_images__{n}" not in z:
                continue
            sym = z[f"symmetries__{n}"] if f"symmetries__{n}" in z else None
            d[n] = ObjectViews(n, z[f"{kind}_images__{n}"], z[f"{kind}_rotations__{n}"],
                               z[f"{kind}_masks__{n}"] if f"{kind}_masks__{n}" in z else None,
                               kinds.get(kind, "reference" if kind in ("ref", "clean") else "query"), sym,
                               {"key": meta.get("render_keys", {}).get(f"{kind}/{n}")})
        out[attr] = d
    return out


def build_train_config(P: dict, device: str, epochs: int, steps_per_epoch: int, image_size: int):
    """TrainConfig of the notebook parameters ``P``, as notebook 02's configuration cell builds it
    (not imported from helpers.study.pipeline, which needs the render stack and pandas)."""
    from helpers.core.configs import AugmentConfig, ModelConfig, TrainConfig

    sc = P["scales"]
    scales = "global" if str(sc).strip().lower() == "global" else tuple(int(x) for x in str(sc).split(",") if x.strip())
    mc = ModelConfig(image_size=image_size, fusion=P["fusion"], scales=scales, local_norm=P["local_norm"],
                     norm_window=P["norm_window"])
    return TrainConfig(epochs=epochs, steps_per_epoch=steps_per_epoch, batch_size=P["batch_size"], lr=P["lr"],
                       lr_milestones=tuple(P["lr_milestones"]), lr_schedule=P["lr_schedule"],
                       warmup_steps=P["warmup_steps"], clean_steps=P["clean_steps"], random_ref=P["random_ref"],
                       weighted_loss=P["weighted_loss"], seed=P["seed"], device=device,
                       occlusion=P["train_occlusion"], augment=AugmentConfig(), val_every=P["val_every"],
                       model=mc, progress=False)


class Ctx:
    """Run-wide settings and the clock."""

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.device = args.device
        self.cuda = args.device.startswith("cuda")
        self.tiny = args.tiny
        self.deadline = T_START + args.budget_s

    def sync(self) -> None:
        if self.cuda:
            import torch

            torch.cuda.synchronize()

    def left(self) -> float:
        return self.deadline - RESERVE_S - time.perf_counter()


def timed_runs(ctx: Ctx, fn: Callable[[], Any], repeats: int, warmup: int, stop_at: float) -> dict:
    """Median of ``repeats`` timed calls after ``warmup`` untimed ones, synchronised; stops early at ``stop_at``."""
    for _ in range(warmup):
        fn()
        ctx.sync()
        if time.perf_counter() > stop_at:
            break
    secs = []
    for _ in range(repeats):
        if secs and time.perf_counter() + secs[-1] > stop_at:
            break
        ctx.sync()
        t0 = time.perf_counter()
        fn()
        ctx.sync()
        secs.append(time.perf_counter() - t0)
    if not secs:
        return {"median_s": None, "runs_s": [], "repeats_done": 0, "repeats_planned": repeats, "warmup": warmup,
                "cut_short": True}
    return {"median_s": statistics.median(secs), "min_s": min(secs), "max_s": max(secs), "runs_s": secs,
            "repeats_done": len(secs), "repeats_planned": repeats, "warmup": warmup,
            "cut_short": len(secs) < repeats}


def cuda_mem() -> dict | None:
    import torch

    if not torch.cuda.is_available():
        return None
    free, total = torch.cuda.mem_get_info()
    return {"free_bytes": free, "total_bytes": total, "allocated_bytes": torch.cuda.memory_allocated(),
            "max_allocated_bytes": torch.cuda.max_memory_allocated(), "reserved_bytes": torch.cuda.memory_reserved()}


def release_cuda() -> None:
    import gc

    import torch

    gc.collect()
    if torch.cuda.is_available():
        torch.cuda.empty_cache()



# =========================================================================== sections

def bench_train(ctx: Ctx, data: dict, P: dict, cap_s: float, out: dict) -> dict:
    """helpers.training.train.train on the real data, paper config, in epochs of --epoch-steps steps (resume between)."""
    import torch

    import helpers.training.train as ht

    stop_at = time.perf_counter() + cap_s
    a = ctx.args
    size = int(data["meta"]["data_config"]["image_size"])
    epoch_steps = min(a.epoch_steps, a.train_steps)
    n_epochs = max(1, a.train_steps // epoch_steps)
    seen = data["names"]
    refs, tq = {n: data["refs"][n] for n in seen}, {n: data["train_q"][n] for n in seen}
    clean = data.get("clean_q") or None
    plot_fn = ht.plot_history
    ht.plot_history = lambda history, path: Path(path)  # matplotlib may be absent; plotting is not training
    run_dir = Path(tempfile.mkdtemp(prefix="bench_gpu_train_"))
    out.update({
        "what": "helpers.training.train.train(cfg, refs, train_queries, {}, {}, run_dir, resume=True) called once per epoch "
                "with cfg.epochs = 1, 2, ...; validation off inside train(); checkpoints written each epoch as usual; "
                "plot_history replaced by a no-op",
        "image_size": size, "objects": seen, "n_refs_per_object": len(refs[seen[0]]),
        "n_train_queries_per_object": len(tq[seen[0]]), "train_query_side": int(tq[seen[0]].images.shape[1]),
        "steps_planned": n_epochs * epoch_steps, "steps_per_epoch": epoch_steps, "cap_s": cap_s,
        "calls": [], "cut_short": False})
    hist: list = []
    try:
        if ctx.cuda:
            torch.cuda.reset_peak_memory_stats()
        wall = 0.0
        for e in range(1, n_epochs + 1):
            if e > 1 and time.perf_counter() + out["calls"][-1]["wall_s"] > stop_at:
                out["cut_short"] = True
                break
            cfg = build_train_config(P, ctx.device, e, epoch_steps, size)
            t0 = time.perf_counter()
            res = ht.train(cfg, refs, tq, {}, {}, run_dir, resume=True,
                           clean_queries=clean if cfg.clean_steps else None)
            ctx.sync()
            dt = time.perf_counter() - t0
            wall += dt
            hist = res.history
            h = hist[-1]
            out["calls"].append({"epoch": e, "wall_s": dt, "epoch_seconds": h["seconds"],
                                 "images_per_s_epoch": h["images_per_s"], "train_loss": h["train_loss"],
                                 "global_step": h["global_step"]})
            _log(f"train epoch {e}/{n_epochs}: {h['seconds']:.1f} s in-loop, {dt:.1f} s call, "
                 f"{h['images_per_s']:.0f} img/s, loss {h['train_loss']:.4f}")
        out["train_config"] = cfg.to_dict()
        steps = hist[-1]["global_step"] if hist else 0
        per_step = 3 * cfg.batch_size
        loop_s = sum(h["seconds"] for h in hist)
        later_s = sum(h["seconds"] for h in hist[1:])
        out.update({
            "steps_done": steps, "epochs_done": len(hist), "seconds_wall": wall, "seconds_in_loop": loop_s,
            "images_per_step": per_step,
            "images_per_s": per_step * steps / wall if wall else None,
            "images_per_s_in_loop": per_step * steps / loop_s if loop_s else None,
            "images_per_s_in_loop_after_first_epoch": (per_step * epoch_steps * (len(hist) - 1) / later_s
                                                       if later_s else None),
            "loss_first_epoch": hist[0]["train_loss"] if hist else None,
            "loss_last_epoch": hist[-1]["train_loss"] if hist else None,
            "history": hist,
            "note": "images_per_s = 3 * batch * steps / wall seconds of the train() calls (data preparation, "
                    "augmentation, resume and checkpoint writes included); images_per_s_in_loop uses train()'s own "
                    "per-epoch seconds (batches + steps only). Loss is the mean over each epoch's steps "
                    "(train() records no per-step loss)."})
        if ctx.cuda:
            out["cuda_memory"] = cuda_mem()
        out["helpers_render_imported"] = "helpers.data.render" in sys.modules  # by the in-plane augmentation
        # One validate() call (not timed inside train): seen-object val queries vs the references
        # (all of them; 8 per object in --tiny).
        if data.get("val_q") and time.perf_counter() < stop_at:
            model, _ = ht.load_model(run_dir / "last.pt", device=ctx.device)
            vrefs = {n: r.subset(np.arange(min(len(r), 8))) for n, r in refs.items()} if ctx.tiny else refs
            t0 = time.perf_counter()
            val = ht.validate(model, vrefs, {n: data["val_q"][n] for n in seen}, ctx.device, 32)
            ctx.sync()
            val.pop("per_object", None)
            out["validate_once"] = {**val, "seconds": time.perf_counter() - t0,
                                    "n_val_queries": sum(len(data["val_q"][n]) for n in seen),
                                    "n_val_refs_per_object": len(vrefs[seen[0]]),
                                    "note": f"after {steps} steps: not a trained model, just the call on {ctx.device}"}
            del model
    finally:
        ht.plot_history = plot_fn
        shutil.rmtree(run_dir, ignore_errors=True)
    return out


def bench_train_step(ctx: Ctx, P: dict, cap_s: float, size: int, out: dict) -> dict:
    """Bare helpers.training.train.train_step on random images already on the device (pure compute rate)."""
    import torch

    from helpers.core.rotations import haar_uniform
    from helpers.net.model import OrientationNet
    from helpers.training.train import train_step

    stop_at = time.perf_counter() + cap_s
    a = ctx.args
    out.update({"what": "helpers.training.train.train_step: encode 3B images (B queries, B positives, B random "
                        "refs), B x 2B fusion scores with autograd, weighted infoNCE, backward, Adam",
                "image_size": size, "by_batch": {}, "cut_short": False})
    batches = [int(b) for b in a.train_step_batches.split(",") if b.strip()]
    for i, b in enumerate(batches):
        left = stop_at - time.perf_counter()
        if left <= 1:
            out["cut_short"] = True
            break
        cfg = build_train_config(P, ctx.device, 1, 1, size)
        torch.manual_seed(0)
        model = OrientationNet(cfg.model).to(ctx.device).train()
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
        rng = np.random.default_rng(0)
        gen = torch.Generator(device=ctx.device).manual_seed(0)
        images = torch.rand(3 * b, 3, size, size, generator=gen, device=ctx.device)
        q_obj = rng.integers(0, 9, b)
        r_obj = np.concatenate([q_obj, rng.integers(0, 9, b)])
        q_rot = haar_uniform(b, seed=1)
        r_rot = np.concatenate([q_rot, haar_uniform(b, seed=2)])
        losses: list[float] = []
        if ctx.cuda:
            torch.cuda.reset_peak_memory_stats()
        sub_stop = time.perf_counter() + left / (len(batches) - i)
        t = timed_runs(ctx, lambda: losses.append(train_step(model, opt, images, q_obj, q_rot, r_obj, r_rot,
                                                             cfg.tau, cfg.weighted_loss)),
                       a.train_step_repeats, a.train_step_warmup, sub_stop)
        ips = 3 * b / t["median_s"] if t["median_s"] else None
        out["by_batch"][str(b)] = {**t, "batch_queries": b, "images_per_step": 3 * b, "images_per_s": ips,
                                   "queries_per_s": b / t["median_s"] if t["median_s"] else None,
                                   "loss_first_last": [losses[0], losses[-1]] if losses else None,
                                   "cuda_memory": cuda_mem() if ctx.cuda else None}
        out["cut_short"] |= t["cut_short"]
        _log(f"train_step B={b}: {t['median_s'] if t['median_s'] else float('nan'):.4f} s, "
             f"{ips or float('nan'):.0f} img/s")
        del model, opt, images
        release_cuda()
    return out


def bench_encode(ctx: Ctx, data: dict, cap_s: float, size: int, out: dict) -> dict:
    """model.encode refs/s on real rendered references (repeated to fill the batch), eval + inference_mode."""
    import torch

    from helpers.core.configs import ModelConfig
    from helpers.net.model import OrientationNet, images_to_tensor

    stop_at = time.perf_counter() + cap_s
    a = ctx.args
    b = a.encode_batch
    pool = np.concatenate([data["refs"][n].images for n in data["names"]])
    imgs = pool[np.arange(b) % len(pool)]
    torch.manual_seed(0)
    model = OrientationNet(ModelConfig(image_size=size)).to(ctx.device).eval()
    x = images_to_tensor(imgs).to(ctx.device)

    def run():
        with torch.inference_mode():
            return model.encode(x)

    shape = tuple(run().shape)
    t = timed_runs(ctx, run, a.encode_repeats, a.encode_warmup, stop_at - min(5.0, cap_s / 4))
    out.update({"image_size": size, "batch": b, "distinct_images": int(min(b, len(pool))),
                "feature_shape": list(shape[1:]), **t,
                "refs_per_s": b / t["median_s"] if t["median_s"] else None,
                "note": "input already on the device as float32 (B,3,S,S); eval mode, inference_mode"})

    def run_h2d():
        with torch.inference_mode():
            return model.encode(images_to_tensor(imgs).to(ctx.device))

    if time.perf_counter() < stop_at - 1:
        t2 = timed_runs(ctx, run_h2d, max(2, a.encode_repeats // 2), 1, stop_at)
        out["with_host_conversion"] = {**t2, "refs_per_s": b / t2["median_s"] if t2["median_s"] else None,
                                       "note": "uint8 numpy -> images_to_tensor -> .to(device) inside each timed run"}
    out["cut_short"] = t["cut_short"]
    _log(f"encode B={b}: {out['refs_per_s'] or float('nan'):.0f} refs/s")
    del model, x
    release_cuda()
    return out



def bench_fusion(ctx: Ctx, cap_s: float, size: int, out: dict) -> dict:
    """model.score pair-scores/s with float16 references on the device; what-if: larger fusion blocks."""
    import torch

    import helpers.net.model as hm

    stop_at = time.perf_counter() + cap_s
    a = ctx.args
    dev = torch.device(ctx.device)
    torch.manual_seed(0)
    model = hm.OrientationNet(hm.ModelConfig(image_size=size)).to(dev).eval()
    c, length = model.cfg.channels, model.feature_length
    gen = torch.Generator(device=dev).manual_seed(3)
    pool = torch.randn(256, c, length, generator=gen, device=dev)
    pool = (pool / pool.norm(dim=1, keepdim=True)).half()
    qs = torch.randn(16, c, length, generator=gen, device=dev)
    qs = qs / qs.norm(dim=1, keepdim=True)
    shapes = [(1, a.fusion_refs_q1), (16, a.fusion_refs_q16)]
    variants: list[tuple[str, int | None]] = [("default", None)]
    if hasattr(hm, "_BLOCK_ELEMENTS"):
        variants += [("block_2^22", 2 ** 22), ("block_2^25", 2 ** 25)]
    out.update({"image_size": size, "C": c, "L": length, "reference_dtype": "float16",
                           "default_block_elements": getattr(hm, "_BLOCK_ELEMENTS", None),
                           "what": "model.score(q, r) under inference_mode, eval; r float16 on the device",
                           "what_if": "helpers.net.model._BLOCK_ELEMENTS (references per product block = it / (C*X)) "
                                      "set in this process only, restored afterwards; scores compared to default",
                           "variants": {}, "cut_short": False})
    ref_scores: dict[str, torch.Tensor] = {}
    orig = getattr(hm, "_BLOCK_ELEMENTS", None)
    try:
        for vi, (name, blk) in enumerate(variants):
            if blk is not None:
                hm._BLOCK_ELEMENTS = blk
            res = {}
            for nq, nr in shapes:
                if time.perf_counter() > stop_at - 1:
                    out["cut_short"] = True
                    break
                r = pool[torch.arange(nr, device=dev) % len(pool)]
                q = qs[:nq]

                def run():
                    with torch.inference_mode():
                        return model.score(q, r)

                s0 = run()
                ctx.sync()
                key = f"Q{nq}xR{nr}"
                diff = None
                if name == "default":
                    ref_scores[key] = s0
                elif key in ref_scores:
                    diff = float((s0 - ref_scores[key]).abs().max())
                n_left = (len(variants) - vi) * len(shapes)
                t = timed_runs(ctx, run, a.fusion_repeats, 0,
                               time.perf_counter() + max(0.5, (stop_at - time.perf_counter()) / n_left))
                rate = nq * nr / t["median_s"] if t["median_s"] else None
                res[key] = {**t, "Q": nq, "R": nr, "pair_scores_per_s": rate, "max_abs_diff_vs_default": diff}
                out["cut_short"] |= t["cut_short"]
                _log(f"fusion {name} {key}: {rate or float('nan'):.0f} pair-scores/s")
            out["variants"][name] = res
    finally:
        if orig is not None:
            hm._BLOCK_ELEMENTS = orig
    del model, pool
    release_cuda()
    return out

