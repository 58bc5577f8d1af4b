"""In-memory container for a set of rendered views of one object.

This is the hand-off between rendering (``helpers.data.datasets``) and everything
that consumes images (training, feature encoding, baselines).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .rotations import Symmetries


@dataclass
class ObjectViews:
    """Views of one object.

    Attributes:
        name: object name from the data manifest (e.g. ``"duck"``).
        images: (N, S, S, 3) uint8 RGB crops (array or read-only memmap).
        rotations: (N, 3, 3) float32 ``R_m2c`` of each view.
        masks: optional (N, S, S) bool visible-object masks.
        kind: ``"reference"`` (object on black) or ``"query"`` (real-like).
        symmetries: optional (K, 3, 3) model-frame symmetry rotations, or a
            :class:`helpers.core.rotations.Symmetries` (continuous axis).
        meta: free-form provenance (render parameters, cache key, ...).
    """

    name: str
    images: np.ndarray
    rotations: np.ndarray
    masks: np.ndarray | None = None
    kind: str = "reference"
    symmetries: np.ndarray | Symmetries | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.images.ndim != 4 or self.images.shape[-1] != 3 or self.images.dtype != np.uint8:
            raise ValueError(f"ObjectViews({self.name!r}).images: expected (N,S,S,3) uint8, "
                             f"got {self.images.shape} {self.images.dtype}")
        if self.rotations.shape != (len(self.images), 3, 3):
            raise ValueError(f"ObjectViews({self.name!r}).rotations: expected ({len(self.images)},3,3), "
                             f"got {self.rotations.shape}")

    def __len__(self) -> int:
        return len(self.images)

    def subset(self, idx: np.ndarray) -> "ObjectViews":
        """Views at indices ``idx`` (copied into memory)."""
        idx = np.asarray(idx)
        return ObjectViews(self.name, np.ascontiguousarray(self.images[idx]),
                           np.asarray(self.rotations[idx]),
                           None if self.masks is None else np.asarray(self.masks[idx]),
                           self.kind, self.symmetries, dict(self.meta))
