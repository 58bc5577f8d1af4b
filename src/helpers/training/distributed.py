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
    def encode(images: torch.Tensor) -> torch.Tensor:
        return _GatherShares.apply(net(images.tensor_split(world)[rank].contiguous()), rank, world)

    return encode


class _GatherShares(torch.autograd.Function):
    """Concatenate every process's equal-sized share along dim 0, with autograd.

    Backward: the gradients of the whole concatenation are summed over the processes
    (all-reduce) and each process keeps its own share's rows: the reduce-scatter of
    ``torch.distributed.nn.functional.all_gather`` (deprecated in torch 2.13), written with
    collectives that gloo and nccl both have.
    """

    @staticmethod
    def forward(ctx, share: torch.Tensor, rank: int, world: int) -> torch.Tensor:
        import torch.distributed as dist

        ctx.rank, ctx.world = rank, world
        parts = [torch.empty_like(share) for _ in range(world)]
        dist.all_gather(parts, share.contiguous())
        return torch.cat(parts, 0)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        import torch.distributed as dist

        grad = grad.contiguous().clone()
        dist.all_reduce(grad)
        return grad.chunk(ctx.world, 0)[ctx.rank], None, None


def barrier() -> None:
    """Wait for every process of the group."""
    import torch.distributed as dist

    dist.barrier()
