"""LineMOD-like query views: the object resting on a textured table among clutter.

LineMOD's real queries are objects standing on a cluttered table, seen from the
upper hemisphere by a roughly upright camera. This module renders that:

* the object rests on the table in one of its stable poses (trimesh), turned by
  a random yaw about the table normal;
* the camera looks at the object's centre from an elevation drawn uniformly in
  ``TabletopStyle.elevation_deg`` above the table plane, with a small roll
  (uniform in +-``roll_deg``), at the same distance as the references;
* the table is a large plane textured with a photograph (the train or test
  photos of the manifest), shifted and turned at random so each view sees
  another part of it; primitive clutter objects (boxes, cylinders, spheres,
  cones) of random colour stand around the object, beside or behind it as
  seen from the camera, so they rarely hide it;
* one directional light from above the table plus ambient light.

World frame (this module only): table plane z = 0 under the object, z up.
Camera frame: OpenCV (x right, y down, z forward), as everywhere else. The
label is ``R_m2c = R_w2c @ R_m2w``; the object's model origin sits at
``(0, 0, distance)`` in the camera frame exactly as in reference renders, so a
tight crop of a query and a reference at the same rotation show the same
silhouette (up to the crop's jitter).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from ..core.rotations import rot_z
from .gl import frame_with_minus_z, object_scene, renderer
from .meshes import ObjectMesh

_TT: dict = {"poses": {}, "scenes": {}}

#: Side of the table plane, object diameters (large enough that its far edge
#: stays out of view down to 10 degrees of elevation).
TABLE_SIDE_DIAMETERS = 40.0
#: One photo tile on the table covers this many object diameters.
TABLE_TILE_DIAMETERS = 3.0
#: Clutter primitives kept in every scene (shown or hidden per view).
CLUTTER_POOL = 8


@dataclass(frozen=True)
class Viewpoint:
    """A sampled tabletop viewpoint.

    Attributes:
        R_m2c: (3, 3) label rotation.
        R_w2c: (3, 3) world (table) to camera rotation.
        R_m2w: (3, 3) model to world rotation (stable pose turned by the yaw).
        height: height of the model origin above the table, metres.
        elevation_deg: camera elevation above the table plane, degrees.
        azimuth_deg: camera azimuth around the table normal, degrees.
        roll_deg: camera roll about its optical axis, degrees.
    """

    R_m2c: np.ndarray
    R_w2c: np.ndarray
    R_m2w: np.ndarray
    height: float
    elevation_deg: float
    azimuth_deg: float
    roll_deg: float


def stable_poses(obj: ObjectMesh, min_prob: float = 0.05, max_poses: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Resting rotations (K, 3, 3) of ``obj`` on a plane z = 0 and their probabilities (K,).

    trimesh's quasi-static estimate on the convex hull (centre of mass taken as the
    surface centroid, robust for meshes that are not watertight); poses below
    ``min_prob`` are dropped (the most likely one is always kept), the rest renormalised.
    """
    key = (obj.name, obj.sha256, obj.diameter)
    hit = _TT["poses"].get(key)
    if hit is not None:
        return hit
    try:
        T, p = trimesh.poses.compute_stable_poses(obj.mesh, center_mass=obj.mesh.centroid, n_samples=1)
    except Exception as e:  # degenerate hulls: name the object instead of a bare qhull error
        raise ValueError(f"object {obj.name!r}: stable resting poses could not be computed ({e})") from None
    if len(T) == 0:
        raise ValueError(f"object {obj.name!r}: trimesh found no stable resting pose")
    order = np.argsort(-p)[:max_poses]
    keep = [i for i in order if p[i] >= min_prob] or [order[0]]
    R = np.stack([T[i][:3, :3] for i in keep]).astype(np.float64)
    prob = np.asarray([p[i] for i in keep], dtype=np.float64)
    _TT["poses"][key] = (R, prob / prob.sum())
    return _TT["poses"][key]


def look_at_w2c(elevation_deg: float, azimuth_deg: float, roll_deg: float) -> np.ndarray:
    """World-to-camera rotation (3, 3) of an OpenCV camera on the sphere around the origin.

    The camera sits at elevation/azimuth (degrees; z up) and looks at the origin,
    image y pointing down the world up axis when ``roll_deg`` = 0; the roll turns
    the picture by ``roll_deg`` (positive: counter-clockwise on screen, as
    ``cv2.getRotationMatrix2D``).
    """
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    pos = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    z = -pos
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world coordinates
    return rot_z(-math.radians(roll_deg)) @ R


