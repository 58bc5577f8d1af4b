#!/usr/bin/env python
"""Training throughput on CPU with glibc's default malloc (A) against the setting training uses,
freed memory kept in the process (B, :func:`helpers.core.allocator.keep_freed_memory`).

Every run is a freshly started Python process (the setting is process-wide and cannot be undone),
A with ``HELPERS_KEEP_FREED_MEMORY=0``; both train ``helpers.training.train.train`` on the same
synthetic training set (13 objects, random 64 px images, the real augmentation and batch builder)
for ``--epochs`` epochs of ``--steps`` steps at batch 16 (48 images a step), precision ``auto``.
Speed = images/s of each epoch as ``train`` measures it, the first epoch dropped as warm-up; the
process's minor page faults and kernel share of CPU time say where the time went. A and B
alternate ``--pairs`` times so that machine drift hits both; the ratio is of medians. The loss
trajectories must be equal: the allocator changes where memory lives, not the arithmetic.

Run: ``.venv/bin/python benchmarks/malloc_ab.py`` (about 6 minutes on 2 cores; writes
``benchmarks/results/malloc_ab.json``). Needs a quiet machine: it is a wall-clock A/B.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SIZE = 64


def _worker(args) -> None:
    """One training run in this process; prints a JSON line with its speeds, losses and fault counts."""
    from ddp_cpu_ab import _data

    from helpers.core.allocator import keep_freed_memory
    from helpers.core.configs import ModelConfig, TrainConfig
    from helpers.training.train import train

    refs, queries = _data(args.objects, args.refs, args.queries)
    cfg = TrainConfig(epochs=args.epochs, steps_per_epoch=args.steps, batch_size=16, lr=1e-3, seed=3,
                      device="cpu", progress=False, model=ModelConfig(image_size=SIZE, dropout=0.0))
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    result = train(cfg, refs, queries, {}, {}, args.worker, resume=False)
    r1, wall = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter() - t0
    hist = result.history
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    print(json.dumps({"allocator": keep_freed_memory(), "precision": hist[0]["precision"],
                      "images_per_s_per_epoch": [h["images_per_s"] for h in hist],
                      "images_per_s_median": statistics.median(h["images_per_s"] for h in hist[1:]),
                      "train_loss_per_epoch": [h["train_loss"] for h in hist],
                      "minor_faults_per_s": (r1.ru_minflt - r0.ru_minflt) / wall,
                      "kernel_share_of_cpu": (r1.ru_stime - r0.ru_stime) / cpu if cpu > 0 else None}))


def _run(variant: str, out: Path, args) -> dict:
    env = dict(os.environ, HELPERS_KEEP_FREED_MEMORY="0" if variant == "A" else "1")
    cmd = [sys.executable, __file__, "--worker", str(out), "--epochs", str(args.epochs), "--steps", str(args.steps),
           "--objects", str(args.objects), "--refs", str(args.refs), "--queries", str(args.queries)]
    # the timeout keeps a wedged run from hanging the benchmark silently
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False, timeout=3600)
    if done.returncode != 0:
        raise RuntimeError(f"malloc_ab: variant {variant} failed (exit {done.returncode}):\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--epochs", type=int, default=4, help="epochs per run (the first is warm-up)")
    ap.add_argument("--steps", type=int, default=12, help="optimiser steps per epoch")
    ap.add_argument("--pairs", type=int, default=2, help="alternating A,B runs")
    ap.add_argument("--objects", type=int, default=13)
    ap.add_argument("--refs", type=int, default=64, help="references per object")
    ap.add_argument("--queries", type=int, default=32, help="training queries per object")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)  # internal: one run into this folder
    ap.add_argument("--out", default=str(HERE / "results" / "malloc_ab.json"))
    args = ap.parse_args(argv)
    if args.epochs < 2 or args.steps < 1 or args.pairs < 1:
        ap.error("--epochs >= 2, --steps >= 1 and --pairs >= 1 are needed (the first epoch is warm-up)")
    sys.path.insert(0, str(HERE))
    if args.worker:
        _worker(args)
        return 0
    import torch
    from timing import log, source_hashes

    from helpers.core.precision import cpu_flags

    runs: dict[str, list[dict]] = {"A": [], "B": []}
    with tempfile.TemporaryDirectory(prefix="malloc_ab_") as tmp:
        for i, name in enumerate(["A", "B"] * args.pairs):
            r = _run(name, Path(tmp) / f"{i}_{name}", args)
            log(f"{name}: {r['images_per_s_median']:.1f} images/s, {r['minor_faults_per_s']:.0f} minor faults/s, "
                f"kernel {100 * (r['kernel_share_of_cpu'] or 0):.0f} % of CPU time")
            runs[name].append(r)
    med = {k: statistics.median(r["images_per_s_median"] for r in v) for k, v in runs.items()}
    loss_diff = float(np.max(np.abs(np.subtract(runs["A"][0]["train_loss_per_epoch"],
                                                runs["B"][0]["train_loss_per_epoch"]))))
    isa = sorted(cpu_flags() & {"avx2", "avx512f", "avx512_bf16", "amx_bf16"})
    res = {
        "what": " ".join(__doc__.split("\n\n")[0].split()),
        "setup": {"image_size": SIZE, "batch_size": 16, "images_per_step": 48, "epochs": args.epochs,
                  "steps_per_epoch": args.steps, "pairs": args.pairs, "objects": args.objects,
                  "torch": torch.__version__, "cpu_count": os.cpu_count(), "isa_flags": isa,
                  "precision": runs["B"][0]["precision"], "date": time.strftime("%Y-%m-%d %H:%M:%S"),
                  "sources": source_hashes()},
        "runs": runs,
        "images_per_s_median": med,
        "ratio_B_over_A": med["B"] / med["A"],
        "minor_faults_per_s_median": {k: statistics.median(r["minor_faults_per_s"] for r in v)
                                      for k, v in runs.items()},
        "max_epoch_loss_diff_A_B": loss_diff,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=2) + "\n")
    log(f"B/A = {res['ratio_B_over_A']:.2f} (A {med['A']:.1f}, B {med['B']:.1f} images/s); loss diff {loss_diff:.2e}; "
        f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
