"""Data-parallel training with torch.distributed: who am I, and encoding with the same global batch."""

from __future__ import annotations

import torch


def distributed_world() -> tuple[int, int]:
    """(rank, world size) of an initialised torch.distributed process group, else (0, 1)."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def sharded_encoder(net: torch.nn.Module, rank: int, world: int):
    """Encoder for data-parallel training with the SAME global batch as one process.

    Every process builds the whole batch (same seed, same augmentation), encodes only its
    contiguous share of the 3B images through the DistributedDataParallel-wrapped model and
    all-gathers the features with autograd, so each process computes the full B x 2B loss.
    Gradient bookkeeping: the gather's backward sums the (identical) losses' gradients of all
    W processes into each share, W times the single-process gradient; DDP then averages over
    the W processes, which gives exactly the single-process gradient for every weight (the
    fusion head, used outside the wrapped forward, gets the plain gradient on every process
    and is averaged to itself).
    """
    from torch.distributed.nn.functional import all_gather

    def encode(images: torch.Tensor) -> torch.Tensor:
        return torch.cat(all_gather(net(images.tensor_split(world)[rank].contiguous())), 0)

    return encode


def barrier() -> None:
    """Wait for every process of the group."""
    import torch.distributed as dist

    dist.barrier()
