"""Numeric precision of the network's convolutions: float32, or bfloat16 autocast where it pays.

bfloat16 autocast halves the bytes every convolution moves and, on CPUs with native bf16
dot-product instructions (x86 AVX512-BF16 or AMX-BF16, Arm BF16), runs oneDNN's bf16 kernels:
about 2x faster training steps there. Without them oneDNN emulates bf16 and it is slower than
float32, so ``"auto"`` picks bf16 only where the hardware has it (detected, never assumed).
Only the encoder-decoder runs under autocast; local normalisation, the unit-normalised features,
the fusion head, the scores and the loss stay float32 (see :meth:`OrientationNet.encode`).
"""

from __future__ import annotations

import contextlib
import platform
from pathlib import Path

import torch

PRECISIONS = ("auto", "fp32", "bf16")

# /proc/cpuinfo flags that mean native bf16 arithmetic (x86 "flags", Arm "Features").
_BF16_FLAGS = {"avx512_bf16", "amx_bf16", "bf16"}


def cpu_flags() -> set[str]:
    """ISA flags of this CPU from /proc/cpuinfo (empty where it cannot be read, e.g. not Linux)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():
        key = line.split(":", 1)[0].strip().lower()
        if key in ("flags", "features"):
            return set(line.split(":", 1)[1].split())
    return set()


def native_bf16(device: torch.device) -> bool:
    """True where bf16 arithmetic is native on ``device``: a CUDA GPU that supports it, or a CPU
    with one of the bf16 instruction-set flags."""
    if device.type == "cuda":
        return bool(torch.cuda.is_bf16_supported())
    if device.type != "cpu":
        return False
    return bool(_BF16_FLAGS & cpu_flags())


def resolve_precision(precision: str, device: torch.device) -> str:
    """``"auto"`` -> ``"bf16"`` where :func:`native_bf16`, else ``"fp32"``; others pass through.

    Raises ValueError naming the parameter for an unknown value.
    """
    if precision not in PRECISIONS:
        raise ValueError(f"precision: expected one of {PRECISIONS}, got {precision!r}")
    if precision == "auto":
        return "bf16" if native_bf16(device) else "fp32"
    return precision


def autocast(precision: str, device: torch.device):
    """Context manager: bf16 autocast on ``device`` for ``"bf16"``, nothing for ``"fp32"``."""
    if precision == "bf16":
        return torch.autocast(device_type=device.type, dtype=torch.bfloat16)
    if precision != "fp32":
        raise ValueError(f"precision: expected 'fp32' or 'bf16' (resolved), got {precision!r}")
    return contextlib.nullcontext()


def describe(device: torch.device) -> dict:
    """What a run records about its precision choice: the CPU's bf16 flags and the verdict."""
    return {"native_bf16": native_bf16(device), "machine": platform.machine(),
            "bf16_flags": sorted(_BF16_FLAGS & cpu_flags()) if device.type == "cpu" else None}
