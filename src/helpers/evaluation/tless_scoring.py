"""Scores of estimated rotations on the T-LESS-like set or a real BOP T-LESS (:mod:`helpers.data.tless`).

A query is correct when err_vsd (:mod:`helpers.evaluation.vsd`) <= 0.3, computed, as in the paper, with
the estimated rotation and the ground-truth translation: depth renders of the part at both poses
against the query's depth image (metres). The symmetric geodesic error (degrees) is reported beside it.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from ..core.rotations import symmetric_geodesic_deg
from ..data.bop import BOPFormatError
from ..data.gl import render_depth_at, render_raw
from ..data.tless import TlessSet
from .vsd import vsd_error

#: VSD tolerances of the paper and BOP on T-LESS, metres (our depth unit), and the correctness threshold.
VSD_DELTA_M, VSD_TAU_M, VSD_THRESHOLD = 0.015, 0.020, 0.3


@lru_cache(maxsize=8)
def _depth_scales(scene: Path) -> dict[str, float]:
    """im_id -> depth_scale (mm per depth unit) of one BOP scene, read once per scene."""
    cams = json.loads((scene / "scene_camera.json").read_text())
    return {k: float(v.get("depth_scale", 1.0)) for k, v in cams.items()}


def _bop_depth(inst) -> np.ndarray:
    """The instance image's depth (H, W) in metres (BOP: uint16 x depth_scale mm)."""
    scene = inst.rgb_path.parent.parent
    scale = _depth_scales(scene)[str(inst.im_id)]
    path = scene / "depth" / f"{inst.im_id:06d}.png"
    d = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if d is None:
        raise BOPFormatError(f"{path}: missing or unreadable depth image (err_vsd needs the test depth)")
    return d.astype(np.float32) * scale / 1000.0


def _bop_vsd_errors(tset: TlessSet, name: str, R_est: np.ndarray, idx: list[int]) -> np.ndarray:
    obj, out = tset.parts[name], np.empty(len(idx))
    for k, (Re, i) in enumerate(zip(R_est, idx)):
        inst = tset.instances[name][i]
        test = _bop_depth(inst)
        h, w = test.shape
        t = inst.t_m2c / 1000.0
        d_est = render_depth_at(obj, np.asarray(Re, np.float64), t, inst.K, w, h)
        d_gt = render_depth_at(obj, inst.R_m2c, t, inst.K, w, h)
        out[k] = vsd_error(d_est, d_gt, test, inst.K, VSD_DELTA_M, VSD_TAU_M)
    return out


def vsd_errors(tset: TlessSet, name: str, R_est: np.ndarray, indices: list[int] | None = None) -> np.ndarray:
    """(N,) err_vsd of estimated rotations (N, 3, 3) for part ``name``'s queries ``indices`` (default: all, in
    order): depth renders at the estimated and true rotation with the true translation, against the scene's
    depth (metres; tolerances VSD_DELTA_M, VSD_TAU_M)."""
    obj, rc = tset.parts[name], tset.cfg.render_config()
    K = rc.intrinsics()
    idx = list(range(len(tset.queries[name]))) if indices is None else list(indices)
    if len(R_est) != len(idx):
        raise ValueError(f"vsd_errors: {len(R_est)} estimates for {len(idx)} queries of {name!r}")
    if tset.instances:
        return _bop_vsd_errors(tset, name, R_est, idx)
    out = np.empty(len(idx))
    for k, (Re, i) in enumerate(zip(R_est, idx)):
        d_est = render_raw(obj, np.asarray(Re, np.float64), rc)[1]
        d_gt = render_raw(obj, tset.queries[name].rotations[i].astype(np.float64), rc)[1]
        out[k] = vsd_error(d_est, d_gt, tset.depth[name][i].astype(np.float32), K, VSD_DELTA_M, VSD_TAU_M)
    return out


def rotation_errors(tset: TlessSet, name: str, R_est: np.ndarray) -> np.ndarray:
    """(N,) symmetric geodesic error (degrees) of estimated rotations for part ``name``'s queries."""
    q = tset.queries[name]
    return symmetric_geodesic_deg(np.asarray(R_est, np.float64), q.rotations.astype(np.float64), q.symmetries)
