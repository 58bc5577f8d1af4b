"""Offscreen rendering of objects with pyrender, and crops in the method's style.

Two kinds of image come out of here:

* references: the object on black, lit the same way every time, tightly
  cropped around its silhouette and resized to ``size`` x ``size``;
* real-like queries: the same object under random light and material, over a
  photograph, with crop jitter, in-plane rotation, blur, noise and optional
  occluders, so there is a synthetic-to-real style gap to bridge.

Geometry follows OpenCV: the world frame *is* the camera frame (x right,
y down, z forward); objects are posed with ``R_m2c`` at ``(0, 0, distance)``.
pyrender's camera looks down its -z with y up, so its pose in that world is a
half turn about x.

GL rules this module keeps: one ``OffscreenRenderer`` per process, created
lazily and never deleted (with EGL, deleting one tears down the display that
all share); the platform (EGL, else OSMesa) is chosen before PyOpenGL is
imported; worker processes are spawned, never forked after a GL context.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from .meshes import ObjectMesh
from .rotations import inplane_rotate_label

_STATE: dict = {"renderer": None, "platform": None, "meshes": {}, "scenes": {}}


@dataclass(frozen=True)
class RenderConfig:
    """How views are rendered and cropped.

    Attributes:
        size: output crop side, pixels.
        render_size: side of the internal render, pixels (crops are taken from it).
        distance_diameters: camera-object distance in object diameters.
        fov_margin: extra field of view so the whole object always fits.
        crop_pad: crop side / silhouette bbox side (1.0 = tight).
    """

    size: int = 128
    render_size: int = 160
    distance_diameters: float = 2.5
    fov_margin: float = 1.08
    crop_pad: float = 1.0

    def __post_init__(self) -> None:
        for k in ("size", "render_size"):
            v = getattr(self, k)
            if not isinstance(v, int) or v < 16:
                raise ValueError(f"RenderConfig.{k} must be an int >= 16, got {v!r}")
        if self.distance_diameters <= 0.6:
            raise ValueError("RenderConfig.distance_diameters must exceed 0.6 (camera outside the object)")

    def intrinsics(self) -> np.ndarray:
        """3x3 K of the internal render (OpenCV, pixel centres at +0.5)."""
        half = math.asin(0.5 / self.distance_diameters) * self.fov_margin
        f = (self.render_size / 2) / math.tan(half)
        c = self.render_size / 2
        return np.array([[f, 0, c], [0, f, c], [0, 0, 1.0]])


@dataclass(frozen=True)
class QueryStyle:
    """How real-like query views are made (ranges sampled uniformly).

    Two scenes: ``"tabletop"`` (the default benchmark, LineMOD-like: the object
    resting on a photo-textured table among clutter, camera on the upper
    hemisphere, see :mod:`helpers.tabletop`) and ``"photo"`` (the ``hard``
    variant: any rotation of SO(3), crop rotated in-plane by up to
    ``inplane_deg``, pasted over a random patch of a full-frame photograph).
    :func:`query_style` gives the named presets.

    Attributes:
        scene: ``"tabletop"`` or ``"photo"``.
        light_intensity: directional light intensity range.
        ambient: ambient light range (0..1).
        light_cone_deg: photo scene: max angle of the light direction from the viewing axis.
        color_scale: per-channel multiplicative material colour jitter (+-).
        crop_shift: max crop-centre shift as a fraction of the crop side.
        crop_scale: max relative change of the crop side (+-).
        inplane_deg: photo scene: max in-plane rotation of the crop (+-), degrees.
        blur_sigma: max Gaussian blur sigma, pixels of the output.
        noise_sigma: max Gaussian noise sigma, grey levels (0..255).
        occlusion: probability a query gets an occluder.
        occlusion_fraction: (min, max) fraction of the silhouette to cover.
        elevation_deg: tabletop: camera elevation range above the table plane, degrees.
        roll_deg: tabletop: max camera roll (+-), degrees.
        n_clutter: tabletop: (min, max) clutter objects on the table.
        clutter_size: tabletop: clutter height range, object diameters.
        clutter_distance: tabletop: clutter distance from the object, object diameters.
        table_contrast: tabletop: contrast of the table photo about its mean colour
            (1 = the photograph as is).
        context: stored crop side / crop side: > 1 keeps a margin of real
            surroundings (training queries, so the in-plane augmentation can
            rotate the whole view and re-take the box without padding).
    """

    scene: str = "photo"
    light_intensity: tuple[float, float] = (1.5, 6.0)
    ambient: tuple[float, float] = (0.1, 0.5)
    light_cone_deg: float = 70.0
    color_scale: float = 0.25
    crop_shift: float = 0.08
    crop_scale: float = 0.12
    inplane_deg: float = 30.0
    blur_sigma: float = 1.2
    noise_sigma: float = 8.0
    occlusion: float = 0.0
    occlusion_fraction: tuple[float, float] = (0.1, 0.4)
    elevation_deg: tuple[float, float] = (15.0, 75.0)
    roll_deg: float = 10.0
    n_clutter: tuple[int, int] = (2, 5)
    clutter_size: tuple[float, float] = (0.3, 0.8)
    clutter_distance: tuple[float, float] = (0.6, 1.4)
    table_contrast: float = 1.0
    context: float = 1.0

    def __post_init__(self) -> None:
        if self.scene not in SCENES:
            raise ValueError(f"QueryStyle.scene must be one of {SCENES}, got {self.scene!r}")
        lo, hi = self.elevation_deg
        if not -90 <= lo <= hi <= 90:
            raise ValueError(f"QueryStyle.elevation_deg must be (lo, hi) within [-90, 90], got {self.elevation_deg!r}")
        if not 1.0 <= self.context <= 2.0:
            raise ValueError(f"QueryStyle.context must be in [1, 2], got {self.context!r}")
        if not 0 <= self.n_clutter[0] <= self.n_clutter[1]:
            raise ValueError(f"QueryStyle.n_clutter must be (min, max) with 0 <= min <= max, got {self.n_clutter!r}")


SCENES = ("tabletop", "photo")

#: Named query styles. ``linemod`` is the default benchmark; ``hard`` is the
#: earlier full-SO(3) style over photographs.
STYLES = {
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


# ---------------------------------------------------------------- GL context

_PROBE = ("import os, sys; os.environ['PYOPENGL_PLATFORM'] = sys.argv[1]; import pyrender; "
          "pyrender.OffscreenRenderer(8, 8); print('ok')")


def gl_platform() -> str:
    """The PyOpenGL platform to use: ``$PYOPENGL_PLATFORM`` if set, else EGL if a
    probe process can open a context, else OSMesa.

    The probe runs in a separate interpreter so a failing platform never
    poisons this process (PyOpenGL fixes its platform at import).
    """
    if _STATE["platform"]:
        return _STATE["platform"]
    plat = os.environ.get("PYOPENGL_PLATFORM")
    if not plat:
        errors = {}
        for cand in ("egl", "osmesa"):
            try:
                res = subprocess.run([sys.executable, "-c", _PROBE, cand], capture_output=True, text=True, timeout=120)
                if res.returncode == 0 and res.stdout.strip().endswith("ok"):
                    plat = cand
                    break
                errors[cand] = (res.stderr.strip().splitlines() or ["?"])[-1]
            except subprocess.TimeoutExpired:
                errors[cand] = "timed out"
        else:
            raise RuntimeError(f"no headless OpenGL: neither EGL nor OSMesa could create a context ({errors}). "
                               "Install libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libopengl0 libosmesa6 "
                               "(scripts/setup.sh does) or set PYOPENGL_PLATFORM.")
        os.environ["PYOPENGL_PLATFORM"] = plat  # inherited by spawned workers
    _STATE["platform"] = plat
    return plat


def _renderer(render_size: int, height: int | None = None):
    """The process-wide OffscreenRenderer (created once, resized as needed): ``render_size`` square, or
    ``render_size`` x ``height`` pixels (width x height) when ``height`` is given."""
    gl_platform()
    import pyrender

    h = render_size if height is None else height
    r = _STATE["renderer"]
    if r is None:
        r = pyrender.OffscreenRenderer(render_size, h)
        _STATE["renderer"] = r
    elif r.viewport_width != render_size or r.viewport_height != h:
        r.viewport_width, r.viewport_height = render_size, h
    return r


def _pyrender_mesh(obj: ObjectMesh):
    import pyrender

    key = (obj.name, obj.sha256, obj.diameter)
    m = _STATE["meshes"].get(key)
    if m is None:
        m = pyrender.Mesh.from_trimesh(obj.mesh, smooth=False)
        base = [np.array(p.material.baseColorFactor, dtype=np.float32).copy() for p in m.primitives]
        _STATE["meshes"][key] = m = (m, base)
    return m


_CV2GL = np.diag([1.0, -1.0, -1.0, 1.0])


def _scene(obj: ObjectMesh, cfg: RenderConfig):
    """A persistent scene per (object, camera setup): building scenes per render
    costs more than the render itself."""
    import pyrender

    key = (obj.name, obj.sha256, obj.diameter, cfg.render_size, cfg.distance_diameters, cfg.fov_margin)
    sc = _STATE["scenes"].get(key)
    if sc is None:
        pm, base = _pyrender_mesh(obj)
        K = cfg.intrinsics()
        scene = pyrender.Scene(bg_color=[0, 0, 0, 0], ambient_light=[0.3] * 3)
        obj_node = scene.add(pm, pose=np.eye(4))
        cam = pyrender.IntrinsicsCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], znear=0.05 * obj.diameter,
                                        zfar=10 * cfg.distance_diameters * obj.diameter)
        scene.add(cam, pose=_CV2GL)
        light = pyrender.DirectionalLight(color=np.ones(3), intensity=3.0)
        light_node = scene.add(light, pose=np.eye(4))
        sc = _STATE["scenes"][key] = (scene, obj_node, light, light_node, (pm, base))
    return sc


def render_raw(obj: ObjectMesh, R_m2c: np.ndarray, cfg: RenderConfig, *,
               light_dir: np.ndarray | None = None, light_intensity: float = 3.0,
               ambient: float = 0.3, color_scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Render ``obj`` at rotation ``R_m2c`` (3, 3) on black.

    Args:
        light_dir: (3,) direction the light travels, camera frame (default: along +z,
            i.e. from the camera).
        light_intensity: directional light intensity (pyrender units).
        ambient: ambient light level 0..1.
        color_scale: (3,) multiplier on the material base colour.

    Returns:
        color (render_size, render_size, 3) uint8 and depth (render_size, render_size)
        float32 metres (0 where empty).
    """
    r = _renderer(cfg.render_size)
    scene, obj_node, light, light_node, (pm, base) = _scene(obj, cfg)
    for prim, b in zip(pm.primitives, base):
        c = b.copy()
        if color_scale is not None:
            c[:3] = np.clip(c[:3] * np.asarray(color_scale, dtype=np.float32), 0, 1)
        prim.material.baseColorFactor = c
    scene.ambient_light = np.full(3, ambient)
    pose = np.eye(4)
    pose[:3, :3] = R_m2c
    pose[2, 3] = cfg.distance_diameters * obj.diameter
    scene.set_pose(obj_node, pose)
    d = np.array([0.0, 0.0, 1.0]) if light_dir is None else np.asarray(light_dir, dtype=np.float64)
    d = d / np.linalg.norm(d)
    # A directional light shines along its node's -z (OpenGL); build a frame whose -z is d.
    lp = np.eye(4)
    lp[:3, :3] = _frame_with_minus_z(d)
    scene.set_pose(light_node, lp)
    light.intensity = light_intensity
    color, depth = r.render(scene)
    return np.ascontiguousarray(color[..., :3]), depth.astype(np.float32)


