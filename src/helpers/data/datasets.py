"""Rendered view sets on disk: content-hashed, chunked, resumable, parallel.

A *view set* is N views of one object, either references (object on black,
rotations shared by every object) or real-like queries. It lives in::

    <cache>/renders/<object>/<kind>-<key>/
        chunk_00000.npz ...   finished chunks (atomic writes)
        images.npy            (N, S, S, 3) uint8, memory-mappable
        masks.npy             (N, S, S) bool
        rotations.npy         (N, 3, 3) float32 R_m2c
        meta.json             written last: its presence means "complete"; holds the
                              sha256 of the three .npy files, checked on load
    <cache>/renders/<object>/.<kind>-<key>.lock   held by the one process building it

``key`` hashes everything that determines the pixels: object mesh and
texture checksums, render and style parameters, N, seeds, code version. An
interrupted render keeps its finished chunks and a rerun renders only the
missing ones, so no finished work is lost.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import shutil
import tempfile
import time
import warnings
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm.auto import tqdm

from ..core.configs import QueryStyle, RenderConfig
from ..core.fileio import (
    DamagedEntry,
    atomic_save_npy,
    atomic_write_json,
    check_sha256,
    output_errors,
    preallocate,
    read_json,
    sha256_file,
    stable_hash,
    touch,
)
from ..core.locks import entry_lock, made_by, settle, try_entry_lock
from ..core.paths import cache_dir
from ..core.rotations import haar_uniform
from ..core.views import ObjectViews
from .manifest import Manifest, load_manifest, verify_file
from .meshes import load_object
from .render import config_dict, output_side, render_query, render_reference

#: Bump when rendering code changes in a way that alters pixels.
RENDER_VERSION = 3
KINDS = ("reference", "query")


@dataclass(frozen=True)
class ViewSetSpec:
    """What to render for one object.

    Attributes:
        object: manifest object name.
        kind: ``"reference"`` or ``"query"``.
        n: number of views.
        seed: seed of the rotations (references: shared by all objects, so the
            seed does not depend on the object) and of the query perturbations.
        render: RenderConfig.
        style: QueryStyle (queries only).
        background_split: ``"train"`` or ``"test"`` photos (queries only).
    """

    object: str
    kind: str
    n: int
    seed: int = 0
    render: RenderConfig = RenderConfig()
    style: QueryStyle = QueryStyle()
    background_split: str = "train"

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"ViewSetSpec.kind must be one of {KINDS}, got {self.kind!r}")
        if not isinstance(self.n, int) or self.n < 1:
            raise ValueError(f"ViewSetSpec.n must be a positive int, got {self.n!r}")
        if self.background_split not in ("train", "test"):
            raise ValueError(f"ViewSetSpec.background_split must be 'train' or 'test', got {self.background_split!r}")

    def side(self) -> int:
        """Side of the stored images, pixels (queries may keep context around the crop)."""
        return output_side(self.render, self.style) if self.kind == "query" else self.render.size

    def rotations(self) -> np.ndarray:
        """(n, 3, 3) rotations to render (before any in-plane rotation of queries)."""
        if self.kind == "reference":
            return haar_uniform(self.n, seed=self.seed)
        # Queries: object-specific stream, disjoint from the reference stream.
        return haar_uniform(self.n, seed=[self.seed, 7919, _name_int(self.object)])

    def key(self, manifest: Manifest) -> str:
        entry = manifest.object(self.object)
        d = {"v": RENDER_VERSION, "object": self.object, "kind": self.kind, "n": self.n, "seed": self.seed,
             "files": [f.sha256 for f in entry.files()], "color": entry.color,
             **config_dict(self.render, self.style if self.kind == "query" else None)}
        if self.kind == "query":
            d["backgrounds"] = [b.file.sha256 for b in manifest.backgrounds if b.split == self.background_split]
        return stable_hash(d)


def _name_int(name: str) -> int:
    return int(stable_hash(name, 8), 16)


def set_dir(spec: ViewSetSpec, manifest: Manifest, root: Path) -> Path:
    return root / "renders" / spec.object / f"{spec.kind}-{spec.key(manifest)}"


CHUNK = 128


# ------------------------------------------------------------ worker side

_W: dict = {}


def _worker_init(manifest: Manifest, lp_threads: int | None) -> None:
    if lp_threads:
        # llvmpipe would otherwise start one thread per core in every worker.
        os.environ.setdefault("LP_NUM_THREADS", str(lp_threads))
    _use_manifest(manifest)


def _use_manifest(manifest: Manifest) -> None:
    """Render this manifest's objects from now on in this process. The manifest itself is handed over (not its
    path): a real data set's manifest is built from its folder, not read from a file."""
    if _W.get("manifest") is not manifest:
        _W["manifest"] = manifest
        _W["backgrounds"] = {}


