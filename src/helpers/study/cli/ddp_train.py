"""Train one split's main model on N processes (GPUs or CPU) with DistributedDataParallel.

    torchrun --nproc_per_node=N -m helpers.study.cli.ddp_train --preset paper --split 1
    (or: python -m torch.distributed.run --nproc_per_node=N -m helpers.study.cli.ddp_train ...)

Uses the training parameters of ``presets/<preset>/02_train.yaml`` (checked like the
runner checks them). Backend nccl when CUDA is present (process k on GPU k of its node),
gloo on CPU. Every process builds the same global batch; each encodes its share and the
features are gathered, so the run follows the single-process run with the same global
batch (:func:`helpers.training.train.sharded_encoder`; tests/test_ddp.py). Only process 0
renders (the others load its cache), validates and writes checkpoints; the run lands in
the same cache folder as notebook 02's, so the notebooks then load it, and an interrupted
run resumes from its last epoch.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace

from ..parameters import ParameterError, check_values, configs_from
from ..pipeline import prepare_data, train_or_load
from .runner import preset_parameters


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="torchrun --nproc_per_node=N -m helpers.study.cli.ddp_train",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="paper", help="preset whose 02_train parameters are used")
    ap.add_argument("--split", type=int, default=None, help="split to train (default: the preset's)")
    a = ap.parse_args(argv)
    if "RANK" not in os.environ:
        print("error: start this with torchrun (it sets RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR)", file=sys.stderr)
        return 2

    import torch
    import torch.distributed as dist

    try:
        P = preset_parameters(a.preset, "02_train")
        if a.split is not None:
            P["split"] = a.split
        check_values("02_train", P)
    except ParameterError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    cuda = torch.cuda.is_available()
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if cuda:
        torch.cuda.set_device(local)
    dist.init_process_group("nccl" if cuda else "gloo")
    try:
        rank = dist.get_rank()
        device = f"cuda:{local}" if cuda else "cpu"
        cfg = configs_from(P)  # the notebook's typed configs; this process's device and bar
        data_cfg, train_cfg = cfg.data, replace(cfg.train, device=device, progress=rank == 0)
        if rank == 0:  # one process renders; the others then load the cached sets
            prepare_data(data_cfg)
        dist.barrier()
        data = prepare_data(data_cfg)
        _, run, info = train_or_load(P["split"], train_cfg, data, val_refs_per_object=P["val_refs"])
        if rank == 0:
            print(f"[ddp_train] {dist.get_world_size()} processes ({'nccl' if cuda else 'gloo'}); run {run}; "
                  f"{info.get('train_images_per_s', float('nan')):.1f} images/s")
    finally:
        dist.destroy_process_group()
    return 0


if __name__ == "__main__":
    sys.exit(main())