def sample_viewpoint(obj: ObjectMesh, rng: np.random.Generator, elevation_deg: tuple[float, float],
                     roll_deg: float) -> Viewpoint:
    """Draw a resting pose, a yaw, a camera elevation/azimuth and a roll (all uniform)."""
    R_rest, prob = stable_poses(obj)
    k = int(rng.choice(len(prob), p=prob))
    R_m2w = _rz(rng.uniform(0, 2 * math.pi)) @ R_rest[k]
    height = float(-(obj.mesh.vertices @ R_m2w.T)[:, 2].min())
    elev = float(rng.uniform(*elevation_deg))
    azim = float(rng.uniform(0, 360))
    roll = float(rng.uniform(-roll_deg, roll_deg))
    R_w2c = look_at_w2c(elev, azim, roll)
    return Viewpoint(R_w2c @ R_m2w, R_w2c, R_m2w, height, elev, azim, roll)


def elevation_of(R_m2c: np.ndarray, up_model: np.ndarray) -> float:
    """Camera elevation (degrees) implied by a label, given the table normal in model coordinates.

    The viewing ray is +z of the camera; elevation = asin(-(z_cam . up_cam)).
    """
    up_cam = np.asarray(R_m2c) @ np.asarray(up_model, dtype=np.float64)
    return float(math.degrees(math.asin(np.clip(-up_cam[2], -1.0, 1.0))))


# ------------------------------------------------------------------ scene

def table_texture(photo: np.ndarray, contrast: float) -> np.ndarray:
    """The photo as a table surface: its contrast about its mean colour scaled by ``contrast``
    (a table top is smoother than a photograph), (H, W, 3) uint8."""
    p = photo.astype(np.float32)
    mean = p.reshape(-1, 3).mean(axis=0)
    return np.clip(np.rint(mean + contrast * (p - mean)), 0, 255).astype(np.uint8)


def _table_mesh(photo: np.ndarray, diameter: float):
    """A square plane (z = 0, normal +z) textured with ``photo`` repeated every few object diameters."""
    import pyrender
    from PIL import Image

    half = TABLE_SIDE_DIAMETERS * diameter / 2
    v = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    reps = TABLE_SIDE_DIAMETERS / TABLE_TILE_DIAMETERS
    uv = np.array([[0, 0], [reps, 0], [reps, reps], [0, reps]], dtype=np.float64)
    tex = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(photo))
    return pyrender.Mesh.from_trimesh(trimesh.Trimesh(v, f, visual=tex, process=False), smooth=False)


def _clutter_meshes(diameter: float) -> list:
    """Unit-height primitives (base on z = 0) as pyrender meshes, scaled per view by their node."""
    import pyrender

    prims = [trimesh.creation.box(extents=(1.0, 0.7, 1.0)), trimesh.creation.cylinder(radius=0.35, height=1.0),
             trimesh.creation.icosphere(subdivisions=2, radius=0.5), trimesh.creation.cone(radius=0.45, height=1.0),
             trimesh.creation.box(extents=(0.5, 1.2, 0.6)), trimesh.creation.capsule(height=0.5, radius=0.25),
             trimesh.creation.cylinder(radius=0.5, height=0.4), trimesh.creation.box(extents=(0.3, 0.3, 1.0))]
    out = []
    for i in range(CLUTTER_POOL):
        m = prims[i % len(prims)].copy()
        m.apply_translation([0, 0, -m.bounds[0, 2]])  # base on z = 0
        m.apply_scale(diameter)
        mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=[0.5, 0.5, 0.5, 1.0], metallicFactor=0.0,
                                                 roughnessFactor=0.8)
        out.append(pyrender.Mesh.from_trimesh(m, material=mat, smooth=False))
    return out


