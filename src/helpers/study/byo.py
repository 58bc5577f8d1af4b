"""Bring your own object: a mesh file and a query crop in, a rotation out.

Renders references of the given mesh (same recipe as the benchmark's,
cached by the mesh's sha256), encodes them with a trained model, retrieves
the query and draws the retrieved reference beside the query.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import torch
from tqdm.auto import tqdm

from ..core.configs import RenderConfig
from ..core.device import resolve_device
from ..core.fileio import (
    DamagedEntry,
    atomic_save_npy,
    atomic_write_json,
    check_sha256,
    read_json,
    sha256_file,
    stable_hash,
    touch,
)
from ..core.locks import entry_lock, made_by
from ..core.paths import cache_dir
from ..core.rotations import geodesic_deg, haar_uniform
from ..core.views import ObjectViews
from ..data.meshes import ObjectMesh, custom_object
from ..data.render import render_reference
from ..data.symmetry.rule import RULE_VERSION, SymmetryRule, describe, find_symmetries
from ..evaluation.metrics import rotation_errors_deg, rotation_text
from ..search.features import FeatureCache, encode_batch, encode_views, model_fingerprint
from .figures import _plt, save


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
        alternatives: the next best references, best first: {"index", "score",
            "R_m2c" (3x3 list), "deg_from_best" (geodesic angle to ``R_m2c``, degrees)}.
        symmetries: what the symmetry rule found on the mesh (:func:`mesh_symmetries`): {"discrete": [{"axis",
            "angle_deg"}], "continuous": [{"axis"}]} (model frame), or None when not asked for.
        equivalents: ``R_m2c @ S`` (3x3 lists) for each declared discrete symmetry S: rotations that look the
            same, as right as ``R_m2c`` (a continuous axis adds every turn about it).
    """

    R_m2c: np.ndarray
    score: float
    ref_index: int
    ref_image: np.ndarray
    query_image: np.ndarray
    alternatives: list[dict] = field(default_factory=list)
    symmetries: dict | None = None
    equivalents: list = field(default_factory=list)


ALPHA_MODES = ("composite", "crop")


