"""Rendered views in the method's style, built on :mod:`helpers.data.gl` (raw renders).

Two kinds of image come out of here:

* references: the object on black, lit the same way every time, tightly
  cropped around its silhouette and resized to ``size`` x ``size``;
* real-like queries: the same object under random light and material, over a
  photograph or on a table among clutter (:mod:`helpers.data.tabletop`), with crop
  jitter, in-plane rotation, blur, noise and optional occluders, so there is a
  synthetic-to-real style gap to bridge.

Configurations (:class:`helpers.core.configs.RenderConfig`, ``QueryStyle``) live with the
other configurations.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import cv2
import numpy as np

from ..core.configs import QueryStyle, RenderConfig
from ..core.rotations import inplane_rotate_label
from .gl import frame_with_minus_z, render_raw
from .meshes import ObjectMesh
from .tabletop import render_tabletop

#: Named query styles. ``linemod`` is the default benchmark; ``hard`` is the
#: earlier full-SO(3) style over photographs.
STYLES: dict[str, dict] = {  # keys: helpers.core.configs.QUERY_STYLES
    # Calibrated once with HOG nearest neighbour (Dalal-Triggs settings), never with a trained
    # model: 13 benchmark objects x 512 references at 64 px, 100 test queries per object,
    # greedy search: mean unseen Rota. Acc. 31.0 % (paper's HOG on LineMOD: 33.13 %). Sensor
    # blur/noise are small because a real crop is downsampled from a VGA frame.
    "linemod": dict(scene="tabletop", light_intensity=(2.0, 5.0), ambient=(0.2, 0.45), color_scale=0.15,
                    crop_shift=0.03, crop_scale=0.03, blur_sigma=0.5, noise_sigma=2.0, table_contrast=0.3,
                    n_clutter=(1, 4)),
    "hard": dict(scene="photo"),
}


def query_style(name: str = "linemod", **overrides) -> QueryStyle:
    """The named query style (``"linemod"`` or ``"hard"``) with field overrides."""
    if name not in STYLES:
        raise ValueError(f"query style must be one of {sorted(STYLES)}, got {name!r}")
    return QueryStyle(**{**STYLES[name], **overrides})


# ---------------------------------------------------------------- crops

def silhouette_box(mask: np.ndarray) -> tuple[float, float, float]:
    """Centre (cx, cy) and side of the square around a mask's bounding box, pixels."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        raise ValueError("empty silhouette: the object is not in view")
    x0, x1, y0, y1 = xs.min(), xs.max() + 1, ys.min(), ys.max() + 1
    return (x0 + x1) / 2.0, (y0 + y1) / 2.0, float(max(x1 - x0, y1 - y0))


def crop_affine(cx: float, cy: float, side: float, size: int, angle_deg: float = 0.0) -> np.ndarray:
    """2x3 affine taking the square (centre, side, rotated by angle_deg CCW on screen)
    to a ``size`` x ``size`` image."""
    s = size / side
    M = cv2.getRotationMatrix2D((cx, cy), angle_deg, s)
    M[0, 2] += size / 2 - cx
    M[1, 2] += size / 2 - cy
    return M


def reference_crop(color: np.ndarray, depth: np.ndarray, cfg: RenderConfig) -> tuple[np.ndarray, np.ndarray]:
    """Tight square crop around the silhouette: (size,size,3) uint8 and (size,size) bool mask."""
    mask = depth > 0
    cx, cy, side = silhouette_box(mask)
    M = crop_affine(cx, cy, side * cfg.crop_pad, cfg.size)
    img = cv2.warpAffine(color, M, (cfg.size, cfg.size), flags=cv2.INTER_AREA, borderValue=0)
    m = cv2.warpAffine(mask.astype(np.uint8) * 255, M, (cfg.size, cfg.size), flags=cv2.INTER_LINEAR) > 127
    img[~m] = 0  # keep the background exactly black
    return img, m


def render_reference(obj: ObjectMesh, R_m2c: np.ndarray, cfg: RenderConfig) -> tuple[np.ndarray, np.ndarray]:
    """A reference view: fixed light from the camera, no jitter."""
    color, depth = render_raw(obj, R_m2c, cfg, light_intensity=3.0, ambient=0.35)
    return reference_crop(color, depth, cfg)


