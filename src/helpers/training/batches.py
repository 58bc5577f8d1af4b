"""Training batches: which queries a step uses, and the query/positive/random-reference images.

Split out of :mod:`helpers.training.train` (the loop); the batch follows the authors' code: each query
brings its positive (nearest reference rotation of its own object, after augmentation) and one
random reference (of its own object, or of any training object).
"""

from __future__ import annotations

import math

import numpy as np

from ..core.configs import AugmentConfig
from ..core.rotations import nearest, nearest_symmetric
from ..core.views import ObjectViews
from .augment import augment_batch


def _order_stream(rng: np.random.Generator, n: int, count: int) -> np.ndarray:
    """``count`` indices in [0, n): back-to-back random permutations (each item once per pass)."""
    reps = math.ceil(count / n)
    return np.concatenate([rng.permutation(n) for _ in range(reps)])[:count]


class _Batcher:
    """Builds training batches: augmented queries, positives and random references."""

    def __init__(self, names: list[str], refs: dict[str, ObjectViews], queries: dict[str, ObjectViews],
                 aug: AugmentConfig, size: int, random_ref: str = "own",
                 clean: dict[str, ObjectViews] | None = None, symmetry_aware: bool = False) -> None:
        self.names = names
        self.clean = [None if clean is None else clean.get(n) for n in names]
        self.size = size
        self.random_ref = random_ref
        self.refs = [refs[n] for n in names]
        self.queries = [queries.get(n) for n in names]
        self.aug = aug
        obj, idx = [], []
        for i, q in enumerate(self.queries):
            if q is not None and len(q):
                obj.append(np.full(len(q), i))
                idx.append(np.arange(len(q)))
        self.q_obj = np.concatenate(obj)
        self.q_idx = np.concatenate(idx)
        self.n_refs = np.array([len(r) for r in self.refs])
        #: Symmetry group per object id (None: none declared, or symmetry-blind training).
        self.symmetries = [r.symmetries if symmetry_aware else None for r in self.refs]

    def __len__(self) -> int:
        return len(self.q_obj)

    def _view(self, o: int, i: int, clean: bool, u: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(image, rotation, mask) of query ``i`` of object ``o``, or of a clean view of it
        (index drawn from ``u`` in [0, 1)), cropped to ``size`` if the clean set has no context."""
        v = self.clean[o] if clean else self.queries[o]
        if clean:
            i = int(u * len(v))
        img, mask = v.images[i], None if v.masks is None else v.masks[i]
        if clean and img.shape[0] != self.queries[o].images.shape[1]:
            # Clean views are stored as crops (no context): pad with black to the queries' side.
            pad = (self.queries[o].images.shape[1] - img.shape[0]) // 2
            img = np.pad(img, ((pad, pad), (pad, pad), (0, 0)))
            mask = None if mask is None else np.pad(mask, pad)
        return img, np.asarray(v.rotations[i], np.float64), mask

    def make(self, picks: np.ndarray, rng: np.random.Generator, p_clean: float = 0.0):
        """Batch for query indices ``picks`` (B,) -> (images (3B,S,S,3) uint8,
        query objects (B,), query rotations (B,3,3), reference objects (2B,), reference rotations (2B,3,3)).
        With probability ``p_clean`` a query is swapped for a clean view of its object (curriculum)."""
        q_obj, q_idx = self.q_obj[picks], self.q_idx[picks]
        if p_clean > 0:  # drawn only during the curriculum, so runs without one keep their stream
            u = rng.random((2, len(picks)))
            use_clean = (u[0] < p_clean) & np.array([self.clean[o] is not None for o in q_obj])
        else:
            u, use_clean = np.zeros((2, len(picks))), np.zeros(len(picks), bool)
        views = [self._view(o, i, c, uu) for o, i, c, uu in zip(q_obj, q_idx, use_clean, u[1])]
        q_img = np.stack([v[0] for v in views])
        q_rot = np.stack([v[1] for v in views])
        q_mask = None if any(v[2] is None for v in views) else np.stack([v[2] for v in views])
        q_img, q_rot = augment_batch(q_img, q_rot, rng, self.aug, q_mask, self.size)
        # Positive: nearest reference rotation of the same object, after augmentation (under the object's
        # symmetries when training is symmetry-aware).
        pos_idx = np.empty(len(picks), dtype=np.int64)
        for o in np.unique(q_obj):
            sel = q_obj == o
            sym = self.symmetries[o]
            pos_idx[sel] = (nearest(q_rot[sel], self.refs[o].rotations) if sym is None
                            else nearest_symmetric(q_rot[sel], self.refs[o].rotations, sym))[0]
        rnd_obj = rng.integers(0, len(self.refs), size=len(picks))
        if self.random_ref == "own":  # drawn either way, so both switches consume the same stream
            rnd_obj = q_obj
        rnd_idx = np.floor(rng.random(len(picks)) * self.n_refs[rnd_obj]).astype(np.int64)
        r_obj = np.concatenate([q_obj, rnd_obj])
        r_idx = np.concatenate([pos_idx, rnd_idx])
        r_img = np.stack([self.refs[o].images[i] for o, i in zip(r_obj, r_idx)])
        r_rot = np.stack([np.asarray(self.refs[o].rotations[i], np.float64) for o, i in zip(r_obj, r_idx)])
        return np.concatenate([q_img, r_img]), q_obj, q_rot, r_obj, r_rot