def _family_meshes(family: "ClutterFamily", diameter: float) -> list:
    """A clutter family's meshes as pyrender meshes: each resting on z = 0 and scaled to ``diameter``
    (the node's per-view scale then applies the family's size range)."""
    import pyrender

    out = []
    for m in family.meshes:
        m = m.copy()
        m.apply_translation(-m.bounds.mean(axis=0))
        m.apply_scale(diameter / float(np.linalg.norm(m.extents)))
        m.apply_translation([0, 0, -m.bounds[0, 2]])
        mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=[*family.color, 1.0], metallicFactor=0.0,
                                                 roughnessFactor=0.7)
        out.append(pyrender.Mesh.from_trimesh(m, material=mat, smooth=False))
    return out


@dataclass(frozen=True)
class ClutterFamily:
    """Clutter other than the default primitives, e.g. other parts of the same family (T-LESS-like scenes).

    Attributes:
        key: names the family (scenes keep one pool per key).
        meshes: the clutter meshes (any units; each is scaled to the object's diameter, then by the style's
            ``clutter_size``).
        color: RGB in [0, 1] of every clutter mesh (jittered per view by the style's ``color_scale``).
        azimuth_deg: (min, max) clutter azimuth from the camera's, degrees: (70, 290) keeps it beside or
            behind the object; (0, 360) lets it stand in front and hide part of it.
    """

    key: str
    meshes: tuple
    color: tuple[float, float, float]
    azimuth_deg: tuple[float, float] = (0.0, 360.0)


def _scene_nodes(obj: ObjectMesh, cfg, photos: dict[str, np.ndarray], contrast: float,
                 family: ClutterFamily | None = None):
    """The object's scene from :mod:`helpers.data.render` with a table plane per photo and the
    clutter pool added once (all hidden until a view shows them)."""
    base = object_scene(obj, cfg)
    scene = base[0]
    extra = _TT["scenes"].setdefault(id(scene), {"tables": {}, "clutter": None, "families": {}})
    for name, photo in photos.items():
        if (name, contrast) not in extra["tables"]:
            node = scene.add(_table_mesh(table_texture(photo, contrast), obj.diameter), pose=np.eye(4))
            node.mesh.is_visible = False
            extra["tables"][(name, contrast)] = node
    if extra["clutter"] is None:
        extra["clutter"] = [scene.add(m, pose=np.eye(4)) for m in _clutter_meshes(obj.diameter)]
        for n in extra["clutter"]:
            n.mesh.is_visible = False
    if family is not None and family.key not in extra["families"]:
        extra["families"][family.key] = [scene.add(m, pose=np.eye(4)) for m in _family_meshes(family, obj.diameter)]
        for n in extra["families"][family.key]:
            n.mesh.is_visible = False
    return base, extra


def pose4(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 rigid pose from rotation (3, 3) and translation (3,)."""
    P = np.eye(4)
    P[:3, :3] = R
    P[:3, 3] = t
    return P


def _rz(a: float) -> np.ndarray:
    """Rotation (3, 3) by ``a`` radians about the world's up (z) axis."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _place_clutter(scene, pool: list, style, vp: Viewpoint, d: float, to_cam, rng: np.random.Generator,
                   family: ClutterFamily | None) -> list:
    """Show and pose ``style.n_clutter`` nodes of ``pool`` on the table around the object (``d``: its
    diameter, metres; ``to_cam``: table coordinates -> camera frame); returns the nodes shown."""
    n_clutter = int(rng.integers(style.n_clutter[0], style.n_clutter[1] + 1))
    # Default: beside or behind the object as seen from the camera (at least 70 deg away from the
    # camera's azimuth), so clutter seldom stands between the camera and the object.
    az_lo, az_hi = (70.0, 290.0) if family is None else family.azimuth_deg
    picks = rng.permutation(len(pool))[:n_clutter]
    shown = []
    for j in picks:
        node = pool[int(j)]
        s = float(rng.uniform(*style.clutter_size))
        phi = math.radians(vp.azimuth_deg) + math.radians(rng.uniform(az_lo, az_hi))
        r = max(float(rng.uniform(*style.clutter_distance)), 0.5 + 0.65 * s) * d
        R = vp.R_w2c @ _rz(rng.uniform(0, 2 * math.pi))
        node.mesh.is_visible = True
        rgb = rng.uniform(0.05, 1.0, 3)
        if family is not None:  # the family's colour, jittered like the object's
            rgb = np.clip(np.asarray(family.color) * (1 + rng.uniform(-style.color_scale, style.color_scale, 3)), 0, 1)
        node.mesh.primitives[0].material.baseColorFactor = np.array([*rgb, 1.0], np.float32)
        scene.set_pose(node, pose4(R * s, to_cam(np.array([r * math.cos(phi), r * math.sin(phi), -vp.height]))))
        shown.append(node)
    return shown


