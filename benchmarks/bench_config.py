"""The sizes of one benchmark run (:class:`BenchConfig`, with the ``FULL`` and ``QUICK`` settings).

Below every benchmark module: ``bench.py`` and the ``bench_*.py`` sections import it, it imports none of them,
so the benchmarks have no import circle. Standard library only (see ``bench.py`` on spawned workers).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass
class BenchConfig:
    """All sizes of one benchmark run (``FULL``, ``QUICK`` or a tiny test setting)."""

    mode: str = "full"
    threads: int = 2
    # 1. rendering
    render_objects: int = 4
    render_refs_per_object: int = 128
    render_size: int = 128
    render_workers: tuple = (1, 2)
    render_repeats: int = 3
    render_warmup: int = 1
    inproc_renders: int = 128
    # 2./3./4. network
    sizes: tuple = (64, 128)
    train_queries: int = 16
    train_refs: int = 32
    train_steps: int = 5
    train_steps_large: int = 3  # at sizes >= 128 (a step takes ~8 s there)
    train_warmup: int = 1
    encode_batch: int = 64
    encode_repeats: int = 5
    encode_repeats_large: int = 3
    fusion_refs_q1: int = 4096
    fusion_q: int = 16
    fusion_refs_qmany: int = 512
    fusion_repeats: int = 3
    gemm_n: int = 2048
    gemm_repeats: int = 5
    # 2b. training step A (git 1c2d2ee) vs B (today), and data vs compute per step
    train_ab_size: int = 64
    train_ab_batch: int = 16  # queries per step: 3x as many images (query, positive, random reference)
    train_ab_steps: int = 3  # steps per timed block; the losses after them are compared A vs B
    train_ab_repeats: int = 5  # timed A,B pairs
    train_ab_warmup: int = 1  # untimed blocks per variant before the pairs
    train_ab_data_repeats: int = 10  # timed batch builds (data side)
    train_ab_preprocess_calls: int = 10  # preprocess calls per timing of the changed function alone
    train_ab_objects: int = 13  # synthetic training set for the data side
    train_ab_refs_per_object: int = 128
    train_ab_queries_per_object: int = 16
    train_ab_context: float = 1.5  # stored query side / crop side (as DataConfig.train_context)
    # 5. retrieval on synthetic features
    retr_size: int = 64
    retr_objects: int = 13
    retr_refs: tuple = (1000, 10_000)
    retr_fast_queries: int = 10
    retr_greedy_queries: int = 3
    retr_batch_queries: int = 32  # queries through the batched fast search (anchor stage shared)
    retr_query_batch: int = 16  # queries per batched anchor stage
    disk_margin_bytes: int = 2 * 1024 ** 3
    # 5b. fast vs greedy on a small real (rendered) set
    real_refs: int = 512
    real_queries: int = 3
    real_objects: int = 13
    real_workers: int = 2
    # 6. bf16 against float32 training (section ``precision``, opt-in)
    precision_repeats: int = 20  # timed training steps per precision
    precision_steps: int = 300  # optimiser steps of each of the two fidelity trainings
    precision_tiny_data: bool = False  # a few renders per object instead of the quick data (tests)
    # 7. where a training step's time goes (section ``train_profile``, opt-in)
    profile_steps: int = 10  # timed steps per size (after one untimed)
    profile_val_views: int = 24  # validation views per object (the quick preset's n_val_queries)
    profile_val_refs: int = 128  # validation references per object (the quick preset's val_refs)
    # contention control
    quiet_threshold: float = 0.2  # max fraction of all CPUs busy with OTHER processes
    retry_contended: int = 2  # re-run a contended repeat up to this many times
    wait_quiet_s: float = 0.0  # total budget for waiting until the machine is quiet
    seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


FULL = BenchConfig()
QUICK = BenchConfig(mode="quick", render_objects=2, render_refs_per_object=64, render_repeats=2, render_warmup=0,
                    inproc_renders=32, train_steps=3, train_steps_large=2, train_ab_steps=2, train_ab_repeats=2,
                    train_ab_data_repeats=5, train_ab_objects=4, encode_repeats=3,
                    encode_repeats_large=2, fusion_refs_q1=1024, fusion_refs_qmany=128, fusion_repeats=2,
                    gemm_repeats=3, retr_refs=(1000, 2000), retr_fast_queries=5, retr_greedy_queries=2,
                    retr_batch_queries=8, retr_query_batch=4,
                    real_refs=128, real_queries=1, precision_repeats=10, precision_steps=100)
