"""The network's architecture switches (:class:`ModelConfig`) and the geometry of its decoder levels."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ._checks import _bools, _choice, _from_dict, _ints

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
        _choice(self, "fusion", FUSIONS)
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
        _bools(self, ("local_norm",))
        _ints(self, ("norm_window",), lo=2)
        if self.norm_window > self.image_size // 2:
            raise ValueError(f"ModelConfig.norm_window: expected an int in [2, image_size/2="
                             f"{self.image_size // 2}], got {self.norm_window!r}")
        _ints(self, ("channels",))
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
        d = dict(d)
        if "scales" in d and not isinstance(d["scales"], str):
            d["scales"] = tuple(d["scales"])
        return _from_dict(cls, d)


def parse_scales(scales: str) -> tuple[int, ...] | str:
    """Notebook form of the scales -> ModelConfig form: "global" or "32,16,13" -> (32, 16, 13)."""
    if scales == "global":
        return "global"
    try:
        out = tuple(int(s) for s in str(scales).split(","))
    except ValueError:
        out = ()
    if not out or not set(out) <= set(LEVELS):
        raise ValueError(f"scales: expected 'global' or a comma list of 32/16/13, got {scales!r}")
    return out


def level_shapes(image_size: int) -> dict[int, tuple[int, int]]:
    """Map side lengths (h, w) of each level for a square input of ``image_size`` px."""
    s4, s8 = image_size // 4, image_size // 8
    return {32: (s4, s4), 16: (s8, s8), 13: (s8 - 3, s8 - 3)}
