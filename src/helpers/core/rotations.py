"""Rotations on SO(3): sampling, distances, symmetry.

All rotations are 3x3 matrices ``R_m2c`` (model -> OpenCV camera), stored as
arrays of shape (N, 3, 3), float64 unless said otherwise. Angles are radians
inside the code; functions with ``_deg`` in the name return degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


def haar_uniform(n: int, seed: int | np.random.Generator | None = 0) -> np.ndarray:
    """Sample ``n`` Haar-uniform rotations, shape (n, 3, 3).

    Follows the method's recipe: two Gaussian 3-vectors form a 6D
    representation that Gram-Schmidt turns into an orthonormal frame. The
    Gaussian is isotropic, so the first column is uniform on the sphere and
    the second uniform on the circle orthogonal to it: the result is Haar.
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n, 3))
    b = rng.standard_normal((n, 3))
    return six_d_to_matrix(a, b)


def six_d_to_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Gram-Schmidt of two 3-vectors (N, 3) each into rotations (N, 3, 3).

    Columns are x = a/|a|, y = (b - (x.b) x)/|.|, z = x cross y.
    """
    x = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b - np.sum(x * b, axis=-1, keepdims=True) * x
    y = b / np.linalg.norm(b, axis=-1, keepdims=True)
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=-1)


def geodesic(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """Geodesic angle (radians, in [0, pi]) between broadcastable (..., 3, 3) stacks.

    arccos((tr(R1^T R2) - 1) / 2), with the cosine clipped for round-off.
    """
    tr = np.einsum("...ji,...ji->...", R1, R2)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def geodesic_deg(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """Geodesic angle in degrees; see :func:`geodesic`."""
    return np.degrees(geodesic(R1, R2))


def pairwise_geodesic(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """All geodesic angles (radians) between A (N,3,3) and B (M,3,3): (N, M)."""
    tr = np.einsum("nij,mij->nm", A, B)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def nearest(query: np.ndarray, refs: np.ndarray, chunk: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """Index (N,) and angle (N,) radians of the nearest reference to each query.

    ``query`` (N,3,3), ``refs`` (M,3,3). Works in chunks of references so the
    N x chunk trace matrix bounds memory.
    """
    query = np.asarray(query, dtype=np.float64)
    refs = np.asarray(refs, dtype=np.float64)
    best_tr = np.full(len(query), -np.inf)
    best_idx = np.zeros(len(query), dtype=np.int64)
    qf = query.reshape(len(query), 9)
    for s in range(0, len(refs), chunk):
        tr = qf @ refs[s:s + chunk].reshape(-1, 9).T  # trace(Q^T R) = sum_ij Q_ij R_ij
        j = np.argmax(tr, axis=1)
        v = tr[np.arange(len(query)), j]
        better = v > best_tr
        best_tr[better] = v[better]
        best_idx[better] = j[better] + s
    ang = np.arccos(np.clip((best_tr - 1.0) / 2.0, -1.0, 1.0))
    return best_idx, ang


def rot_z(angle: float | np.ndarray) -> np.ndarray:
    """Rotation(s) about the camera z (optical) axis by ``angle`` radians, (..., 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def inplane_rotate_label(R_m2c: np.ndarray, image_angle_deg: float | np.ndarray) -> np.ndarray:
    """New ``R_m2c`` after rotating the image by ``image_angle_deg`` about its centre.

    The angle follows OpenCV's ``getRotationMatrix2D``: positive turns the
    picture counter-clockwise on screen. With y pointing down, that is a
    rotation by minus the angle about the optical axis.
    """
    return rot_z(-np.radians(image_angle_deg)) @ R_m2c


@dataclass(frozen=True)
class Symmetries:
    """Symmetry group of an object with continuous symmetries, kept exact.

    The group is {Rot(a, t) @ D : t in [0, 2 pi), D in ``discrete``} for one axis
    ``a`` (BOP's ``symmetries_continuous`` x ``symmetries_discrete``); with two or
    more non-parallel axes it is all of SO(3) (a sphere), and every error is 0.

    Attributes:
        discrete: (K, 3, 3) model-frame rotations, identity included.
        axes: (A, 3) unit axes of the continuous symmetries, model frame, A >= 1.
    """

    discrete: np.ndarray
    axes: np.ndarray

    def __post_init__(self) -> None:
        d = np.asarray(self.discrete, dtype=np.float64).reshape(-1, 3, 3)
        if not any(np.allclose(x, np.eye(3)) for x in d):
            d = np.concatenate([np.eye(3)[None], d])
        a = np.asarray(self.axes, dtype=np.float64).reshape(-1, 3)
        if len(a) == 0 or (np.linalg.norm(a, axis=1) == 0).any():
            raise ValueError(f"Symmetries.axes: expected non-zero 3-vectors, got {self.axes!r}")
        object.__setattr__(self, "discrete", d)
        object.__setattr__(self, "axes", a / np.linalg.norm(a, axis=1, keepdims=True))

    @property
    def full(self) -> bool:
        """True when the axes span more than one direction (the group is SO(3))."""
        return bool((np.abs(self.axes @ self.axes[0]) < 1 - 1e-9).any())


def continuous_symmetric_geodesic_deg(R_est: np.ndarray, R_gt: np.ndarray, sym: Symmetries) -> np.ndarray:
    """Exact min over the group of angle(R_est, R_gt @ Rot(a, t) @ D), degrees (N,).

    For each D, with M = D R_est^T R_gt, trace(M Rot(a, t)) = a'Ma + cos t (tr M - a'Ma)
    + sin t tr(M [a]x), whose maximum over t is a'Ma + sqrt((tr M - a'Ma)^2 + tr(M [a]x)^2):
    the smallest angle in closed form, no discretisation.
    """
    R_est = np.asarray(R_est, dtype=np.float64).reshape(-1, 3, 3)
    R_gt = np.asarray(R_gt, dtype=np.float64).reshape(-1, 3, 3)
    if sym.full:
        return np.zeros(len(R_est))
    a = sym.axes[0]
    skew = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    M = np.einsum("kij,nlj,nlm->nkim", sym.discrete, R_est, R_gt)  # D @ R_est^T @ R_gt: (N, K, 3, 3)
    ama = np.einsum("i,nkij,j->nk", a, M, a)
    A = np.einsum("nkii->nk", M) - ama
    B = np.einsum("nkij,ji->nk", M, skew)
    best = ama + np.sqrt(A * A + B * B)
    return np.degrees(np.arccos(np.clip((best - 1.0) / 2.0, -1.0, 1.0))).min(axis=1)


def symmetric_geodesic_deg(R_est: np.ndarray, R_gt: np.ndarray,
                           symmetries: np.ndarray | Symmetries | None) -> np.ndarray:
    """Symmetry-aware error in degrees: min over S of angle(R_est, R_gt @ S).

    Args:
        R_est, R_gt: (N, 3, 3).
        symmetries: (K, 3, 3) model-frame symmetry rotations (identity should
            be included; it is added if missing), a :class:`Symmetries` (continuous
            symmetries, minimised exactly) or None for no symmetry.

    Returns:
        (N,) degrees.
    """
    if isinstance(symmetries, Symmetries):
        return continuous_symmetric_geodesic_deg(R_est, R_gt, symmetries)
    if symmetries is None or len(symmetries) == 0:
        return geodesic_deg(R_est, R_gt)
    sym = np.asarray(symmetries, dtype=np.float64)
    if not any(np.allclose(s, np.eye(3)) for s in sym):
        sym = np.concatenate([np.eye(3)[None], sym])
    cand = np.einsum("nij,kjl->nkil", R_gt, sym)  # (N, K, 3, 3)
    return geodesic_deg(R_est[:, None], cand).min(axis=1)


def nearest_symmetric(query: np.ndarray, refs: np.ndarray,
                      symmetries: np.ndarray | Symmetries | None) -> tuple[np.ndarray, np.ndarray]:
    """Index (N,) and symmetry-aware angle (N,) in radians of each query's nearest reference.

    ``query`` (N,3,3), ``refs`` (M,3,3), ``symmetries`` as :func:`symmetric_geodesic_deg` (None:
    :func:`nearest`). The distance of reference R to query Q is min over S of angle(R, Q S), so of
    a symmetric object's equivalent views the closest one is found whichever it is.
    """
    if symmetries is None or (not isinstance(symmetries, Symmetries) and len(symmetries) <= 1):
        return nearest(query, refs)
    query = np.asarray(query, dtype=np.float64).reshape(-1, 3, 3)
    refs = np.asarray(refs, dtype=np.float64).reshape(-1, 3, 3)
    idx, ang = np.zeros(len(query), np.int64), np.zeros(len(query))
    for i, q in enumerate(query):  # one (M,) row per query: M x |group| traces, small beside a training step
        d = symmetric_geodesic_deg(refs, np.broadcast_to(q, refs.shape), symmetries)
        idx[i] = int(np.argmin(d))
        ang[i] = np.deg2rad(d[idx[i]])
    return idx, ang


def discrete_symmetries_from_axis(axis: np.ndarray, order: int) -> np.ndarray:
    """Rotations (order, 3, 3) about ``axis`` by multiples of 2*pi/order (model frame)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    angles = 2 * np.pi * np.arange(order) / order
    return Rotation.from_rotvec(angles[:, None] * axis[None]).as_matrix()


def random_angle_within(n: int, max_deg: float, seed: int | np.random.Generator | None = 0) -> np.ndarray:
    """Rotations (n,3,3) with uniform random axis and angle uniform in [0, max_deg]."""
    rng = np.random.default_rng(seed)
    axis = rng.standard_normal((n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    ang = np.radians(rng.uniform(0, max_deg, size=n))
    return Rotation.from_rotvec(axis * ang[:, None]).as_matrix()
