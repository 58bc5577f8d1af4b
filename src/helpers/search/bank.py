"""Reference features of K objects rendered at one shared set of rotations.

:class:`ReferenceBank` is what :mod:`helpers.search.retrieval`'s searches read: anchors
spread by farthest point sampling, rotation neighbourhoods, and reference
features in the bank's dtype, gathered (:meth:`ReferenceBank.ref_feats`) or
shared in place (:meth:`ReferenceBank.ref_source`) for a row-indexed scorer.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
import torch

from .fps import farthest_point_sampling


class ReferenceBank:
    """Reference features of K objects rendered at the same R rotations.

    Args:
        feats: K arrays (R, C, L) (float16 memmaps are fine; never loaded whole).
        rotations: (R, 3, 3) ``R_m2c`` shared by all objects.
        names: K object names.
        k_ac: number of anchors precomputed by farthest point sampling
            (clamped to R); None: none now. Other counts are computed on first use.
    """

    def __init__(self, feats: Sequence[np.ndarray], rotations: np.ndarray, names: Sequence[str],
                 k_ac: int | None = 1024):
        rotations = np.asarray(rotations, dtype=np.float64)
        if rotations.ndim != 3 or rotations.shape[1:] != (3, 3) or len(rotations) == 0:
            raise ValueError(f"ReferenceBank: rotations must be (R,3,3) with R >= 1, got {rotations.shape}")
        if len(feats) == 0 or len(feats) != len(names):
            raise ValueError(f"ReferenceBank: got {len(feats)} feature arrays and {len(names)} names "
                             "(expected one array per object, at least one)")
        R = len(rotations)
        shape0 = None
        for name, f in zip(names, feats):
            if f.ndim != 3 or f.shape[0] != R:
                raise ValueError(f"ReferenceBank: features of {name!r} have shape {f.shape}, "
                                 f"expected ({R}, C, L) to match the rotations")
            shape0 = shape0 or f.shape[1:]
            if f.shape[1:] != shape0:
                raise ValueError(f"ReferenceBank: features of {name!r} are {f.shape[1:]}, others {shape0}")
        self.feats = list(feats)
        self.rotations = rotations
        self.names = [str(n) for n in names]
        self._flat = rotations.reshape(R, 9)
        self._anchors: dict[int, np.ndarray] = {}
        self._anchor_feats: dict[int, list[torch.Tensor]] = {}
        self._anchor_heads: dict[tuple[int, int], torch.Tensor] = {}
        if k_ac is not None:
            self.anchors(k_ac)

    @property
    def n_objects(self) -> int:
        return len(self.feats)

    @property
    def n_refs(self) -> int:
        return len(self.rotations)

    def anchors(self, k_ac: int) -> np.ndarray:
        """(min(k_ac, R),) reference indices spread by farthest point sampling (cached)."""
        if k_ac < 1:
            raise ValueError(f"k_ac must be >= 1, got {k_ac}")
        k = min(int(k_ac), self.n_refs)
        if k not in self._anchors:
            self._anchors[k] = farthest_point_sampling(self.rotations, k)
        return self._anchors[k]

    def anchor_feats(self, k_ac: int) -> list[torch.Tensor]:
        """Per object, the features (A, C, L) of the ``k_ac`` anchors, gathered once and kept in RAM.

        Every query scores all anchors, so they are read from the (memory-
        mapped) bank once instead of once per query: K * A * C * L elements
        in the bank's dtype (13 x 1024 x 128 x 345 float16 = 1.2 GB at 64 px).
        """
        k = min(int(k_ac), self.n_refs)
        if k not in self._anchor_feats:
            idx = self.anchors(k)
            self._anchor_feats[k] = [self.ref_feats(o, idx) for o in range(self.n_objects)]
        return self._anchor_feats[k]

    def anchor_head_feats(self, k_ac: int, n: int) -> torch.Tensor:
        """(K * n, C, L): the first ``n`` anchors of every object, object-major, in one tensor (cached).

        The coarse round of :func:`fast_search` scores them in one scorer call
        instead of K small ones; n/A of :meth:`anchor_feats`' memory.
        """
        key = (min(int(k_ac), self.n_refs), int(n))
        if key not in self._anchor_heads:
            feats = self.anchor_feats(k_ac)
            if not 1 <= n <= len(feats[0]):
                raise ValueError(f"anchor_head_feats: n must be in [1, {len(feats[0])}], got {n}")
            self._anchor_heads[key] = torch.cat([f[:n] for f in feats])
        return self._anchor_heads[key]

    def nearest_refs(self, ref_index: int, k: int) -> np.ndarray:
        """The ``k`` references closest in rotation to ``ref_index`` (itself first), nearest first.

        One (R,) trace vector, O(R): cheap enough to recompute per step instead
        of storing an R x R neighbour table.
        """
        k = max(1, min(int(k), self.n_refs))
        tr = self._flat @ self._flat[ref_index]  # trace(Ri^T Rj): larger = closer
        idx = np.argpartition(-tr, k - 1)[:k] if k < self.n_refs else np.arange(self.n_refs)
        idx = idx[np.argsort(-tr[idx], kind="stable")]
        # Duplicated rotations could tie with the centre: make sure it leads.
        idx = np.concatenate([[ref_index], idx[idx != ref_index]])[:k]
        return idx.astype(np.int64)

    def ref_feats(self, obj: int, idx: np.ndarray) -> torch.Tensor:
        """Features (M, C, L) of references ``idx`` of object ``obj`` (in ``idx`` order).

        float16 banks stay float16 (half the bytes to copy; the scorer
        promotes); anything else becomes float32.
        """
        idx = np.asarray(idx, dtype=np.int64)
        src = self.feats[obj]
        dtype = np.float16 if src.dtype == np.float16 else np.float32
        if len(idx) < 2 or bool((idx[1:] >= idx[:-1]).all()):
            # Already in order (the fast search's score cache asks this way): one copy, not two.
            return torch.from_numpy(np.ascontiguousarray(src[idx], dtype=dtype))
        order = np.argsort(idx)  # sorted reads are sequential on a memmap
        out = np.empty((len(idx), *src.shape[1:]), dtype=dtype)
        out[order] = src[idx[order]]
        return torch.from_numpy(out)

    def ref_source(self, obj: int) -> torch.Tensor | None:
        """All (R, C, L) features of object ``obj`` as a CPU tensor sharing the bank's memory, or None.

        None unless the features are a C-contiguous float16/float32 numpy array (or
        memmap): then a row-indexed scorer (``scorer.rows``) can read the rows it
        needs in place instead of :meth:`ref_feats` copying them out first.
        """
        src = self.feats[obj]
        if not isinstance(src, np.ndarray) or src.dtype not in (np.float16, np.float32) \
                or not src.flags.c_contiguous:
            return None
        with warnings.catch_warnings():
            # Read-only memmaps are wrapped without a copy; scorers only read them.
            warnings.filterwarnings("ignore", message="The given NumPy array is not writable")
            return torch.from_numpy(src)

    def chunk(self, obj: int, start: int, stop: int) -> torch.Tensor:
        """Features (stop - start, C, L) of a contiguous run of references (dtype as in :meth:`ref_feats`)."""
        src = self.feats[obj]
        dtype = np.float16 if src.dtype == np.float16 else np.float32
        part = np.ascontiguousarray(src[start:stop], dtype=dtype)
        with warnings.catch_warnings():
            # A read-only memmap slice is wrapped without a copy; scorers only read it.
            warnings.filterwarnings("ignore", message="The given NumPy array is not writable")
            return torch.from_numpy(part)
