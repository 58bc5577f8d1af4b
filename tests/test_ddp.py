"""Data-parallel training (DistributedDataParallel, 2 gloo processes on CPU) equals one process."""

from __future__ import annotations

import socket

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp

from helpers.core.configs import ModelConfig, TrainConfig
from helpers.core.rotations import haar_uniform
from helpers.core.views import ObjectViews
from helpers.training.train import train

SIZE = 64
TOL = 1e-5  # float32 sums in another order (gathered shares, averaged gradients)


def _views(name: str, n: int, seed: int) -> ObjectViews:
    rng = np.random.default_rng(seed)
    imgs = rng.integers(0, 255, (n, SIZE, SIZE, 3), dtype=np.uint8)
    return ObjectViews(name, imgs, haar_uniform(n, rng).astype(np.float32), kind="reference")


def _data():
    names = ["aa", "bb"]
    refs = {n: _views(n, 16, 10 + i) for i, n in enumerate(names)}
    queries = {n: _views(n, 6, 20 + i) for i, n in enumerate(names)}
    return refs, queries


def _cfg() -> TrainConfig:
    # Dropout off: its masks come from each process's own generator, so with dropout the two runs are
    # equal in distribution only. float32: bf16 rounding depends on each process's batch shape, and this
    # test checks that the distributed math equals the single-process math.
    return TrainConfig(epochs=2, steps_per_epoch=2, batch_size=2, lr=1e-3, seed=5, device="cpu", progress=False,
                       num_threads=1, model=ModelConfig(image_size=SIZE, channels=16, dropout=0.0),
                       precision="fp32")


def _worker(rank: int, world: int, port: int, out: str) -> None:
    import torch.distributed as dist

    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=world)
    try:
        refs, queries = _data()
        train(_cfg(), refs, queries, {}, {}, out, resume=False)
    finally:
        dist.destroy_process_group()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_gloo_processes_train_like_one(tmp_path):
    refs, queries = _data()
    single = train(_cfg(), refs, queries, {}, {}, tmp_path / "single", resume=False)
    mp.start_processes(_worker, args=(2, _free_port(), str(tmp_path / "ddp")), nprocs=2, join=True,
                       start_method="spawn")
    a = torch.load(single.last_path, weights_only=True)
    b = torch.load(tmp_path / "ddp" / "last.pt", weights_only=True)
    assert a["global_step"] == b["global_step"] == 4
    la = [h["train_loss"] for h in a["history"]]
    lb = [h["train_loss"] for h in b["history"]]
    assert np.allclose(la, lb, atol=TOL)
    # Weights: Adam turns float noise in a (near-)zero gradient into a step of up to lr (m / sqrt(v) ~ +-1),
    # so the tolerance is per weight at most lr per step. The median says the bulk agrees: processes that did not
    # synchronise would differ by about lr per step (1e-3) in most weights; float noise leaves them far closer
    # (how close depends on the CPU's kernels: medians of 2e-6 in one CI run, 6e-9 on a 2-core AVX2 VM), so the
    # bound is 5 % of one step.
    diffs = torch.cat([(a["model"][k] - b["model"][k]).abs().flatten() for k in a["model"]])
    assert float(diffs.max()) <= 1e-3 * 4 and float(diffs.median()) < 5e-5, (float(diffs.max()), float(diffs.median()))
    # Only the first process wrote: one run folder, with its history and best.pt.
    assert (tmp_path / "ddp" / "best.pt").exists() and (tmp_path / "ddp" / "history.json").exists()


def test_global_batch_must_split_evenly(tmp_path, monkeypatch):
    import helpers.training.train as T

    monkeypatch.setattr(T, "distributed_world", lambda: (0, 4))
    refs, queries = _data()
    with pytest.raises(ValueError, match="do not split evenly over 4 processes"):
        train(_cfg(), refs, queries, {}, {}, tmp_path, resume=False)


def _grad_worker(rank: int, world: int, port: int, out: str) -> None:
    import torch.distributed as dist
    from torch.nn.parallel import DistributedDataParallel

    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=world)
    try:
        model, batch = _grad_setup()
        from helpers.training.distributed import sharded_encoder
        net = DistributedDataParallel(model)
        _loss(model, batch, sharded_encoder(net, rank, world)).backward()
        if rank == 0:
            torch.save({k: p.grad for k, p in model.named_parameters()}, out)
    finally:
        dist.destroy_process_group()


def _grad_setup():
    from helpers.core.configs import AugmentConfig
    from helpers.net.model import OrientationNet
    from helpers.training.batches import _Batcher

    torch.manual_seed(5)
    model = OrientationNet(_cfg().model)
    refs, queries = _data()
    batcher = _Batcher(sorted(refs), refs, queries, AugmentConfig(), SIZE)
    return model, batcher.make(np.arange(4), np.random.default_rng(0))


def _loss(model, batch, encode):
    from helpers.net.model import images_to_tensor
    from helpers.training.losses import pair_weights, weighted_info_nce

    imgs, q_obj, q_rot, r_obj, r_rot = batch
    feats = encode(images_to_tensor(imgs))
    b = len(q_obj)
    return weighted_info_nce(model.score(feats[:b], feats[b:]), torch.arange(b), pair_weights(q_obj, q_rot, r_obj, r_rot),
                             0.1)


def test_two_gloo_processes_give_the_single_process_gradient(tmp_path):
    model, batch = _grad_setup()
    _loss(model, batch, model.encode).backward()
    mp.start_processes(_grad_worker, args=(2, _free_port(), str(tmp_path / "g.pt")), nprocs=2, join=True,
                       start_method="spawn")
    g = torch.load(tmp_path / "g.pt", weights_only=True)
    for k, p in model.named_parameters():
        scale = float(p.grad.abs().max()) + 1e-12
        assert float((p.grad - g[k]).abs().max()) <= TOL * max(1.0, scale), k


def test_torchrun_launcher_trains_the_smoke_model_on_two_cpu_processes(tmp_path):
    """The README's command, on CPU with gloo: two processes train split 1's smoke-preset model."""
    import json
    import os
    import subprocess
    import sys

    # TMPDIR: the launcher's own log folder (torchelastic_*) stays inside this test's folder, not in /tmp
    (tmp_path / "tmp").mkdir()
    env = {**os.environ, "HELPERS_CACHE_DIR": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1",
           "TMPDIR": str(tmp_path / "tmp")}
    r = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--nproc_per_node=2",
                        f"--master_port={_free_port()}", "-m", "helpers.study.cli.ddp_train", "--preset", "smoke"],
                       env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-4000:]
    assert "[ddp_train] 2 processes (gloo)" in r.stdout
    done = list((tmp_path / "cache" / "runs").glob("split1-*/done.json"))
    assert len(done) == 1 and json.loads(done[0].read_text())["processes"] == 2
    assert (done[0].parent / "best.pt").exists()


def test_launcher_refuses_to_run_without_torchrun(capsys, monkeypatch):
    from helpers.study.cli import ddp_train

    monkeypatch.delenv("RANK", raising=False)
    assert ddp_train.main(["--preset", "smoke"]) == 2
    assert "torchrun" in capsys.readouterr().err