def background_photos(manifest: Manifest, split: str) -> dict[str, np.ndarray]:
    """The manifest's ``split`` ("train"/"test") photos, name -> (H, W, 3) uint8 RGB, checked and kept per process."""
    bgs = _W.setdefault("backgrounds", {})
    if split not in bgs:
        out = {}
        for b in manifest.backgrounds:
            if b.split != split:
                continue
            p = verify_file(b.file, f"background {b.name!r}")
            img = cv2.imread(str(p), cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"background {b.name!r}: {p} is not a readable image")
            out[b.name] = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        if not out:
            raise ValueError(f"{manifest.path}: no backgrounds with split {split!r}")
        bgs[split] = out
    return bgs[split]


def _render_chunk(spec: ViewSetSpec, out_dir: str, chunk_idx: int) -> int:
    """Render views [chunk_idx*CHUNK, ...) of ``spec`` into ``chunk_XXXXX.npz``."""
    manifest = _W.get("manifest") or load_manifest()
    objs = _W.setdefault("objects", {})
    key = (spec.object, manifest.object(spec.object).mesh.sha256)  # two manifests may share a name ("duck")
    if key not in objs:
        objs[key] = load_object(spec.object, manifest)
    obj = objs[key]
    R = spec.rotations()
    lo, hi = chunk_idx * CHUNK, min(spec.n, (chunk_idx + 1) * CHUNK)
    S = spec.side()
    imgs = np.zeros((hi - lo, S, S, 3), np.uint8)
    masks = np.zeros((hi - lo, S, S), bool)
    rots = np.zeros((hi - lo, 3, 3), np.float32)
    if spec.kind == "query":
        bgs = background_photos(manifest, spec.background_split)
    for i in range(lo, hi):
        try:
            if spec.kind == "reference":
                imgs[i - lo], masks[i - lo] = render_reference(obj, R[i], spec.render)
                rots[i - lo] = R[i]
            else:
                # One generator per view: a view's pixels do not depend on chunking or workers.
                rng = np.random.default_rng([spec.seed, _name_int(spec.object), i])
                imgs[i - lo], masks[i - lo], rots[i - lo] = render_query(obj, R[i], spec.render, spec.style, bgs,
                                                                         rng)
        except ValueError as e:  # say which object and view: a worker's traceback does not
            raise ValueError(f"object {spec.object!r}, {spec.kind} view {i} of {spec.n} (seed {spec.seed}): {e}") \
                from None
    path = Path(out_dir) / f"chunk_{chunk_idx:05d}.npz"
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with output_errors(path), open(tmp, "wb") as f:
            np.savez(f, images=imgs, masks=masks, rotations=rots)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)
    return hi - lo


# ------------------------------------------------------------ main side

def _n_chunks(n: int) -> int:
    return (n + CHUNK - 1) // CHUNK


def _load_complete(d: Path, spec: ViewSetSpec, manifest: Manifest, mmap: bool) -> ObjectViews:
    meta = read_json(d / "meta.json")
    mode = "r" if mmap else None
    images = np.load(d / "images.npy", mmap_mode=mode)
    rots = np.load(d / "rotations.npy")
    masks = np.load(d / "masks.npy", mmap_mode=mode)
    if images.shape != (spec.n, spec.side(), spec.side(), 3):
        raise DamagedEntry(f"{d}/images.npy: expected shape {(spec.n, spec.side(), spec.side(), 3)}, "
                           f"got {images.shape}; delete {d} to re-render")
    touch(d / "meta.json")  # its modification time is the set's last use (python -m helpers.study.cli.cache list)
    return ObjectViews(spec.object, images, rots, masks, spec.kind, manifest.object(spec.object).symmetry_group(), meta)