def render_tabletop(obj: ObjectMesh, cfg, style, photos: dict[str, np.ndarray], rng: np.random.Generator,
                    family: ClutterFamily | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Viewpoint]:
    """Render one tabletop view (full frame, before cropping).

    Args:
        cfg: :class:`helpers.data.render.RenderConfig` (camera distance and field of view as references).
        style: :class:`helpers.data.render.QueryStyle` (tabletop fields: elevation, roll,
            clutter count/size/distance, light).
        photos: name -> (H, W, 3) uint8 table textures; one is drawn per view.
        family: clutter drawn from these meshes instead of the default primitives (None: the
            LineMOD-like scenes, unchanged).

    Returns:
        colour (R, R, 3) uint8, depth (R, R) float32 metres, full object silhouette
        (R, R) bool (ignoring clutter), visible object mask (R, R) bool, and the viewpoint.
    """
    import pyrender

    vp = sample_viewpoint(obj, rng, style.elevation_deg, style.roll_deg)
    (scene, obj_node, light, light_node, (pm, base_colors)), extra = _scene_nodes(obj, cfg, photos,
                                                                                   style.table_contrast, family)
    d = obj.diameter
    centre = np.array([0.0, 0.0, cfg.distance_diameters * d])  # model origin, camera frame

    def to_cam(p_world: np.ndarray) -> np.ndarray:
        return centre + vp.R_w2c @ p_world

    names = sorted(photos)
    table = extra["tables"][(names[int(rng.integers(len(names)))], style.table_contrast)]
    tile = TABLE_TILE_DIAMETERS * d
    off = np.array([rng.uniform(-tile, tile), rng.uniform(-tile, tile), -vp.height])
    table.mesh.is_visible = True
    scene.set_pose(table, pose4(vp.R_w2c @ _rz(rng.uniform(0, 2 * math.pi)), to_cam(off)))

    pool = extra["clutter"] if family is None else extra["families"][family.key]
    shown = _place_clutter(scene, pool, style, vp, d, to_cam, rng, family)

    # Light from above the table: elevation 30-90 deg, any azimuth; direction it travels, camera frame.
    le, la = math.radians(rng.uniform(30, 90)), rng.uniform(0, 2 * math.pi)
    to_light = np.array([math.cos(le) * math.cos(la), math.cos(le) * math.sin(la), math.sin(le)])
    cs = 1.0 + rng.uniform(-style.color_scale, style.color_scale, size=3)
    for prim, b in zip(pm.primitives, base_colors):
        c = b.copy()
        c[:3] = np.clip(c[:3] * cs.astype(np.float32), 0, 1)
        prim.material.baseColorFactor = c
    scene.ambient_light = np.full(3, float(rng.uniform(*style.ambient)))
    scene.set_pose(obj_node, pose4(vp.R_m2c, centre))
    lp = np.eye(4)
    lp[:3, :3] = frame_with_minus_z(vp.R_w2c @ -to_light)
    scene.set_pose(light_node, lp)
    light.intensity = float(rng.uniform(*style.light_intensity))
    r = renderer(cfg.render_size)
    try:
        color, depth = r.render(scene)
        _, obj_depth = r.render(scene, flags=pyrender.RenderFlags.SEG, seg_node_map={obj_node: (255, 255, 255)})
    finally:  # reference renders share this scene: hide the table and clutter again
        table.mesh.is_visible = False
        for node in shown:
            node.mesh.is_visible = False
    full = obj_depth > 0
    # Visible where the scene's nearest surface is the object's own. The two passes' depths
    # differ by a few millimetres (multisampled colour pass vs plain segmentation pass), so
    # only a surface more than 3 % of the diameter in front counts as hiding the object.
    visible = full & (depth >= obj_depth - 0.03 * d)
    return np.ascontiguousarray(color[..., :3]), depth.astype(np.float32), full, visible, vp
