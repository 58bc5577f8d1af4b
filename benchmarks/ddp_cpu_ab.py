#!/usr/bin/env python
"""Training throughput on CPU: one process with 2 threads (A, today's default) vs data-parallel
training over 2 gloo processes with 1 thread each (B), the same global batch.

B is ``helpers.training.train.train`` under torch.distributed exactly as ``helpers.study.cli.ddp_train`` runs it
(DistributedDataParallel, each process encodes its share of the 3B images and all-gathers the
features, so both compute the full B x 2B loss; gradients averaged): the same math as A up to
the order of float32 sums (tests/test_ddp.py). C, for context, is one process with one thread:
it says how well torch's intra-op threads use the second core.

Every variant runs in a freshly spawned process (B: two), on the same synthetic training set
(13 objects, random 64 px images, the real augmentation and batch builder), for ``--epochs``
epochs of ``--steps`` steps at batch 16 (48 images a step), dropout off so that the runs are
comparable weight for weight. Speed = images/s of each epoch as ``train`` measures it (the
first epoch is warm-up and dropped); A and B alternate ``--pairs`` times so that machine drift
hits both; the ratio is of medians. Loss trajectories (per-epoch mean loss) and final weights of
A and B are compared.

Run: ``.venv/bin/python benchmarks/ddp_cpu_ab.py`` (about 5 minutes on 2 cores; writes
``benchmarks/results/ddp_cpu_ab.json``). Needs a quiet machine: it is a wall-clock A/B.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SIZE = 64
GLOO_TIMEOUT = datetime.timedelta(minutes=10)  # a collective waiting longer than this raises instead of hanging


def _data(objects: int, refs: int, queries: int):
    from helpers.core.rotations import haar_uniform
    from helpers.core.views import ObjectViews

    def views(name, n, seed):
        rng = np.random.default_rng(seed)
        imgs = rng.integers(0, 255, (n, SIZE, SIZE, 3), dtype=np.uint8)
        return ObjectViews(name, imgs, haar_uniform(n, rng).astype(np.float32), kind="reference")

    names = [f"obj{i:02d}" for i in range(objects)]
    return ({n: views(n, refs, 100 + i) for i, n in enumerate(names)},
            {n: views(n, queries, 200 + i) for i, n in enumerate(names)})


def _cfg(args, threads: int):
    from helpers.core.configs import ModelConfig, TrainConfig

    return TrainConfig(epochs=args.epochs, steps_per_epoch=args.steps, batch_size=16, lr=1e-3, seed=3,
                       device="cpu", progress=False, num_threads=threads,
                       model=ModelConfig(image_size=SIZE, dropout=0.0),
                       precision="fp32")  # the A/B compares losses of the same math: no bf16 rounding


def _worker(rank: int, world: int, port: int, out: str, threads: int, args) -> None:
    import torch.distributed as dist

    from helpers.training.train import train

    refs, queries = _data(args.objects, args.refs, args.queries)
    if world > 1:
        dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=world,
                                timeout=GLOO_TIMEOUT)
    try:
        train(_cfg(args, threads), refs, queries, {}, {}, out, resume=False)
    finally:
        if world > 1:
            dist.destroy_process_group()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(world: int, threads: int, out: Path, args) -> dict:
    import torch
    import torch.multiprocessing as mp

    t0 = time.perf_counter()
    mp.start_processes(_worker, args=(world, _free_port(), str(out), threads, args), nprocs=world, join=True,
                       start_method="spawn")
    wall = time.perf_counter() - t0
    ck = torch.load(out / "last.pt", weights_only=True)
    hist = ck["history"]
    speeds = [h["images_per_s"] for h in hist]
    return {"processes": world, "threads_per_process": threads, "wall_s_with_startup": wall,
            "images_per_s_per_epoch": speeds, "images_per_s_median": statistics.median(speeds[1:]),
            "train_loss_per_epoch": [h["train_loss"] for h in hist], "global_step": ck["global_step"],
            "model": ck["model"]}


def _weight_diffs(a: dict, b: dict):
    """|a - b| of every weight of two state dicts, flattened into one tensor."""
    import torch

    return torch.cat([(a[k] - b[k]).abs().flatten() for k in a])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--epochs", type=int, default=4, help="epochs per run (the first is warm-up)")
    ap.add_argument("--steps", type=int, default=8, help="optimiser steps per epoch")
    ap.add_argument("--pairs", type=int, default=2, help="alternating A,B runs")
    ap.add_argument("--objects", type=int, default=13)
    ap.add_argument("--refs", type=int, default=64, help="references per object")
    ap.add_argument("--queries", type=int, default=32, help="training queries per object")
    ap.add_argument("--no-single-thread", action="store_true", help="skip C (1 process, 1 thread)")
    ap.add_argument("--out", default=str(HERE / "results" / "ddp_cpu_ab.json"))
    args = ap.parse_args(argv)
    if args.epochs < 2 or args.steps < 1 or args.pairs < 1:
        ap.error("--epochs >= 2, --steps >= 1 and --pairs >= 1 are needed (the first epoch is warm-up)")
    sys.path.insert(0, str(HERE))
    import torch
    from timing import log, source_hashes

    runs: dict[str, list[dict]] = {"A": [], "B": [], "C": []}
    plan = [("A", 1, 2), ("B", 2, 1)] * args.pairs + ([] if args.no_single_thread else [("C", 1, 1)])
    with tempfile.TemporaryDirectory(prefix="ddp_cpu_ab_") as tmp:
        for i, (name, world, threads) in enumerate(plan):
            r = _run(world, threads, Path(tmp) / f"{i}_{name}", args)
            log(f"{name}: {world} process(es) x {threads} thread(s): "
                f"{r['images_per_s_median']:.1f} images/s (epochs {[round(s, 1) for s in r['images_per_s_per_epoch']]})")
            runs[name].append(r)
    med = {k: statistics.median(r["images_per_s_median"] for r in v) for k, v in runs.items() if v}
    a, b = runs["A"][0], runs["B"][0]
    loss_diff = float(np.max(np.abs(np.subtract(a["train_loss_per_epoch"], b["train_loss_per_epoch"]))))
    w = _weight_diffs(a["model"], b["model"])
    same_seed_a = max((float(_weight_diffs(a["model"], r["model"]).max()) for r in runs["A"][1:]), default=0.0)
    res = {
        "what": " ".join(__doc__.split("\n\n")[0].split()),
        "setup": {"image_size": SIZE, "batch_size": 16, "images_per_step": 48, "epochs": args.epochs,
                  "steps_per_epoch": args.steps, "pairs": args.pairs, "objects": args.objects,
                  "refs_per_object": args.refs, "queries_per_object": args.queries, "dropout": 0.0,
                  "torch": torch.__version__, "cpu_count": os.cpu_count(),
                  "date": time.strftime("%Y-%m-%d %H:%M:%S"), "sources": source_hashes()},
        "runs": {k: [{kk: vv for kk, vv in r.items() if kk != "model"} for r in v] for k, v in runs.items()},
        "images_per_s_median": med,
        "ratio_B_over_A": med["B"] / med["A"],
        "ratio_A_over_C": med["A"] / med["C"] if "C" in med else None,
        "loss_per_epoch_max_abs_diff_A_vs_B": loss_diff,
        "weights_max_abs_diff_A_vs_B": float(w.max()), "weights_median_abs_diff_A_vs_B": float(w.median()),
        "weights_max_abs_diff_A_repeats": same_seed_a,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    from helpers.core.paths import portable_obj

    Path(args.out).write_text(json.dumps(portable_obj(res), indent=1) + "\n")
    log(f"B/A = {res['ratio_B_over_A']:.3f}; loss diff {loss_diff:.2e}; weights max diff {float(w.max()):.2e} "
        f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
