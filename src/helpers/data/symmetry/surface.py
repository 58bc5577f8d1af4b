"""Stage 1 of the symmetry rule: candidate rotations from the mesh surface alone.

A rotation S (model frame, about the surface's area centroid) is a *surface candidate* when the
surface turned by S lies closer to itself than the surface turned by a small angle (the rule's
``small_turn_deg``, 10 deg) does on average over axes. Closeness is a symmetric mean surface distance
between two independent point samples of the surface, in units of the object's diameter, so the
sampling noise is part of both sides of the comparison and the test is scale-free.

The search scores a grid of rotations (Haar-uniform ones plus the n-fold turns about the surface's
principal axes, their bisectors and the model axes, where modelled objects keep their symmetries),
keeps those far enough from the identity that pass, refines each by a local search and snaps angles
within a few degrees of 360/n to exactly that. A continuous axis is one about which every tested
angle passes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.optimize import minimize
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ...core.rotations import Symmetries, continuous_symmetric_geodesic_deg, geodesic_deg, haar_uniform

#: Angles (degrees) tested about an axis before it is called a continuous surface symmetry.
CONTINUOUS_TEST_DEG = (20.0, 45.0, 90.0, 135.0, 180.0)
#: Refined angles within this many degrees of 360/n (n = 2..8) are snapped to 360/n.
SNAP_DEG = 4.0
#: Two candidates closer than this (degrees, geodesic) are the same candidate.
SAME_DEG = 15.0


@dataclass(frozen=True)
class SurfaceSamples:
    """Two independent area-uniform samples of one surface, centred and scaled.

    Attributes:
        a, b: (N, 3) points, centred on the surface's area centroid, in object diameters.
        centre: (3,) the centroid in the mesh's own frame (its units).
        tree_a, tree_b: KD-trees of ``a`` and ``b``.
    """

    a: np.ndarray
    b: np.ndarray
    centre: np.ndarray
    tree_a: cKDTree
    tree_b: cKDTree


def sample_surface(mesh: trimesh.Trimesh, n_points: int, seed: int) -> SurfaceSamples:
    """Sample ``n_points`` points twice (different seeds) on ``mesh``'s surface.

    The rotation centre is the area centroid: every rotational symmetry of a surface fixes it,
    whatever the mesh's own origin or bounding box.
    """
    a, _ = trimesh.sample.sample_surface(mesh, n_points, seed=seed)
    b, _ = trimesh.sample.sample_surface(mesh, n_points, seed=seed + 1)
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    centre = 0.5 * (a.mean(axis=0) + b.mean(axis=0))
    span = float(np.linalg.norm(np.ptp(np.concatenate([a, b]), axis=0)))
    if span <= 0:
        raise ValueError("sample_surface: the mesh has zero extent")
    a, b = (a - centre) / span, (b - centre) / span
    return SurfaceSamples(a, b, centre, cKDTree(a), cKDTree(b))


def surface_distance(s: SurfaceSamples, R: np.ndarray) -> np.ndarray:
    """Symmetric mean distance (object diameters) between the surface turned by each R and itself.

    Args:
        R: (3, 3) or (K, 3, 3) rotations about the centroid.

    Returns:
        (K,) mean of the two directed mean nearest-neighbour distances: turned sample a to sample b,
        and sample b turned back to sample a.
    """
    R = np.asarray(R, np.float64).reshape(-1, 3, 3)
    out = np.empty(len(R))
    for i, r in enumerate(R):
        d1, _ = s.tree_b.query(s.a @ r.T, k=1)
        d2, _ = s.tree_a.query(s.b @ r, k=1)
        out[i] = 0.5 * (d1.mean() + d2.mean())
    return out


def fibonacci_axes(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the upper half-sphere (an axis and its opposite are one axis)."""
    i = np.arange(n) + 0.5
    z = 1.0 - i / n
    r = np.sqrt(1.0 - z * z)
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def axis_angle(axes: np.ndarray, deg: float | np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) by ``deg`` degrees about each of the (N, 3) unit ``axes``."""
    axes = np.asarray(axes, np.float64).reshape(-1, 3)
    ang = np.broadcast_to(np.radians(np.asarray(deg, np.float64)), (len(axes),))
    return Rotation.from_rotvec(axes * ang[:, None]).as_matrix()


def small_turn_distance(s: SurfaceSamples, small_turn_deg: float, n_axes: int = 26) -> float:
    """The surface distance of a small turn, averaged over ``n_axes`` evenly spread axes: the bar."""
    return float(surface_distance(s, axis_angle(fibonacci_axes(n_axes), small_turn_deg)).mean())


def principal_axes(s: SurfaceSamples) -> np.ndarray:
    """(3, 3) rows: the eigenvectors of the sample's second-moment matrix (where symmetry axes lie)."""
    pts = np.concatenate([s.a, s.b])
    _, vec = np.linalg.eigh(pts.T @ pts)
    return vec.T


def structured_axes(s: SurfaceSamples) -> np.ndarray:
    """(M, 3) axes worth testing exactly: principal axes, their pairwise bisectors, the model axes."""
    p = principal_axes(s)
    bis = [(p[i] + sg * p[j]) / np.sqrt(2) for i in range(3) for j in range(i + 1, 3) for sg in (1.0, -1.0)]
    return np.concatenate([p, np.stack(bis), np.eye(3)])


