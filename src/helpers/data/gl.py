"""The GL side of rendering: the headless platform, the process's one renderer, scenes, raw renders.

GL rules kept here: one ``OffscreenRenderer`` per process, created lazily and never deleted (with
EGL, deleting one tears down the display that all share); the platform (EGL, else OSMesa) is chosen
before PyOpenGL is imported (``pyrender`` is therefore imported inside the functions, after
:func:`gl_platform`); worker processes are spawned, never forked after a GL context.

Geometry follows OpenCV: the world frame *is* the camera frame (x right, y down, z forward);
objects are posed with ``R_m2c`` at ``(0, 0, distance)``. pyrender's camera looks down its -z
with y up, so its pose in that world is a half turn about x (``_CV2GL``).
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from ..core.configs import RenderConfig
from .meshes import ObjectMesh

_STATE: dict = {"renderer": None, "platform": None, "meshes": {}, "scenes": {}}

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


def renderer(render_size: int, height: int | None = None):
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


def object_scene(obj: ObjectMesh, cfg: RenderConfig):
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
    r = renderer(cfg.render_size)
    scene, obj_node, light, light_node, (pm, base) = object_scene(obj, cfg)
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
    lp[:3, :3] = frame_with_minus_z(d)
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
    r = renderer(int(width), int(height))
    return r.render(scene, flags=pyrender.RenderFlags.DEPTH_ONLY).astype(np.float32)


def frame_with_minus_z(d: np.ndarray) -> np.ndarray:
    z = -d
    a = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)