def render_depth_at(obj: ObjectMesh, R_m2c: np.ndarray, t_m2c: np.ndarray, K: np.ndarray, width: int,
                    height: int) -> np.ndarray:
    """Depth (height, width) float32, metres (0 where empty), of ``obj`` alone at pose (R_m2c (3, 3), t_m2c (3,)
    metres) seen by an OpenCV camera with intrinsics ``K`` (3, 3) and that image size: a real dataset's camera
    (BOP), for err_vsd. The mesh is used in its own model frame (no re-centring)."""
    import pyrender

    key = ("depth_at", obj.name, obj.sha256, obj.diameter)
    scene = _STATE["scenes"].get(key)
    if scene is None:
        pm, _ = _pyrender_mesh(obj)
        scene = pyrender.Scene(bg_color=[0, 0, 0, 0])
        scene.add(pm, pose=np.eye(4), name="object")
        _STATE["scenes"][key] = scene
    for n in [n for n in scene.camera_nodes]:
        scene.remove_node(n)
    t = np.asarray(t_m2c, dtype=np.float64)
    cam = pyrender.IntrinsicsCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], znear=max(1e-3, 0.1 * (t[2] - obj.diameter)),
                                    zfar=t[2] + 10 * obj.diameter)
    scene.add(cam, pose=_CV2GL)
    obj_node = next(iter(scene.get_nodes(name="object")))
    P = np.eye(4)
    P[:3, :3], P[:3, 3] = R_m2c, t
    scene.set_pose(obj_node, P)
    r = _renderer(int(width), int(height))
    return r.render(scene, flags=pyrender.RenderFlags.DEPTH_ONLY).astype(np.float32)


def _frame_with_minus_z(d: np.ndarray) -> np.ndarray:
    z = -d
    a = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


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
    return _frame_with_minus_z(-axis) @ v  # frame whose +z is axis


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
    """Tabletop view (:func:`helpers.tabletop.render_tabletop`), cropped to the visible object's
    square box with modest jitter (zero padding where the square leaves the frame)."""
    from .tabletop import render_tabletop

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