def grid_rotations(s: SurfaceSamples, n_grid: int, seed: int) -> np.ndarray:
    """(G, 3, 3) rotations to score: Haar-uniform ones and every n-fold turn (n = 2..6) about the structured axes."""
    turns = [axis_angle(ax[None], 360.0 * k / n) for ax in structured_axes(s) for n in range(2, 7) for k in range(1, n)]
    return np.concatenate([haar_uniform(n_grid, seed=seed), np.concatenate(turns)])


def _dedupe(R: np.ndarray, scores: np.ndarray, same_deg: float) -> np.ndarray:
    """Indices of R kept by non-maximum suppression (lowest score first, drop any within ``same_deg``)."""
    keep: list[int] = []
    for i in np.argsort(scores):
        if all(geodesic_deg(R[i][None], R[j][None])[0] >= same_deg for j in keep):
            keep.append(int(i))
    return np.asarray(keep, dtype=int)


def _refine(s: SurfaceSamples, R0: np.ndarray, max_iter: int) -> np.ndarray:
    """Local search (Nelder-Mead on a rotation vector) for the nearest minimum of the surface distance."""
    def f(v: np.ndarray) -> float:
        return float(surface_distance(s, Rotation.from_rotvec(v).as_matrix() @ R0)[0])

    res = minimize(f, np.zeros(3), method="Nelder-Mead",
                   options={"maxiter": max_iter, "initial_simplex": np.vstack([np.zeros(3), 0.05 * np.eye(3)]),
                            "xatol": 1e-3, "fatol": 1e-6})
    return Rotation.from_rotvec(res.x).as_matrix() @ R0


def snap(R: np.ndarray, snap_deg: float = SNAP_DEG) -> np.ndarray:
    """R with its angle set to exactly 360/n when it lies within ``snap_deg`` of it (n = 2..8), same axis."""
    rv = Rotation.from_matrix(R).as_rotvec()
    ang = np.degrees(np.linalg.norm(rv))
    for n in range(2, 9):
        if abs(ang - 360.0 / n) < snap_deg:
            return axis_angle(rv / np.linalg.norm(rv), 360.0 / n)[0]
    return R


def discrete_candidates(s: SurfaceSamples, bar: float, min_angle_deg: float, n_grid: int, seed: int,
                        max_candidates: int, refine_iter: int = 80) -> tuple[np.ndarray, np.ndarray]:
    """Surface candidates: rotations at least ``min_angle_deg`` from the identity whose surface distance is
    below ``bar``, one per basin, refined and snapped.

    Returns:
        rotations (C, 3, 3) and their surface distances (C,), best first; C <= ``max_candidates``.
    """
    G = grid_rotations(s, n_grid, seed)
    far = geodesic_deg(G, np.broadcast_to(np.eye(3), G.shape)) >= min_angle_deg
    G = G[far]
    d = surface_distance(s, G)
    ok = d < bar
    G, d = G[ok], d[ok]
    if len(G) == 0:
        return np.zeros((0, 3, 3)), np.zeros(0)
    keep = _dedupe(G, d, SAME_DEG)[:max_candidates]
    refined = []
    for R in G[keep]:
        r = _refine(s, R, refine_iter)
        r_snap = snap(r)
        if surface_distance(s, r_snap)[0] < bar:  # snapping must not cost the candidate its pass
            r = r_snap
        refined.append(r)
    R = np.stack(refined)
    d = surface_distance(s, R)
    angle = geodesic_deg(R, np.broadcast_to(np.eye(3), R.shape))
    ok = (d < bar) & (angle >= min_angle_deg)
    R, d = R[ok], d[ok]
    keep = _dedupe(R, d, SAME_DEG)
    return R[keep], d[keep]


def continuous_axes(s: SurfaceSamples, bar: float, extra_axes: np.ndarray | None = None) -> np.ndarray:
    """(A, 3) axes about which every angle of :data:`CONTINUOUS_TEST_DEG` passes the surface bar.

    Tested: the principal axes and any ``extra_axes`` (e.g. the candidates' own axes).
    """
    axes = principal_axes(s)
    if extra_axes is not None and len(extra_axes):
        axes = np.concatenate([axes, np.asarray(extra_axes, np.float64).reshape(-1, 3)])
    found: list[np.ndarray] = []
    for ax in axes:
        ax = ax / np.linalg.norm(ax)
        if any(abs(float(ax @ f)) > np.cos(np.radians(SAME_DEG)) for f in found):
            continue
        d = surface_distance(s, np.stack([axis_angle(ax[None], t)[0] for t in CONTINUOUS_TEST_DEG]))
        if (d < bar).all():
            found.append(ax)
    return np.asarray(found).reshape(-1, 3)


def modulo_continuous(R: np.ndarray, axes: np.ndarray, same_deg: float = 5.0) -> np.ndarray:
    """Indices of the rotations R (C, 3, 3) not already generated by the continuous ``axes`` and the
    rotations kept before them (their group)."""
    if len(axes) == 0:
        return np.arange(len(R))
    kept: list[int] = []
    for i, r in enumerate(R):
        group = Symmetries(np.concatenate([np.eye(3)[None], R[kept]]) if kept else np.eye(3)[None], axes)
        if continuous_symmetric_geodesic_deg(r[None], np.eye(3)[None], group)[0] >= same_deg:
            kept.append(i)
    return np.asarray(kept, dtype=int)
