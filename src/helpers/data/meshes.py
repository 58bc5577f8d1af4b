"""Load object meshes with trimesh and normalise them.

Manifest meshes come in arbitrary units and origins. They are centred on
their bounding-box centre and scaled to a common diameter (metres), which
the renderer relies on to frame every object the same way. Textures are kept
where the manifest says the object is textured; untextured ones get the
manifest colour.
"""

from __future__ import annotations

import os
from typing import Any
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.distance import pdist

from ..core.fileio import sha256_file
from .manifest import Manifest, ManifestError, load_manifest, verify_file

#: Diameter (metres) every manifest object is scaled to.
DEFAULT_DIAMETER_M = 0.2


@dataclass
class ObjectMesh:
    """A normalised mesh.

    Attributes:
        name: object name.
        mesh: trimesh.Trimesh in metres, model frame.
        diameter: largest vertex-to-vertex distance, metres.
        textured: True if a texture image is attached.
        sha256: checksum of the source mesh file (part of render cache keys).
        symmetries: (K, 3, 3) model-frame symmetry rotations (identity first), or a
            :class:`helpers.core.rotations.Symmetries` for a continuous axis (the manifest's declaration).
    """

    name: str
    mesh: trimesh.Trimesh
    diameter: float
    textured: bool
    sha256: str
    symmetries: Any


def mesh_diameter(vertices: np.ndarray) -> float:
    """Largest pairwise distance of (N, 3) vertices (exact, via the convex hull)."""
    v = np.asarray(vertices, dtype=np.float64)
    if len(v) < 2:
        return 0.0
    try:
        hull = trimesh.convex.convex_hull(v)
        v = hull.vertices
    except Exception:  # degenerate (flat) point sets: fall back to all vertices
        pass
    return float(pdist(v).max())


def load_mesh_file(path: str | os.PathLike) -> trimesh.Trimesh:
    """Load one mesh file (obj/ply/stl/dae...) as a single Trimesh, textures kept.

    Raises ValueError naming the file if it is missing, unreadable or empty.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file {path} does not exist")
    # allow_anywhere: some packages' .mtl files point at textures in sibling folders.
    resolver = trimesh.resolvers.FilePathResolver(str(path.parent), allow_anywhere=True)
    try:
        mesh = trimesh.load(str(path), force="mesh", resolver=resolver, process=False)
    except Exception as e:
        raise ValueError(f"mesh file {path} could not be read as a mesh: {e}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"mesh file {path} holds no triangles")
    defect = mesh_defect(mesh)
    if defect:
        raise ValueError(f"mesh file {path} cannot be rendered: {defect}")
    return mesh


def mesh_defect(mesh: trimesh.Trimesh) -> str | None:
    """What makes ``mesh`` unrenderable (None when nothing does): no triangles, vertices that are not finite
    numbers (a file of ``nan`` vertices loads without complaint and would later render as nothing), or no area."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if len(mesh.faces) == 0 or len(v) == 0:
        return "no triangles"
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        return f"{int(bad.sum())} of {len(v)} vertices are not finite numbers"
    if not mesh.area > 0:
        return "zero surface area"
    return None


def has_texture(mesh: trimesh.Trimesh) -> bool:
    vis = mesh.visual
    return (getattr(vis, "kind", None) == "texture" and getattr(vis, "uv", None) is not None
            and getattr(getattr(vis, "material", None), "image", None) is not None)


def has_vertex_colours(mesh: trimesh.Trimesh) -> bool:
    """Colours stored per vertex (LineMOD's PLY meshes): the renderer draws them as a texture's stand-in."""
    return getattr(mesh.visual, "kind", None) == "vertex"


def normalise(mesh: trimesh.Trimesh, diameter: float = DEFAULT_DIAMETER_M) -> trimesh.Trimesh:
    """Centre on the bounding-box centre and scale to ``diameter`` metres (copy)."""
    mesh = mesh.copy()
    centre = mesh.bounds.mean(axis=0)
    mesh.apply_translation(-centre)
    d = mesh_diameter(mesh.vertices)
    if d <= 0:
        raise ValueError("mesh has zero extent")
    mesh.apply_scale(diameter / d)
    return mesh


def set_color(mesh: trimesh.Trimesh, rgb: tuple[float, float, float]) -> trimesh.Trimesh:
    """Replace any visual with a uniform colour (copy)."""
    mesh = mesh.copy()
    rgba = np.array([*rgb, 1.0]) * 255
    mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=np.tile(rgba.astype(np.uint8), (len(mesh.faces), 1)))
    return mesh


def custom_object(mesh_path: str | os.PathLike, color: tuple[float, float, float] | None = (0.7, 0.7, 0.7),
                  sha256: str | None = None) -> ObjectMesh:
    """An ObjectMesh from any mesh file, normalised like the manifest objects (a user's mesh, bring-your-own, the
    symmetry rule's ``--mesh``). ``color=None`` keeps the file's texture/colours. Every error names the file."""
    try:
        mesh = load_mesh_file(mesh_path)
        if color is not None:
            mesh = set_color(mesh, color)
        mesh = normalise(mesh)
    except (ValueError, FileNotFoundError) as e:
        if str(mesh_path) in str(e):
            raise
        raise type(e)(f"mesh file {mesh_path}: {e}") from None
    return ObjectMesh(Path(mesh_path).stem, mesh, 0.2, color is None, sha256 or sha256_file(mesh_path), np.eye(3)[None])


def load_object(name: str, manifest: Manifest | None = None, diameter: float = DEFAULT_DIAMETER_M) -> ObjectMesh:
    """Load a manifest object, verified and normalised.

    Checks the sha256 of the mesh and every extra file (textures, .mtl)
    first; raises ManifestError naming the file on absence or mismatch.
    """
    m = manifest or load_manifest()
    entry = m.object(name)
    path = verify_file(entry.mesh, f"object {name!r}")
    for f in entry.extra_files:
        verify_file(f, f"object {name!r}")
    mesh = load_mesh_file(path)
    if entry.color is not None:
        mesh = set_color(mesh, entry.color)
        textured = False
    else:
        if not (has_texture(mesh) or has_vertex_colours(mesh)):
            raise ManifestError(f"object {name!r}: manifest says textured (no colour) but {path} loaded without a "
                                "texture or vertex colours")
        textured = True
    mesh = normalise(mesh, diameter)
    return ObjectMesh(name, mesh, diameter, textured, entry.mesh.sha256, entry.symmetry_group())
