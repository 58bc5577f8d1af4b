"""Training-time augmentation of query crops.

Works on uint8 RGB numpy images (S, S, 3), the format of
:class:`helpers.core.views.ObjectViews`, with OpenCV; each image is processed on
its own so per-image magnitudes are independent. References (clean renders)
are not augmented.

Training queries may be stored with context around the crop (side C > S, the
crop being the central S x S). The in-plane augmentation follows the
authors' code: rotate the WHOLE stored view (canvas enlarged, corners zero,
nothing mirrored, nothing cut), then re-take the object's tight square box
from the rotated mask and resize it to S. Un-rotated queries take the
central crop.

Order: in-plane rotation / crop (geometry, changes the label) -> occlusion -> HSV
jitter -> blur -> noise (sensor-like effects last, so they also cover the
occluder). Every random draw comes from the caller's ``numpy.random.Generator``
and happens in a fixed order whatever the switches, so a given seed and
config always give the same result.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.special import ndtri

from ..core.configs import AugmentConfig
from ..core.rotations import inplane_rotate_label
from ..data.render import crop_affine, silhouette_box


def rotate_inplane(image: np.ndarray, angle_deg: float, mask: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Rotate (H, W, 3) uint8 and its (H, W) bool mask about the image centre by
    ``angle_deg`` (positive = counter-clockwise on screen) on an enlarged canvas.

    The canvas grows to hold every rotated pixel, so nothing is cut; new area is
    zero (black, mask False), nothing is mirrored. ``mask`` None = the whole image.
    Returns the rotated image (H', W', 3) and mask (H', W').
    """
    h, w = image.shape[:2]
    if mask is None:
        mask = np.ones((h, w), bool)
    m = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), float(angle_deg), 1.0)
    c, s = abs(m[0, 0]), abs(m[0, 1])
    nw, nh = int(math.ceil(w * c + h * s - 1e-9)), int(math.ceil(w * s + h * c - 1e-9))
    m[0, 2] += (nw - w) / 2.0
    m[1, 2] += (nh - h) / 2.0
    img = cv2.warpAffine(image, m, (nw, nh), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    msk = cv2.warpAffine(mask.astype(np.uint8) * 255, m, (nw, nh), flags=cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 127
    return img, msk


def box_crop(image: np.ndarray, mask: np.ndarray, size: int) -> np.ndarray:
    """The mask's tight bounding box made square (no margin), cropped and resized to
    ``size`` x ``size`` (zero padding where the square leaves the image)."""
    cx, cy, side = silhouette_box(mask)
    M = crop_affine(cx, cy, side, size)
    return cv2.warpAffine(image, M, (size, size), flags=cv2.INTER_AREA, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=0)


def centre_crop(image: np.ndarray, size: int) -> np.ndarray:
    """The central ``size`` x ``size`` pixels of a (C, C, 3) view stored with context."""
    c = image.shape[0]
    if c < size:
        raise ValueError(f"centre_crop: image of {c} px is smaller than the crop ({size} px)")
    o = (c - size) // 2
    return image[o:o + size, o:o + size]


def hsv_jitter(image: np.ndarray, hue_deg: float, sat_scale: float, val_scale: float) -> np.ndarray:
    """Shift hue by ``hue_deg`` degrees and scale saturation/value; uint8 RGB in and out."""
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV).astype(np.float32)
    # OpenCV stores 8-bit hue as degrees / 2 in [0, 180).
    hsv[..., 0] = np.mod(hsv[..., 0] + hue_deg / 2.0, 180.0)
    hsv[..., 1] = np.clip(hsv[..., 1] * sat_scale, 0, 255)
    hsv[..., 2] = np.clip(hsv[..., 2] * val_scale, 0, 255)
    return cv2.cvtColor(hsv.round().astype(np.uint8), cv2.COLOR_HSV2RGB)


def occlude(image: np.ndarray, rng: np.random.Generator, min_frac: float, max_frac: float) -> np.ndarray:
    """Paint a random rectangle (random colour + noise) covering a fraction of the image."""
    h, w = image.shape[:2]
    area = rng.uniform(min_frac, max_frac) * h * w
    aspect = np.exp(rng.uniform(np.log(0.5), np.log(2.0)))
    rh = int(np.clip(round(np.sqrt(area * aspect)), 1, h))
    rw = int(np.clip(round(np.sqrt(area / aspect)), 1, w))
    y0 = int(rng.integers(0, h - rh + 1))
    x0 = int(rng.integers(0, w - rw + 1))
    colour = rng.uniform(0, 255, size=3)
    patch = colour + rng.normal(0.0, 20.0, size=(rh, rw, 3))
    out = image.copy()
    out[y0:y0 + rh, x0:x0 + rw] = np.clip(patch, 0, 255).round().astype(np.uint8)
    return out


def augment_image(image: np.ndarray, rotation: np.ndarray, rng: np.random.Generator,
                  cfg: AugmentConfig, mask: np.ndarray | None = None,
                  size: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Augment one query.

    Args:
        image: (C, C, 3) uint8 RGB, the crop (C = size) or the crop with context
            around it (C > size, crop = central size x size).
        rotation: (3, 3) R_m2c label.
        rng: source of all randomness.
        cfg: switches and magnitudes.
        mask: (C, C) bool visible-object mask (the in-plane augmentation re-takes
            the box from it; None = the whole image).
        size: output side (default C).

    Returns:
        (image (size, size, 3) uint8, rotation (3, 3) float64) -- the rotation
        changes only with the in-plane augmentation.
    """
    if image.ndim != 3 or image.shape[-1] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image: expected (S,S,3) uint8, got {image.shape} {image.dtype}")
    rotation = np.asarray(rotation, dtype=np.float64)
    size = image.shape[0] if size is None else int(size)
    if not cfg.enabled:
        return np.ascontiguousarray(centre_crop(image, size)), rotation
    # Draw every scalar up front, in a fixed order, so switches do not shift the stream.
    u = rng.uniform(size=9)
    angle = float(np.clip(cfg.inplane_deg * ndtri(np.clip(u[0], 1e-12, 1 - 1e-12)), -cfg.inplane_max,
                          cfg.inplane_max))
    hue = (2 * u[1] - 1) * cfg.hue_deg
    sat = 1 + (2 * u[2] - 1) * cfg.sat
    val = 1 + (2 * u[3] - 1) * cfg.val
    blur_sigma = 0.1 + u[4] * (cfg.blur_sigma - 0.1)
    noise_std = u[5] * cfg.noise_std
    do_inplane, do_blur, do_occl = u[6] < cfg.inplane_p, u[7] < cfg.blur_p, u[8] < cfg.occlusion_p
    occl_rng = np.random.default_rng(rng.integers(2 ** 63))
    noise_rng = np.random.default_rng(rng.integers(2 ** 63))

    if cfg.inplane and do_inplane and angle != 0.0:
        rot_img, rot_mask = rotate_inplane(image, angle, mask)
        if not rot_mask.any():  # nothing visible to re-take a box from: whole rotated view
            rot_mask = rotate_inplane(image, angle, None)[1]
        out = box_crop(rot_img, rot_mask, size)
        rotation = inplane_rotate_label(rotation, angle)
    else:
        out = centre_crop(image, size)
    if cfg.occlusion and do_occl:
        out = occlude(out, occl_rng, cfg.occlusion_min, cfg.occlusion_max)
    if cfg.hsv:
        out = hsv_jitter(out, hue, sat, val)
    if cfg.blur and do_blur:
        out = cv2.GaussianBlur(out, (0, 0), sigmaX=float(blur_sigma), borderType=cv2.BORDER_REFLECT_101)
    if cfg.noise and noise_std > 0:
        noisy = out.astype(np.float32) + noise_rng.normal(0.0, noise_std, size=out.shape).astype(np.float32)
        out = np.clip(noisy, 0, 255).round().astype(np.uint8)
    return np.ascontiguousarray(out), rotation


def augment_batch(images: np.ndarray, rotations: np.ndarray, rng: np.random.Generator,
                  cfg: AugmentConfig, masks: np.ndarray | None = None,
                  size: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`augment_image` over (B, C, C, 3) uint8, (B, 3, 3) and optional (B, C, C) masks;
    returns new arrays (B, size, size, 3) and (B, 3, 3)."""
    images = np.asarray(images)
    size = images.shape[1] if size is None else int(size)
    out_img = np.empty((len(images), size, size, 3), dtype=np.uint8)
    out_rot = np.empty((len(images), 3, 3), dtype=np.float64)
    for i in range(len(images)):
        out_img[i], out_rot[i] = augment_image(images[i], rotations[i], rng, cfg,
                                               None if masks is None else np.asarray(masks[i]), size)
    return out_img, out_rot
