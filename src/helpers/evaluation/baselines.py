"""HOG nearest-neighbour baseline, shaped like a model so the same pipeline runs it.

:class:`HogModel` has ``encode`` and ``score`` with the network's signatures
(features (B, D, 1): one "location" holding the whole HOG vector), so
:class:`helpers.search.features.FeatureCache` and :mod:`helpers.search.retrieval` use it
unchanged. skimage's ``hog`` is used because OpenCV 5 no longer ships
``HOGDescriptor`` in the main package.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import torch
from skimage.feature import hog

from ..core.configs import HogConfig


def _grey(images: np.ndarray) -> np.ndarray:
    """(N,S,S,3) uint8 -> (N,S,S) float32 grey in [0,1] (channel mean, as the network's input)."""
    return images.astype(np.float32).mean(axis=-1) / 255.0


def hog_descriptor(images: np.ndarray, config: HogConfig = HogConfig()) -> np.ndarray:
    """HOG of each image's grey version, (N, D) float32, each row L2-normalised.

    Args:
        images: (N, S, S, 3) uint8 RGB; S >= cell * block.
        config: HOG parameters.

    D = (S/cell - block + 1)^2 * block^2 * orientations (8100 for S=128).
    """
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ValueError(f"hog_descriptor: images must be (N,S,S,3) uint8, got {images.shape} {images.dtype}")
    if min(images.shape[1:3]) < config.cell * config.block:
        raise ValueError(f"hog_descriptor: images of {images.shape[1:3]} px are smaller than one block "
                         f"({config.cell * config.block} px)")
    grey = _grey(images)
    out = np.stack([hog(g, orientations=config.orientations, pixels_per_cell=(config.cell, config.cell),
                        cells_per_block=(config.block, config.block), block_norm="L2-Hys",
                        feature_vector=True) for g in grey]).astype(np.float32)
    # Blank images give all-zero HOG: leave them zero rather than divide by 0.
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return out / np.maximum(norm, 1e-12)


class HogModel:
    """Duck-typed "model" for the HOG baseline.

    ``encode(images (B,3,H,W) float in [0,1]) -> (B,D,1)`` unit-norm float32;
    ``score(q (Q,D,1), r (R,D,1)) -> (Q,R)`` cosine similarity in [-1, 1].
    It has no weights; :func:`helpers.search.features.model_fingerprint` keys it by
    class and ``config``.
    """

    def __init__(self, config: HogConfig = HogConfig()):
        self.hog_config = config
        self.config = asdict(config)

    def encode(self, images: torch.Tensor) -> torch.Tensor:
        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(f"HogModel.encode: images must be (B,3,H,W), got {tuple(images.shape)}")
        # Back to uint8 so the descriptor sees exactly what a uint8 view holds.
        u8 = (images.detach().float().clamp(0, 1) * 255.0).round().to(torch.uint8)
        d = hog_descriptor(u8.permute(0, 2, 3, 1).cpu().numpy(), self.hog_config)
        return torch.from_numpy(d)[:, :, None].to(images.device)

    def score(self, q: torch.Tensor, r: torch.Tensor, chunk: int = 1024) -> torch.Tensor:
        if q.ndim != 3 or r.ndim != 3 or q.shape[1:] != r.shape[1:]:
            raise ValueError(f"HogModel.score: expected (Q,D,L) and (R,D,L) with equal D,L, "
                             f"got {tuple(q.shape)} and {tuple(r.shape)}")
        qf = q.float().flatten(1)
        out = [qf @ r[s:s + chunk].float().flatten(1).T for s in range(0, len(r), chunk)]
        return torch.cat(out, dim=1) if out else qf.new_zeros((len(q), 0))