def load_query_image(path: str | os.PathLike, size: int, alpha: str = "composite") -> np.ndarray:
    """Read an object crop as (size, size, 3) uint8 RGB, the way the references look.

    * Transparency (RGBA/LA PNG): ``alpha="composite"`` blends the image over black,
      the references' background; ``alpha="crop"`` first cuts the image to the box of
      its non-transparent pixels (then composites over black). A crop's hidden pixels
      never reach the network as they happen to be stored.
    * A non-square crop is padded with black to a square around its centre, never cut:
      the object stays whole and keeps its aspect ratio.
    * Grey and 16-bit images are converted to 8-bit RGB.

    Raises FileNotFoundError / ValueError naming the file and what was expected.
    """
    p = Path(path)
    if alpha not in ALPHA_MODES:
        raise ValueError(f"alpha: expected one of {ALPHA_MODES}, got {alpha!r}")
    if not p.is_file():
        raise FileNotFoundError(f"query image {p} does not exist")
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise ValueError(f"query image {p} is not a readable image (expected PNG/JPEG/... of an object crop)")
    if img.dtype == np.uint16:
        img = (img.astype(np.float32) / 257.0).round().astype(np.uint8)
    elif img.dtype != np.uint8:
        raise ValueError(f"query image {p}: unsupported pixel type {img.dtype} (expected 8- or 16-bit)")
    if img.ndim == 2:
        img = img[..., None]
    a = None
    if img.shape[2] in (2, 4):  # grey+alpha or BGRA
        a = img[..., -1].astype(np.float32) / 255.0
        img = img[..., :-1]
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB) if img.shape[2] == 1 else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if a is not None:
        if not (a > 0).any():
            raise ValueError(f"query image {p}: the alpha channel is fully transparent (no object to see)")
        if alpha == "crop":
            ys, xs = np.nonzero(a > 0)
            img = img[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
            a = a[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
        img = (img.astype(np.float32) * a[..., None]).round().astype(np.uint8)  # over black
    img = pad_to_square(img)
    return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)


def pad_to_square(img: np.ndarray) -> np.ndarray:
    """(H, W, 3) -> (S, S, 3), S = max(H, W): black bands on both sides of the short axis."""
    h, w = img.shape[:2]
    s = max(h, w)
    top, left = (s - h) // 2, (s - w) // 2
    return np.pad(img, ((top, s - h - top), (left, s - w - left), (0, 0)))


def _refset_key(sha: str, n: int, seed: int, cfg: RenderConfig, textured: bool) -> str:
    return stable_hash({"sha": sha, "n": n, "seed": seed, "cfg": cfg.__dict__, "textured": textured})


def render_custom_references(obj: ObjectMesh, n: int, cfg: RenderConfig, seed: int = 0,
                             cache: str | os.PathLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(n, S, S, 3) uint8 references and (n, 3, 3) rotations, cached by mesh hash.

    Renders in this process (one GL context; do not fork afterwards), one process per
    reference set at a time (its lock); ``meta.json`` (written last) records the sha256 of
    both arrays, and a set that no longer matches them is rendered again.
    """
    d = _refs_dir(obj.name, _refset_key(obj.sha256, n, seed, cfg, obj.textured), cache)
    done = _cached_refs(d)
    if done is not None:
        return done
    with entry_lock(d, f"bring-your-own references {d.name}"):
        done = _cached_refs(d, warn=True)
        if done is not None:
            return done
        for stray in d.glob(".*.tmp"):  # left by a killed builder (we hold the lock)
            stray.unlink(missing_ok=True)
        R64 = haar_uniform(n, seed=seed)
        imgs = np.zeros((n, cfg.size, cfg.size, 3), np.uint8)
        for i in tqdm(range(n), desc=f"rendering {obj.name}", unit="img"):
            imgs[i] = render_reference(obj, R64[i], cfg)[0]
        R = R64.astype(np.float32)
        atomic_save_npy(d / "rotations.npy", R)
        atomic_save_npy(d / "images.npy", imgs)
        atomic_write_json(d / "meta.json", {"mesh_sha256": obj.sha256, "n": n, "seed": seed, "made_by": made_by(),
                                            "sha256": {f: sha256_file(d / f) for f in BYO_FILES}})
    return imgs, R


BYO_FILES = ("images.npy", "rotations.npy")


def check_refs(d: Path) -> None:
    """Raise :class:`DamagedEntry` unless reference set ``d`` matches the sha256 sums in its meta.json."""
    meta = d / "meta.json"
    try:
        sums = read_json(meta)["sha256"]
    except (ValueError, KeyError, TypeError):
        raise DamagedEntry(f"{meta}: unreadable or without checksums; delete {d} to re-render") from None
    for f in BYO_FILES:
        check_sha256(d / f, sums.get(f, ""), meta, f"delete {d} to re-render (or rerun: damaged sets are re-rendered)")


def _cached_refs(d: Path, warn: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """The finished, intact reference set in ``d`` (images memory-mapped), or None."""
    if not (d / "meta.json").exists():
        return None
    try:
        check_refs(d)
    except DamagedEntry as e:
        if warn:
            warnings.warn(f"{e}; re-rendering it", RuntimeWarning, stacklevel=3)
        return None
    touch(d / "meta.json")  # last use
    return np.load(d / "images.npy", mmap_mode="r"), np.load(d / "rotations.npy")


def _refs_dir(name: str, key: str, cache: str | os.PathLike | None) -> Path:
    return cache_dir(cache) / "byo" / f"{name}-{key}"


@dataclass
class ReferenceSet:
    """A mesh's rendered references and their features under one model (:func:`reference_set`).

    Attributes:
        refs: (N, S, S, 3) uint8 renders.
        R: (N, 3, 3) their ``R_m2c``.
        feats: (N, C, L) float16 reference features (a read-only memmap of the feature cache).
        device: where the queries are encoded and scored.
    """

    refs: np.ndarray
    R: np.ndarray
    feats: np.ndarray
    device: torch.device


def reference_set(model, mesh_path: str | os.PathLike, n_refs: int = 1024, render_size: int = 160,
                  color: tuple[float, float, float] | None = (0.7, 0.7, 0.7), device: str = "auto",
                  cache: str | os.PathLike | None = None) -> ReferenceSet:
    """Render ``n_refs`` references of the mesh file and encode them with ``model``, or read both from
    the cache (``<cache>/byo`` and ``<cache>/features``, keyed by the mesh file's sha256, the reference
    set (count, seed, render settings, colour) and the model's weights)."""
    size = int(model.cfg.image_size) if hasattr(model, "cfg") else 128
    mesh_path = Path(mesh_path)
    if not mesh_path.is_file():
        raise FileNotFoundError(f"mesh file {mesh_path} does not exist")
    sha = sha256_file(mesh_path)
    cfg = RenderConfig(size=size, render_size=render_size)
    key = _refset_key(sha, n_refs, 0, cfg, color is None)
    dev = resolve_device(device)
    fc = FeatureCache(cache_dir(cache) / "features")
    mkey = model_fingerprint(model)
    rdir = _refs_dir(mesh_path.stem, key, cache)
    try:
        feats = fc.load(mkey, f"byo-{key}")
    except DamagedEntry:
        feats = None  # get_or_build reports and rebuilds it
    cached = _cached_refs(rdir) if feats is not None else None
    if cached is not None:
        refs, R = cached
    else:
        obj = custom_object(mesh_path, color, sha256=sha)
        refs, R = render_custom_references(obj, n_refs, cfg, cache=cache)
        views = ObjectViews(mesh_path.stem, refs, R, None, "reference")
        feats = fc.get_or_build(model, mkey, views, f"byo-{key}", batch=encode_batch(dev), device=dev)
    return ReferenceSet(refs, R, feats, dev)


def mesh_symmetries(mesh_path: str | os.PathLike, color: tuple[float, float, float] | None = (0.7, 0.7, 0.7),
                    cache: str | os.PathLike | None = None, rule: SymmetryRule = SymmetryRule()) -> dict:
    """The symmetry rule of the benchmark (:mod:`helpers.data.symmetry`) applied to a mesh file, cached by the
    file's sha256, the colour and the rule: {"discrete": [{"axis", "angle_deg", "R"}], "continuous": [{"axis"}],
    "candidates": the evidence}. Tens of seconds the first time, read back afterwards."""
    mesh_path = Path(mesh_path)
    sha = sha256_file(mesh_path)
    key = stable_hash({"sha": sha, "color": color, "rule": asdict(rule), "v": RULE_VERSION})
    path = cache_dir(cache) / "byo" / f"{mesh_path.stem}-symmetry-{key}.json"
    if path.is_file():
        try:
            return read_json(path)
        except ValueError:
            pass  # a damaged file: computed again below and replaced
    res = find_symmetries(custom_object(mesh_path, color, sha256=sha), rule)
    out = {"discrete": [{"axis": describe(R)[0], "angle_deg": describe(R)[1], "R": R.tolist()} for R in res.discrete],
           "continuous": [{"axis": [float(x) for x in a]} for a in res.axes],
           "candidates": res.evidence["candidates"], "rule_version": RULE_VERSION}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, out)
    return out


def with_symmetries(res: ByoResult, sym: dict) -> ByoResult:
    """``res`` with the mesh's symmetries and the rotations equivalent to its answer under them."""
    res.symmetries = {"discrete": [{k: d[k] for k in ("axis", "angle_deg")} for d in sym["discrete"]],
                      "continuous": sym["continuous"]}
    res.equivalents = [(res.R_m2c @ np.asarray(d["R"], np.float64)).tolist() for d in sym["discrete"]]
    return res


def answer(model, rs: ReferenceSet, query: np.ndarray, n_alternatives: int = 4) -> ByoResult:
    """Retrieve one (S, S, 3) uint8 query crop (as :func:`load_query_image` returns it) among the
    references of ``rs``: the best reference's rotation and the next ``n_alternatives``."""
    qf = next(encode_views(model, query[None], device=rs.device))
    model.eval()
    with torch.inference_mode(), warnings.catch_warnings():
        # The cached features are a read-only memmap; score() only reads them (chunk by chunk).
        warnings.filterwarnings("ignore", message="The given NumPy array is not writable")
        s = model.score(qf.to(rs.device), torch.from_numpy(np.asarray(rs.feats)))[0].float().cpu().numpy()
    order = np.argsort(-s, kind="stable")
    k = int(order[0])
    best = rs.R[k].astype(np.float64)
    alts = [{"index": int(j), "score": float(s[j]), "R_m2c": rs.R[j].astype(np.float64).tolist(),
             "deg_from_best": float(geodesic_deg(best, rs.R[j].astype(np.float64)))}
            for j in order[1:1 + n_alternatives]]
    return ByoResult(best, float(s[k]), k, np.array(rs.refs[k]), query, alts)


def estimate_rotation(model, mesh_path: str | os.PathLike, query_path: str | os.PathLike, n_refs: int = 1024,
                      render_size: int = 160, color: tuple[float, float, float] | None = (0.7, 0.7, 0.7),
                      device: str = "auto", cache: str | os.PathLike | None = None,
                      alpha: str = "composite", n_alternatives: int = 4, symmetries: bool = True) -> ByoResult:
    """Estimate the rotation of the object in ``query_path`` from its mesh ``mesh_path``.

    With ``symmetries``, the benchmark's symmetry rule also runs on the mesh (:func:`mesh_symmetries`, cached),
    and the answer carries the symmetries found and the rotations equivalent to it.

    The references and their features come from :func:`reference_set` (cached), so a second
    query of the same object with the same model costs only the query's encoding and the search.
    ``alpha``: how a transparent query crop is read (see :func:`load_query_image`).
    """
    size = int(model.cfg.image_size) if hasattr(model, "cfg") else 128
    query = load_query_image(query_path, size, alpha)  # a bad crop is reported before any rendering
    rs = reference_set(model, mesh_path, n_refs, render_size, color, device, cache)
    res = answer(model, rs, query, n_alternatives)
    return with_symmetries(res, mesh_symmetries(mesh_path, color, cache)) if symmetries else res


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


def answer_views(model, mesh_path: str | os.PathLike, views: ObjectViews, n: int = 0,
                 threshold_deg: float = 30.0, alpha: str = "composite", **kw) -> tuple[pd.DataFrame, list[ByoResult]]:
    """Answer the first ``n`` (0: all) crops of ``views`` through the bring-your-own path, as a user
    would: each crop is saved as a PNG (a temporary file), read back with :func:`load_query_image`
    and retrieved among the references of the object's mesh file (:func:`reference_set`, built or
    read once; ``kw``: its options), so only that object's references compete and nothing
    classifies. Errors are scored against the views' true ``R_m2c``, minimised over
    ``views.symmetries`` (the benchmark's metric).

    Returns (per-query table as :func:`helpers.evaluation.metrics.per_query_table` names its columns:
    obj, query_id, class_ok (True: the object is given), err_deg, rot_ok (err_deg < ``threshold_deg``),
    R_est, R_gt, and score, reference; one ByoResult per query, in order)."""
    if n < 0:
        raise ValueError(f"answer_views: n expected 0 (all views) or a positive count, got {n}")
    n = len(views) if n == 0 else min(int(n), len(views))
    if n < 1:
        raise ValueError(f"answer_views: {views.name} has no views to answer")
    size = int(model.cfg.image_size) if hasattr(model, "cfg") else 128
    rs = reference_set(model, mesh_path, **kw)
    results = []
    with tempfile.TemporaryDirectory(prefix="byo-") as tmp:
        for i in tqdm(range(n), desc=f"bring-your-own {views.name}", leave=False):
            png = Path(tmp) / f"{views.name}-{i:04d}.png"
            cv2.imwrite(str(png), cv2.cvtColor(np.ascontiguousarray(views.images[i]), cv2.COLOR_RGB2BGR))
            results.append(answer(model, rs, load_query_image(png, size, alpha)))
    err = rotation_errors_deg(np.stack([r.R_m2c for r in results]), views.rotations[:n].astype(np.float64),
                              views.symmetries)
    table = pd.DataFrame({"obj": views.name, "query_id": np.arange(n), "class_ok": True, "err_deg": err,
                          "rot_ok": err < threshold_deg, "score": [r.score for r in results],
                          "reference": [r.ref_index for r in results],
                          "R_est": [rotation_text(r.R_m2c) for r in results],
                          "R_gt": [rotation_text(R) for R in views.rotations[:n]]})
    return table, results


# ----------------------------------------------------------------------------- command line

#: Zoo models tried in order when ``--model`` is not given: the all-objects model where it exists.