SET_FILES = ("images.npy", "masks.npy", "rotations.npy")


def check_set(d: Path, backfill: bool = True) -> None:
    """Raise :class:`DamagedEntry` unless the finished set ``d`` matches the sha256 sums in its
    meta.json. A set finished before checksums were recorded gets them now (``backfill``) or
    is not checked."""
    meta_p = d / "meta.json"
    try:
        meta = read_json(meta_p)
        sums = meta.get("sha256")
    except (ValueError, AttributeError):
        raise DamagedEntry(f"{meta_p}: unreadable; delete {d} to re-render") from None
    if sums is None:
        if backfill:
            try:
                atomic_write_json(meta_p, {**meta, "sha256": {f: sha256_file(d / f) for f in SET_FILES}})
            except OSError:
                pass  # a read-only cache: the set stays unchecked
        return
    if not isinstance(sums, dict):
        raise DamagedEntry(f"{meta_p}: malformed checksums; delete {d} to re-render")
    for f in SET_FILES:
        check_sha256(d / f, sums.get(f, ""), meta_p, f"delete {d} to re-render (or rerun: damaged sets are re-rendered)")


def _intact(d: Path) -> bool:
    """Whether ``d`` is a finished set whose files match their checksums (a damaged one is reported)."""
    if not (d / "meta.json").exists():
        return False
    try:
        check_set(d)
    except DamagedEntry as e:
        warnings.warn(f"{e}; re-rendering it", RuntimeWarning, stacklevel=3)
        return False
    return True


def _consolidate(d: Path, spec: ViewSetSpec) -> None:
    S = spec.side()
    fd, name = tempfile.mkstemp(dir=d, prefix=".images.npy.", suffix=".tmp")  # unique: never shared
    os.close(fd)
    tmp = Path(name)
    try:
        with output_errors(tmp, spec.n * S * S * 3):
            imgs = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.uint8, shape=(spec.n, S, S, 3))
        preallocate(tmp, tmp.stat().st_size)  # reserve the sparse file's blocks: full disk = error, not SIGBUS
        masks = np.zeros((spec.n, S, S), bool)
        rots = np.zeros((spec.n, 3, 3), np.float32)
        for c in range(_n_chunks(spec.n)):
            with np.load(d / f"chunk_{c:05d}.npz") as z:
                lo = c * CHUNK
                hi = lo + len(z["images"])
                imgs[lo:hi] = z["images"]
                masks[lo:hi] = z["masks"]
                rots[lo:hi] = z["rotations"]
        imgs.flush()
        del imgs
        os.chmod(tmp, 0o644)
        os.replace(tmp, d / "images.npy")
    finally:
        tmp.unlink(missing_ok=True)
    atomic_save_npy(d / "masks.npy", masks)
    atomic_save_npy(d / "rotations.npy", rots)


def _mkdir(d: Path, root: Path) -> None:
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OSError(f"cannot create render cache folder {d} (cache root {root}): {e.strerror}") from None


def _start(d: Path, spec: ViewSetSpec, root: Path) -> list[tuple[ViewSetSpec, Path, int]]:
    """Prepare folder ``d`` for ``spec`` (clearing a damaged finished set); its chunks still to render."""
    for f in ("meta.json", *SET_FILES):  # what is left of a damaged set; its chunks are gone
        (d / f).unlink(missing_ok=True)
    for stray in d.glob(".*.tmp"):  # left by a killed builder (we hold the set's lock)
        stray.unlink(missing_ok=True)
    _mkdir(d, root)
    atomic_write_json(d / "spec.json", {"object": spec.object, "kind": spec.kind, "n": spec.n, "seed": spec.seed,
                                        **config_dict(spec.render, spec.style), "background_split": spec.background_split})
    return [(spec, d, c) for c in range(_n_chunks(spec.n)) if not (d / f"chunk_{c:05d}.npz").exists()]