def _random_unit_in_cone(rng: np.random.Generator, axis: np.ndarray, max_deg: float) -> np.ndarray:
    cos_max = math.cos(math.radians(max_deg))
    z = rng.uniform(cos_max, 1.0)
    phi = rng.uniform(0, 2 * math.pi)
    r = math.sqrt(max(0.0, 1 - z * z))
    v = np.array([r * math.cos(phi), r * math.sin(phi), z])
    return frame_with_minus_z(-axis) @ v  # frame whose +z is axis


def background_patch(bg: np.ndarray, size: int, rng: np.random.Generator) -> np.ndarray:
    """A random square patch of a photo, resized to (size, size, 3) uint8."""
    h, w = bg.shape[:2]
    side = int(rng.uniform(0.25, 0.9) * min(h, w))
    y = int(rng.integers(0, h - side + 1))
    x = int(rng.integers(0, w - side + 1))
    patch = bg[y:y + side, x:x + side]
    if rng.random() < 0.5:
        patch = patch[:, ::-1]
    return cv2.resize(np.ascontiguousarray(patch), (size, size), interpolation=cv2.INTER_AREA)


def add_occluder(img: np.ndarray, mask: np.ndarray, rng: np.random.Generator, fraction: tuple[float, float],
                 texture: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Paint a random ellipse over part of the visible object.

    Grows the ellipse until it covers a fraction of the silhouette drawn from
    ``fraction``. Returns the image and the new visible mask.
    """
    size = img.shape[0]
    target = rng.uniform(*fraction)
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return img, mask
    k = int(rng.integers(len(xs)))
    # Start at a silhouette pixel so the occluder always touches the object.
    cx, cy = int(xs[k]), int(ys[k])
    ang = float(rng.uniform(0, 180))
    ratio = float(rng.uniform(0.4, 1.0))
    occ = np.zeros_like(mask)
    total = mask.sum()
    for r in np.linspace(size * 0.05, size * 0.9, 24):
        occ = np.zeros((size, size), np.uint8)
        cv2.ellipse(occ, (cx, cy), (int(r), max(1, int(r * ratio))), ang, 0, 360, 1, -1)
        occ = occ.astype(bool)
        if (occ & mask).sum() >= target * total:
            break
    fill = texture if texture is not None else np.full_like(img, rng.integers(0, 256, 3, dtype=np.uint8))
    out = img.copy()
    out[occ] = fill[occ]
    return out, mask & ~occ


def _photos(backgrounds) -> list[np.ndarray]:
    return list(backgrounds.values()) if isinstance(backgrounds, dict) else list(backgrounds)


def output_side(cfg: RenderConfig, style: QueryStyle) -> int:
    """Side (pixels) of a stored query image: the crop size times the style's context."""
    return int(round(cfg.size * style.context))


def _jittered_box(mask: np.ndarray, cfg: RenderConfig, style: QueryStyle, rng: np.random.Generator
                  ) -> tuple[float, float, float]:
    """The mask's square box (centre x, y and side, pixels) shifted and scaled by the style's crop jitter."""
    cx, cy, side = silhouette_box(mask)
    cx += rng.uniform(-style.crop_shift, style.crop_shift) * side
    cy += rng.uniform(-style.crop_shift, style.crop_shift) * side
    side *= cfg.crop_pad * (1 + rng.uniform(-style.crop_scale, style.crop_scale))
    return cx, cy, side


def apply_sensor(img: np.ndarray, style: QueryStyle, rng: np.random.Generator) -> np.ndarray:
    """The style's sensor blur and noise on a float image (C, C, 3); uint8 out."""
    sigma = rng.uniform(0, style.blur_sigma)
    if sigma > 0.2:
        img = cv2.GaussianBlur(img, (0, 0), sigma)
    img = img + rng.normal(0, rng.uniform(0, style.noise_sigma), img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def render_query(obj: ObjectMesh, R_m2c: np.ndarray, cfg: RenderConfig, style: QueryStyle,
                 backgrounds, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A real-like query view.

    Args:
        R_m2c: (3, 3) rotation to render (photo scene only; the tabletop scene
            samples its own viewpoint).
        backgrounds: photos, a list of (H, W, 3) uint8 or a dict name -> photo.

    Returns:
        image (C, C, 3) uint8 with C = :func:`output_side`, visible mask (C, C)
        bool, and the label ``R_m2c`` (3, 3) of the view (after any in-plane rotation).
    """
    if style.scene == "tabletop":
        return _render_tabletop_query(obj, cfg, style, backgrounds, rng)
    photos = _photos(backgrounds)
    light = _random_unit_in_cone(rng, np.array([0.0, 0.0, 1.0]), style.light_cone_deg)
    cs = 1.0 + rng.uniform(-style.color_scale, style.color_scale, size=3)
    color, depth = render_raw(obj, R_m2c, cfg, light_dir=light,
                              light_intensity=float(rng.uniform(*style.light_intensity)),
                              ambient=float(rng.uniform(*style.ambient)), color_scale=cs)
    mask = depth > 0
    cx, cy, side = _jittered_box(mask, cfg, style, rng)
    angle = float(rng.uniform(-style.inplane_deg, style.inplane_deg))
    S = output_side(cfg, style)
    M = crop_affine(cx, cy, side * style.context, S, angle)
    obj_img = cv2.warpAffine(color, M, (S, S), flags=cv2.INTER_AREA, borderValue=0).astype(np.float32)
    alpha = cv2.warpAffine(mask.astype(np.float32), M, (S, S), flags=cv2.INTER_LINEAR)[..., None]
    bg = background_patch(photos[int(rng.integers(len(photos)))], S, rng).astype(np.float32)
    img = alpha * obj_img + (1 - alpha) * bg
    vis = alpha[..., 0] > 0.5
    if rng.random() < style.occlusion:
        tex = background_patch(photos[int(rng.integers(len(photos)))], S, rng)
        img8, vis = add_occluder(np.clip(img, 0, 255).astype(np.uint8), vis, rng, style.occlusion_fraction, tex)
        img = img8.astype(np.float32)
    return apply_sensor(img, style, rng), vis, inplane_rotate_label(R_m2c, angle)


def crop_view(color: np.ndarray, visible: np.ndarray, cfg: RenderConfig, style: QueryStyle,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Crop a full-frame view (R, R, 3) uint8 to the visible object's square box (jittered by the style,
    with its context margin, zero padding outside the frame): float32 image (C, C, 3) and mask (C, C) bool,
    C = :func:`output_side`. The sensor's blur and noise are not applied yet."""
    cx, cy, side = _jittered_box(visible, cfg, style, rng)
    S = output_side(cfg, style)
    M = crop_affine(cx, cy, side * style.context, S)
    img = cv2.warpAffine(color, M, (S, S), flags=cv2.INTER_AREA, borderValue=0).astype(np.float32)
    vis = cv2.warpAffine(visible.astype(np.uint8) * 255, M, (S, S), flags=cv2.INTER_LINEAR) > 127
    return img, vis


def _render_tabletop_query(obj: ObjectMesh, cfg: RenderConfig, style: QueryStyle, backgrounds,
                           rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tabletop view (:func:`helpers.data.tabletop.render_tabletop`), cropped to the visible object's
    square box with modest jitter (zero padding where the square leaves the frame)."""
    photos = backgrounds if isinstance(backgrounds, dict) else {f"photo{i}": b for i, b in enumerate(backgrounds)}
    color, _, _, visible, vp = render_tabletop(obj, cfg, style, photos, rng)
    if not visible.any():
        raise ValueError(f"object {obj.name!r}: a tabletop view shows none of the object (clutter in front?)")
    img, vis = crop_view(color, visible, cfg, style, rng)
    if rng.random() < style.occlusion:
        photos_l = _photos(photos)
        tex = background_patch(photos_l[int(rng.integers(len(photos_l)))], img.shape[0], rng)
        img8, vis = add_occluder(np.clip(img, 0, 255).astype(np.uint8), vis, rng, style.occlusion_fraction, tex)
        img = img8.astype(np.float32)
    return apply_sensor(img, style, rng), vis, vp.R_m2c


def config_dict(cfg: RenderConfig, style: QueryStyle | None = None) -> dict:
    """JSON-able description of a render setup (part of cache keys)."""
    d = {"render": asdict(cfg)}
    if style is not None:
        d["style"] = asdict(style)
    return d
