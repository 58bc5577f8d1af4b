"""Bring your own object: a mesh file and a query crop in, a rotation out.

Renders references of the given mesh (same recipe as the benchmark's,
cached by the mesh's sha256), encodes them with a trained model, retrieves
the query and draws the retrieved reference beside the query.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm.auto import tqdm

from .device import resolve_device
from .features import encode_views
from .fileio import atomic_save_npy, sha256_file, stable_hash
from .figures import _plt, save
from .meshes import ObjectMesh, load_mesh_file, normalise, set_color
from .paths import cache_dir
from .render import RenderConfig, render_reference
from .rotations import haar_uniform


@dataclass
class ByoResult:
    """Outcome of :func:`estimate_rotation`.

    Attributes:
        R_m2c: (3, 3) estimated rotation of the mesh in the query's camera frame
            (up to the in-plane rotation of the crop and the mesh's own centring).
        score: similarity of the retrieved reference.
        ref_index: index of the retrieved reference.
        ref_image: (S, S, 3) uint8 retrieved reference.
        query_image: (S, S, 3) uint8 query as fed to the network.
    """

    R_m2c: np.ndarray
    score: float
    ref_index: int
    ref_image: np.ndarray
    query_image: np.ndarray


def load_query_image(path: str | os.PathLike, size: int) -> np.ndarray:
    """Read an image crop and resize it to (size, size, 3) uint8 RGB.

    Raises ValueError naming the file if it is not a readable image.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"query image {p} does not exist")
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"query image {p} is not a readable image (expected PNG/JPEG/... of an object crop)")
    img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    h, w = img.shape[:2]
    if h != w:  # centre-crop to a square: the method works on square crops
        s = min(h, w)
        img = img[(h - s) // 2:(h - s) // 2 + s, (w - s) // 2:(w - s) // 2 + s]
    return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)


def custom_object(mesh_path: str | os.PathLike, color: tuple[float, float, float] | None = (0.7, 0.7, 0.7)) -> ObjectMesh:
    """An ObjectMesh from any mesh file (normalised like the manifest objects).

    ``color=None`` keeps the file's texture/colours.
    """
    mesh = load_mesh_file(mesh_path)
    if color is not None:
        mesh = set_color(mesh, color)
    mesh = normalise(mesh)
    return ObjectMesh(Path(mesh_path).stem, mesh, 0.2, color is None, sha256_file(mesh_path), np.eye(3)[None])


def render_custom_references(obj: ObjectMesh, n: int, cfg: RenderConfig, seed: int = 0,
                             cache: str | os.PathLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(n, S, S, 3) uint8 references and (n, 3, 3) rotations, cached by mesh hash.

    Renders in this process (one GL context; do not fork afterwards).
    """
    key = stable_hash({"sha": obj.sha256, "n": n, "seed": seed, "cfg": cfg.__dict__, "textured": obj.textured})
    d = cache_dir(cache) / "byo" / f"{obj.name}-{key}"
    if (d / "images.npy").exists():
        return np.load(d / "images.npy"), np.load(d / "rotations.npy")
    R = haar_uniform(n, seed=seed)
    imgs = np.zeros((n, cfg.size, cfg.size, 3), np.uint8)
    for i in tqdm(range(n), desc=f"rendering {obj.name}", unit="img"):
        imgs[i] = render_reference(obj, R[i], cfg)[0]
    atomic_save_npy(d / "rotations.npy", R.astype(np.float32))
    atomic_save_npy(d / "images.npy", imgs)
    return imgs, R.astype(np.float32)


def estimate_rotation(model, mesh_path: str | os.PathLike, query_path: str | os.PathLike, n_refs: int = 1024,
                      render_size: int = 160, color: tuple[float, float, float] | None = (0.7, 0.7, 0.7),
                      device: str = "auto", cache: str | os.PathLike | None = None) -> ByoResult:
    """Estimate the rotation of the object in ``query_path`` from its mesh ``mesh_path``."""
    size = int(model.cfg.image_size) if hasattr(model, "cfg") else 128
    query = load_query_image(query_path, size)
    obj = custom_object(mesh_path, color)
    refs, R = render_custom_references(obj, n_refs, RenderConfig(size=size, render_size=render_size), cache=cache)
    dev = resolve_device(device)
    rf = torch.cat(list(encode_views(model, refs, device=dev)))
    qf = next(encode_views(model, query[None], device=dev))
    model.eval()
    with torch.inference_mode():
        s = model.score(qf.to(dev), rf.to(dev))[0].float().cpu().numpy()
    k = int(np.argmax(s))
    return ByoResult(R[k].astype(np.float64), float(s[k]), k, refs[k], query)


def overlay_figure(res: ByoResult, path: str | os.PathLike) -> Path:
    """Query | retrieved reference | blend of the two."""
    plt = _plt()
    fig, ax = plt.subplots(1, 3, figsize=(6, 2.2))
    mask = res.ref_image.sum(-1) > 0
    blend = res.query_image.copy()
    blend[mask] = (0.45 * blend[mask] + 0.55 * res.ref_image[mask]).astype(np.uint8)
    for a, im, t in zip(ax, [res.query_image, res.ref_image, blend], ["query", f"retrieved (s={res.score:.2f})", "overlay"]):
        a.imshow(im)
        a.set_title(t, fontsize=8)
        a.set_xticks([])
        a.set_yticks([])
    return save(fig, path)
