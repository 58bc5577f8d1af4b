"""Stage 2 of the symmetry rule: a surface candidate is confirmed on appearance, as the network sees it.

For each of the benchmark's query viewpoints R (the object resting on a table in one of its stable
poses, camera on the upper hemisphere: :func:`helpers.data.tabletop.sample_viewpoint`), the object is
rendered as a reference (on black, lit from the camera, textures kept) at R, at R @ S and at
R @ T, where T is a small turn about a random axis. The three renders are brought into the network's
input space (grey, local normalisation: :func:`helpers.core.local_norm.preprocess`) and compared by
their mean absolute difference. The view's ratio is diff(R, R @ S) / diff(R, R @ T): below 1 means
that, seen as the network sees it, the symmetric view is closer than a small turn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...core.configs import QueryStyle, RenderConfig
from ...core.local_norm import images_to_tensor, preprocess
from ..meshes import ObjectMesh
from ..render import render_reference
from ..tabletop import sample_viewpoint
from .surface import axis_angle


@dataclass(frozen=True)
class ViewSet:
    """The viewpoints and small turns one object's candidates are judged on.

    Attributes:
        R: (V, 3, 3) query-like viewpoints ``R_m2c``.
        T: (V, 3, 3) one small turn per view (model frame).
        base: (V, 1, S, S) float32 network input of the renders at R.
        small: (V,) mean absolute difference between the renders at R and at R @ T.
        images: (V, S, S, 3) uint8 renders at R (for figures).
    """

    R: np.ndarray
    T: np.ndarray
    base: torch.Tensor
    small: np.ndarray
    images: np.ndarray


def _net_input(images: list[np.ndarray], window: int) -> torch.Tensor:
    return preprocess(images_to_tensor(np.stack(images)), local_norm=True, window=window)


def render_views(obj: ObjectMesh, R: np.ndarray, cfg: RenderConfig) -> list[np.ndarray]:
    """Reference-style renders (S, S, 3) uint8 of ``obj`` at each of the (V, 3, 3) rotations."""
    return [render_reference(obj, r, cfg)[0] for r in R]


def view_set(obj: ObjectMesh, n_views: int, small_turn_deg: float, cfg: RenderConfig, style: QueryStyle,
             window: int, seed: int) -> ViewSet:
    """Draw ``n_views`` query-like viewpoints with their small turns and render both."""
    rng = np.random.default_rng(seed)
    R = np.stack([sample_viewpoint(obj, rng, style.elevation_deg, style.roll_deg).R_m2c for _ in range(n_views)])
    axes = rng.standard_normal((n_views, 3))  # isotropic: a uniformly random axis per view
    T = axis_angle(axes / np.linalg.norm(axes, axis=1, keepdims=True), small_turn_deg)
    imgs = render_views(obj, R, cfg)
    base = _net_input(imgs, window)
    turned = _net_input(render_views(obj, R @ T, cfg), window)
    small = (base - turned).abs().mean(dim=(1, 2, 3)).numpy()
    return ViewSet(R, T, base, small, np.stack(imgs))


def candidate_ratios(obj: ObjectMesh, views: ViewSet, S: np.ndarray, cfg: RenderConfig, window: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per-view ratios (V,) diff(R, R @ S) / diff(R, R @ T) for one candidate ``S`` (3, 3), and the
    renders (V, S, S, 3) uint8 at R @ S."""
    imgs = render_views(obj, views.R @ S, cfg)
    diff = (views.base - _net_input(imgs, window)).abs().mean(dim=(1, 2, 3)).numpy()
    return diff / np.maximum(views.small, 1e-9), np.stack(imgs)


def summarise(ratios: np.ndarray) -> dict:
    """Median ratio and the share of views below 1 (the evidence written to the manifest)."""
    r = np.asarray(ratios, np.float64)
    return {"median_ratio": round(float(np.median(r)), 4), "share_below_1": round(float((r < 1.0).mean()), 4),
            "n_views": int(len(r))}
