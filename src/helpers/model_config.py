"""Architecture switches of :class:`helpers.model.OrientationNet` and its level geometry.

Kept apart from the network so that configs can be built, validated and
serialised (checkpoints, presets) without touching the scoring code.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

LEVELS = (32, 16, 13)
"""Decoder levels, named by their side length at a 128 px input, in feature order."""

FUSIONS = ("adaptive", "sigmoid", "softmax", "avg")


@dataclass
class ModelConfig:
    """Architecture switches (everything needed to rebuild the network).

    Attributes:
        image_size: input side S in px; multiple of 16, >= 64. Level maps are
            S/4 (level 32), S/8 (level 16) and S/8 - 3 (level 13).
        fusion: "adaptive" (softmax(g) x sigmoid(l), the full method),
            "sigmoid", "softmax", or "avg" (plain mean of local cosines, no
            learned head). Ignored when ``scales == "global"``.
        scales: non-empty subset of (32, 16, 13), or "global" (one descriptor
            per image: the level-13 map averaged over locations, cosine score).
        local_norm: locally normalise the grey input (else global per-image
            standardisation).
        norm_window: side r of the local-normalisation window in px (odd or
            even; authors' code 17, paper 32).
        channels: feature channels per location.
        dropout: dropout probability in the level heads.
    """

    image_size: int = 128
    fusion: str = "adaptive"
    scales: tuple | str = (32, 16, 13)
    local_norm: bool = True
    norm_window: int = 17
    channels: int = 128
    dropout: float = 0.1

    def __post_init__(self) -> None:
        if isinstance(self.image_size, bool) or not isinstance(self.image_size, (int, np.integer)) \
                or self.image_size < 64 or self.image_size % 16:
            raise ValueError(f"ModelConfig.image_size: expected an int multiple of 16 and >= 64, "
                             f"got {self.image_size!r}")
        self.image_size = int(self.image_size)
        if self.fusion not in FUSIONS:
            raise ValueError(f"ModelConfig.fusion: expected one of {FUSIONS}, got {self.fusion!r}")
        if isinstance(self.scales, str):
            if self.scales != "global":
                raise ValueError(f"ModelConfig.scales: expected a subset of {LEVELS} or 'global', "
                                 f"got {self.scales!r}")
        else:
            try:
                given = [int(s) for s in self.scales]
            except (TypeError, ValueError):
                raise ValueError(f"ModelConfig.scales: expected a subset of {LEVELS} or 'global', "
                                 f"got {self.scales!r}") from None
            if not given or len(set(given)) != len(given) or not set(given) <= set(LEVELS):
                raise ValueError(f"ModelConfig.scales: expected a non-empty subset of {LEVELS} without "
                                 f"repeats, or 'global', got {self.scales!r}")
            # Canonical order so that feature layout never depends on how the user listed them.
            self.scales = tuple(s for s in LEVELS if s in given)
        if not isinstance(self.local_norm, (bool, np.bool_)):
            raise ValueError(f"ModelConfig.local_norm: expected a bool, got {self.local_norm!r}")
        self.local_norm = bool(self.local_norm)
        if isinstance(self.norm_window, bool) or not isinstance(self.norm_window, (int, np.integer)) \
                or not 2 <= self.norm_window <= self.image_size // 2:
            raise ValueError(f"ModelConfig.norm_window: expected an int in [2, image_size/2="
                             f"{self.image_size // 2}], got {self.norm_window!r}")
        self.norm_window = int(self.norm_window)
        if isinstance(self.channels, bool) or not isinstance(self.channels, (int, np.integer)) \
                or self.channels < 1:
            raise ValueError(f"ModelConfig.channels: expected a positive int, got {self.channels!r}")
        self.channels = int(self.channels)
        if not 0.0 <= float(self.dropout) < 1.0:
            raise ValueError(f"ModelConfig.dropout: expected a float in [0, 1), got {self.dropout!r}")
        self.dropout = float(self.dropout)

    @property
    def is_global(self) -> bool:
        return self.scales == "global"

    @property
    def levels(self) -> tuple[int, ...]:
        """Levels whose maps are returned (``(13,)`` for "global")."""
        return (13,) if self.is_global else tuple(self.scales)

    def to_dict(self) -> dict:
        """Plain JSON/checkpoint-safe dict (tuples become lists)."""
        d = asdict(self)
        if not isinstance(d["scales"], str):
            d["scales"] = list(d["scales"])
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"ModelConfig.from_dict: unknown keys {sorted(unknown)}")
        d = dict(d)
        if "scales" in d and not isinstance(d["scales"], str):
            d["scales"] = tuple(d["scales"])
        return cls(**d)


def level_shapes(image_size: int) -> dict[int, tuple[int, int]]:
    """Map side lengths (h, w) of each level for a square input of ``image_size`` px."""
    s4, s8 = image_size // 4, image_size // 8
    return {32: (s4, s4), 16: (s8, s8), 13: (s8 - 3, s8 - 3)}