def _render_chunks(todo: list[tuple[ViewSetSpec, Path, int]], workers: int, manifest: Manifest,
                   progress: bool) -> None:
    total = sum(min(CHUNK, s.n - c * CHUNK) for s, _, c in todo)
    bar = tqdm(total=total, desc="rendering views", unit="img", disable=not progress)
    if workers and workers > 0:
        ctx = mp.get_context("spawn")
        lp = max(1, (os.cpu_count() or 2) // workers)
        with cf.ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init,
                                    initargs=(manifest, lp)) as ex:
            futs = [ex.submit(_render_chunk, s, str(d), c) for s, d, c in todo]
            for f in cf.as_completed(futs):
                bar.update(f.result())
    else:
        _use_manifest(manifest)
        for s, d, c in todo:
            bar.update(_render_chunk(s, str(d), c))
    bar.close()


def _finish(d: Path, spec: ViewSetSpec, keep_chunks: bool) -> None:
    """Consolidate the chunks of ``d`` and write meta.json (last: its presence means complete)."""
    _consolidate(d, spec)
    meta = {"object": spec.object, "kind": spec.kind, "n": spec.n, "seed": spec.seed, "key": d.name,
            "render_version": RENDER_VERSION, **config_dict(spec.render, spec.style if spec.kind == "query" else None),
            "background_split": spec.background_split if spec.kind == "query" else None,
            "bytes": sum((d / f).stat().st_size for f in SET_FILES),
            "sha256": {f: sha256_file(d / f) for f in SET_FILES}, "made_by": made_by(),
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    atomic_write_json(d / "meta.json", meta)
    if not keep_chunks:
        for f in d.glob("chunk_*.npz"):
            f.unlink()


def render_sets(specs: list[ViewSetSpec], cache: str | os.PathLike | None = None, workers: int = 2,
                manifest: Manifest | None = None, mmap: bool = True, progress: bool = True,
                keep_chunks: bool = False) -> list[ObjectViews]:
    """Render (or load from cache) every view set in ``specs``.

    Sets still to build are locked first (one builder per set, in one global order so two
    processes never wait for each other); a process that waited finds them finished and
    loads them. A finished set whose files no longer match their sha256 is re-rendered.

    Args:
        specs: what to render.
        cache: cache root (default :func:`helpers.core.paths.cache_dir`).
        workers: rendering processes (spawned). ``0`` renders in this process
            (which then holds a GL context: do not fork afterwards).
        mmap: return images as read-only memory maps instead of loading them.
        keep_chunks: keep chunk files after consolidation (default: delete).

    Returns:
        One ObjectViews per spec, in order.
    """
    manifest = manifest or load_manifest()
    root = cache_dir(cache)
    dirs = []
    for spec in specs:
        manifest.object(spec.object)  # clear error for unknown names before any work
        dirs.append(set_dir(spec, manifest, root))
    pending = {d: spec for d, spec in zip(dirs, specs) if not _intact(d)}
    if pending:
        with ExitStack() as stack:
            for d in sorted(pending):
                _mkdir(d.parent, root)
                stack.enter_context(entry_lock(d, f"render set {d.parent.name}/{d.name}"))
            pending = {d: s for d, s in pending.items() if not _intact(d)}  # others may have built them meanwhile
            todo = [t for d, s in pending.items() for t in _start(d, s, root)]
            if todo:
                _render_chunks(todo, workers, manifest, progress)
            for d, s in pending.items():
                _finish(d, s, keep_chunks)
    for d in dirs:
        settle(d)
    return [_load_complete(d, spec, manifest, mmap) for d, spec in zip(dirs, specs)]


def clear_incomplete(cache: str | os.PathLike | None = None) -> int:
    """Delete view-set folders without meta.json that no live process is building (returns how many)."""
    root = cache_dir(cache) / "renders"
    n = 0
    for d in root.glob("*/*-*"):
        if not d.is_dir() or (d / "meta.json").exists():
            continue
        with try_entry_lock(d, f"render set {d.parent.name}/{d.name}") as free:
            if free and not (d / "meta.json").exists():
                shutil.rmtree(d)
                n += 1
    return n
