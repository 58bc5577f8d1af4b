"""The network's input space: RGB crops to locally normalised grey images.

It lives in the bottom layer because two layers need exactly the same transform: the network
(:mod:`helpers.net.model`) and the symmetry rule (:mod:`helpers.data.symmetry`), which compares
renders as the network sees them.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

LOCAL_NORM_EPS = 1e-2
"""Added to the local std (intensity units, image in [0, 1]).

About 2.5 grey levels: flat or nearly flat patches (rendered black background,
8-bit quantisation noise) stay near zero instead of being blown up to unit
contrast, while textured patches (std >> 0.01) are normalised almost exactly.
"""

LOCAL_NORM_CLAMP = 6.0


def images_to_tensor(images: np.ndarray) -> torch.Tensor:
    """uint8 (N, S, S, 3) RGB array -> float32 tensor (N, 3, S, S) in [0, 1]."""
    arr = np.asarray(images)
    if arr.ndim != 4 or arr.shape[-1] != 3 or arr.dtype != np.uint8:
        raise ValueError(f"images: expected (N,S,S,3) uint8, got {arr.shape} {arr.dtype}")
    if not arr.flags.writeable:  # read-only memmap: torch would warn; .float() below copies anyway
        arr = np.array(arr)
    return torch.from_numpy(np.ascontiguousarray(arr)).permute(0, 3, 1, 2).float().div_(255.0)


def preprocess(images: torch.Tensor, local_norm: bool = True, window: int = 17,
               eps: float = LOCAL_NORM_EPS, clamp: float = LOCAL_NORM_CLAMP) -> torch.Tensor:
    """RGB crops -> normalised grey images.

    Args:
        images: (B, 3, H, W) float in [0, 1] (uint8 tensors are divided by 255).
        local_norm: if True, ``(x - mu) / (std + eps)`` with mu/std over an
            ``window x window`` box around each pixel (reflect padding), then
            clamped to +-``clamp``. If False, the grey image is standardised
            with its own global mean and std (eps 1e-6 against blank
            images), without clamping.
        window: box side in px; even sizes put the extra row/column after the
            centre (pad (r-1)//2 before, r//2 after).

    Returns:
        (B, 1, H, W) float32.
    """
    if images.ndim != 4 or images.shape[1] != 3:
        raise ValueError(f"images: expected (B,3,H,W), got {tuple(images.shape)}")
    if images.dtype == torch.uint8:
        images = images.float() / 255.0
    grey = images.float().mean(dim=1, keepdim=True)
    # Removing the per-image mean first keeps E[x^2] - E[x]^2 from cancelling badly.
    grey = grey - grey.mean(dim=(2, 3), keepdim=True)
    if not local_norm:
        std = grey.pow(2).mean(dim=(2, 3), keepdim=True).sqrt()
        return grey / (std + 1e-6)
    before, after = (window - 1) // 2, window // 2
    padded = F.pad(grey, (before, after, before, after), mode="reflect")
    mu = _box_mean(padded, window)
    var = (_box_mean(padded * padded, window) - mu * mu).clamp_min(0.0)
    out = (grey - mu) / (var.sqrt() + eps)
    return out.clamp(-clamp, clamp)


def _box_mean(padded: torch.Tensor, window: int) -> torch.Tensor:
    """Mean over ``window x window`` boxes (valid positions) of (B, 1, H, W).

    Separable: a 1 x r then an r x 1 stride-1 average pool, O(HW r) instead of the
    O(HW r^2) of one r x r pool (3x faster at r = 17 here; same value up to float
    rounding, ~1e-7 relative).
    """
    return F.avg_pool2d(F.avg_pool2d(padded, (1, window), stride=1), (window, 1), stride=1)
