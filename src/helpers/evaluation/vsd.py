"""Visible Surface Discrepancy (VSD; Hodan et al. 2016, the BOP toolkit's definition since BOP'19).

The T-LESS protocol of the paper scores a rotation by err_vsd <= 0.3, computed from three depth images of one
view: the test image's depth (the scene as captured), and depth renders of the object alone at the estimated
and at the ground-truth pose (the paper: estimated rotation with the ground-truth translation).

Conventions (all functions here):

* Depth images are (H, W) arrays of the z coordinate in the camera frame (OpenCV camera), 0 where nothing was
  measured or rendered. They are turned into *distance* images (distance from the camera centre to the 3D point
  seen at each pixel, the BOP toolkit's choice) with the intrinsics ``K`` (3, 3); pixel (u, v) = (column, row)
  back-projects through ((u - cx) / fx, (v - cy) / fy, 1), without a half-pixel offset, as in the toolkit
  (this study's renderer puts pixel centres at +0.5 in its ``K``: the two differ by half a pixel's ray slope,
  below 0.1 % of a distance at our focal lengths).
* ``delta`` (visibility tolerance) and ``tau`` (misalignment tolerance) are in the depth images' unit; the paper
  and BOP use 15 mm and 20 mm on T-LESS, so pass 15 and 20 for millimetre depth, 0.015 and 0.020 for metres.
* Visibility ("bop19" mode): a rendered pixel is visible where it is not more than ``delta`` behind the test
  surface, or where the test image has no depth (missing depth counts as visible). The estimated pose's mask also
  keeps the pixels visible in the ground-truth mask that the estimate covers (the toolkit's rule that keeps an
  occluded-but-correct estimate from being penalised).
* Cost "step": a pixel of the union of both visible masks costs 1 unless it lies in both masks with rendered
  distances within ``tau``; err_vsd = mean cost over the union (1 when the union is empty).
  Cost "tlinear" (the 2016 paper): min(1, |difference| / tau) inside the intersection, 1 outside it.
"""

from __future__ import annotations

import numpy as np

COSTS = ("step", "tlinear")


def depth_to_distance(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(H, W) distance from the camera centre of each pixel's 3D point; 0 where ``depth`` is 0."""
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth_to_distance: depth must be (H, W), got {depth.shape}")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"depth_to_distance: K must be a (3, 3) intrinsic matrix with fx, fy > 0, got {K}")
    h, w = depth.shape
    x = (np.arange(w) - K[0, 2]) / K[0, 0]  # (W,) ray slope per column
    y = (np.arange(h) - K[1, 2]) / K[1, 1]  # (H,) ray slope per row
    return depth * np.sqrt(1.0 + x[None, :] ** 2 + y[:, None] ** 2)


def visible_mask(dist_test: np.ndarray, dist_model: np.ndarray, delta: float) -> np.ndarray:
    """(H, W) bool: pixels of the rendered model surface not hidden in the test image ("bop19" mode)."""
    if dist_test.shape != dist_model.shape:
        raise ValueError(f"visible_mask: test {dist_test.shape} and model {dist_model.shape} images differ in size")
    behind = dist_model - dist_test  # > delta: the test surface lies in front of the model (occluded there)
    return (dist_model > 0) & ((behind <= delta) | (dist_test == 0))


def vsd_error(depth_est: np.ndarray, depth_gt: np.ndarray, depth_test: np.ndarray, K: np.ndarray,
              delta: float, tau: float, cost: str = "step") -> float:
    """err_vsd in [0, 1] of one estimate from the three (H, W) depth images (see the module's conventions)."""
    if cost not in COSTS:
        raise ValueError(f"vsd_error: cost must be one of {COSTS}, got {cost!r}")
    if not (delta > 0 and tau > 0):
        raise ValueError(f"vsd_error: delta and tau must be > 0, got delta={delta}, tau={tau}")
    shapes = {np.shape(depth_est), np.shape(depth_gt), np.shape(depth_test)}
    if len(shapes) != 1:
        raise ValueError(f"vsd_error: depth images differ in size: {sorted(shapes)}")
    seen = np.asarray(depth_gt)[np.asarray(depth_gt) > 0]
    if seen.size and tau > 0.5 * float(np.median(seen)):
        # e.g. tau=20 (mm) with depth in metres: every pixel would count as aligned.
        raise ValueError(f"vsd_error: tau={tau} is over half the object's median depth {float(np.median(seen)):.4g}; "
                         "delta and tau must be in the depth images' unit (15/20 for mm, 0.015/0.02 for m)")
    d_test, d_gt, d_est = (depth_to_distance(d, K) for d in (depth_test, depth_gt, depth_est))
    vis_gt = visible_mask(d_test, d_gt, delta)
    vis_est = visible_mask(d_test, d_est, delta) | (vis_gt & (d_est > 0))
    union = vis_gt | vis_est
    n_union = int(union.sum())
    if n_union == 0:
        return 1.0
    inter = vis_gt & vis_est
    diff = np.abs(d_gt[inter] - d_est[inter])
    inside = (diff >= tau).astype(np.float64) if cost == "step" else np.minimum(1.0, diff / tau)
    return float((inside.sum() + (n_union - int(inter.sum()))) / n_union)


def vsd_accuracy(errors: np.ndarray, threshold: float = 0.3) -> float:
    """Share (%) of estimates with err_vsd <= ``threshold`` (the paper's T-LESS Rota. Acc.)."""
    errors = np.asarray(errors, dtype=np.float64)
    if errors.size == 0:
        raise ValueError("vsd_accuracy: no errors given")
    return float(100.0 * np.mean(errors <= threshold))
