"""Encode reference views once and keep the feature maps on disk as float16 memmaps.

A reference feature map is (C, L) floats (the method's: 128 x 1449, 0.37 MB in
float16), so 13 objects x 10,000 references do not fit in memory. The cache
writes each set batch by batch into a temporary memmap, records progress in a
JSON sidecar after every batch (so an interrupted build resumes where it
stopped) and renames the file into place only when complete.

Layout: ``<root>/<model_key>/<refset_key>.f16`` (raw C-order float16, no
header) and ``<root>/<model_key>/<refset_key>.json``; ``.<refset_key>.f16.lock`` is held by
the one process building it::

    {"shape": [N, C, L], "dtype": "float16", "done": n, "complete": bool,
     "keys": {"model_key": ..., "refset_key": ..., "name": ..., "n_views": N,
              "image_shape": [S, S, 3], "probe": <hash of a few images>}}

The model is any object with ``encode(images (B,3,H,W) float in [0,1]) ->
(B,C,L)`` (duck typing).
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
import os
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from ..core import local_norm, precision
from ..core.fileio import DamagedEntry, atomic_write_json, preallocate, sha256_file, source_digest, touch
from ..core.locks import entry_lock, made_by, settle
from ..core.views import ObjectViews

SIDECAR_VERSION = 1

# Feature files whose content was checked in this process: (path, size, mtime_ns).
_VERIFIED: set[tuple[str, int, int]] = set()


def _check_images(images: np.ndarray, where: str) -> None:
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ValueError(f"{where}: expected images (N,S,S,3) uint8, got {images.shape} {images.dtype}")


def encode_batch(device: torch.device) -> int:
    """Images per encoder pass: 16 on CPU (the activations of a small batch stay in cache:
    125 vs 93 images/s at 64 px for batches of 16 vs 64 on 2 cores), 256 on a GPU."""
    return 16 if device.type == "cpu" else 256


def encode_views(model: Any, images: np.ndarray, batch: int = 64, device: str | torch.device = "cpu",
                 start: int = 0) -> Iterator[torch.Tensor]:
    """Yield the model's features for ``images[start:]`` batch by batch.

    Args:
        model: object with ``encode``; put in eval mode for the duration if it
            has ``eval``/``train`` (dropout must be off for cached features).
        images: (N, S, S, 3) uint8 RGB (array or memmap; read one batch at a time).
        batch: images per forward pass.
        device: where the model runs.
        start: first image index (used to resume).

    Yields:
        float32 CPU tensors (B, C, L), B <= batch, in order.
    """
    _check_images(images, "encode_views")
    if batch < 1:
        raise ValueError(f"encode_views: batch must be >= 1, got {batch}")
    was_training = getattr(model, "training", None)
    if hasattr(model, "eval"):
        model.eval()
    try:
        for s in range(start, len(images), batch):
            x = torch.from_numpy(np.array(images[s:s + batch]))  # a writable copy of the (memmap) batch
            x = x.to(device).permute(0, 3, 1, 2).float().div_(255.0)
            with torch.inference_mode():
                f = model.encode(x)
            if f.ndim != 3 or f.shape[0] != x.shape[0]:
                raise ValueError(f"encode_views: model.encode returned shape {tuple(f.shape)}, "
                                 f"expected ({x.shape[0]}, C, L)")
            yield f.float().cpu()
    finally:
        if was_training and hasattr(model, "train"):
            model.train(True)


def _config_of(model: Any) -> Any:
    """What configures ``model``'s encoding besides its weights: ``config`` or ``cfg`` (dict or dataclass) and the
    runtime ``precision`` it encodes in (bf16 and float32 features differ)."""
    cfg = getattr(model, "config", None) or getattr(model, "cfg", None)
    if dataclasses.is_dataclass(cfg) and not isinstance(cfg, type):
        cfg = dataclasses.asdict(cfg)
    precision = getattr(model, "precision", None)
    return cfg if precision is None else {"config": cfg, "precision": precision}


def _source_of(cls: type) -> Path | None:
    """The file that defines ``cls``; None for torch's and Python's own classes and for a class defined in a
    notebook or ``python -c`` (no file)."""
    if cls.__module__.split(".")[0] in ("builtins", "torch", "typing", "abc"):
        return None
    try:
        f = Path(inspect.getsourcefile(cls) or "")
    except (TypeError, OSError):
        return None
    return f if f.is_file() else None


def encoder_sources(model: Any) -> list[Path]:
    """The source files that turn images into ``model``'s features: those defining its class and base classes,
    and (a torch module) every submodule's class (the network's backbone), the shared preprocessing and
    precision rules, and this module (how images reach the model, how features are stored)."""
    classes = list(type(model).__mro__) + [type(m) for m in (model.modules() if hasattr(model, "modules") else [])]
    found = {f for f in map(_source_of, classes) if f is not None}
    return sorted(found) + [Path(local_norm.__file__), Path(precision.__file__), Path(__file__)]


def model_fingerprint(model: Any, n: int = 16) -> str:
    """Short hex sha256 of the model's class, configuration (:func:`_config_of`), state_dict bytes and encoding
    code (:func:`encoder_sources`).

    Two models with the same weights and config get the same key, so their
    reference features can be shared; any weight change gives a new key, and so
    does a change to the code that encodes (cached features of older code are
    never read back). ``model.config`` / ``model.cfg`` (dict or dataclass; optional) must be JSON-serialisable.
    """
    h = hashlib.sha256()
    cls = type(model)
    h.update(f"{cls.__module__}.{cls.__qualname__}".encode())
    h.update(f"code:{source_digest(encoder_sources(model))}".encode())
    h.update(json.dumps(_config_of(model), sort_keys=True, default=str).encode())
    if hasattr(model, "state_dict"):
        for name, t in sorted(model.state_dict().items()):
            if not torch.is_tensor(t):
                h.update(f"{name}={t!r}".encode())
                continue
            t = t.detach().cpu().contiguous().reshape(-1)
            h.update(f"{name}:{t.dtype}:{tuple(t.shape)}".encode())
            # Raw bytes via a uint8 view: works for every dtype, bfloat16 included.
            h.update(t.view(torch.uint8).numpy().tobytes())
    return h.hexdigest()[:n]


def _probe(images: np.ndarray) -> str:
    """Cheap content check of a view set: hash of its first, middle and last images."""
    h = hashlib.sha256(str(images.shape).encode())
    for i in sorted({0, len(images) // 2, len(images) - 1}):
        if len(images):
            h.update(np.ascontiguousarray(images[i]).tobytes())
    return h.hexdigest()[:16]


def _safe_key(key: str, what: str) -> str:
    if not key or any(c in key for c in "/\\\0") or key in (".", "..") or key.startswith("."):
        raise ValueError(f"FeatureCache: {what} {key!r} must be a non-empty name without path separators "
                         "and not starting with '.'")
    return key


def _check_keys(side: Path, meta: dict | None, keys: dict) -> None:
    if meta is not None and meta["keys"] != keys:
        diff = sorted(k for k in keys if meta["keys"].get(k) != keys[k])
        raise ValueError(f"{side}: cached features were built from different views (mismatch in {diff}); "
                         "use another refset_key or delete the cache entry")


class FeatureCache:
    """Content-keyed on-disk cache of reference feature maps (float16 memmaps).

    Args:
        root: cache folder (created on first build, not at construction).
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)

    def paths(self, model_key: str, refset_key: str) -> tuple[Path, Path, Path]:
        """(final .f16, sidecar .json, temporary .f16.partial) paths."""
        d = self.root / _safe_key(model_key, "model_key")
        base = _safe_key(refset_key, "refset_key")
        return d / f"{base}.f16", d / f"{base}.json", d / f".{base}.f16.partial"

    def load(self, model_key: str, refset_key: str, mark_used: bool = True) -> np.memmap | None:
        """The finished cached array (N, C, L) float16 read-only, or None if not built.
        ``mark_used`` records this as the entry's last use (``python -m helpers.study.cli.cache`` reads it)."""
        final, side, _ = self.paths(model_key, refset_key)
        if not final.is_file():
            return None
        meta = self._read_sidecar(side)
        if meta is None:
            raise DamagedEntry(f"{final}: feature file exists but its sidecar {side} is missing; delete it to rebuild")
        shape = tuple(meta["shape"])
        expected = int(np.prod(shape)) * 2
        if final.stat().st_size != expected:
            raise DamagedEntry(f"{final}: size {final.stat().st_size} bytes, expected {expected} "
                               f"for float16 {shape} (per {side}); delete both to rebuild")
        self._verify(final, side, meta, shape)
        if mark_used:
            touch(side)  # the sidecar's modification time is the entry's last use
        return np.memmap(final, dtype=np.float16, mode="r", shape=shape)

    def _verify(self, final: Path, side: Path, meta: dict, shape: tuple) -> None:
        """Content check, once per process and file version: the sha256 recorded when the
        file was finished must match (a changed or corrupted file is an error, never used).
        Files from before checksums were recorded are scanned for NaN/inf once and then
        get their checksum."""
        st = final.stat()
        stamp = (str(final), st.st_size, st.st_mtime_ns)
        if stamp in _VERIFIED:
            return
        digest = sha256_file(final)
        if meta.get("sha256") is None:
            mm = np.memmap(final, dtype=np.float16, mode="r", shape=shape)
            for s in range(0, shape[0], 256):
                if not np.isfinite(mm[s:s + 256]).all():
                    raise DamagedEntry(f"{final}: cached features hold NaN/inf (rows {s}..{s + 255}); "
                                     f"delete it and {side} to rebuild")
            del mm
            self._write_sidecar(side, shape, meta["done"], True, meta["keys"], digest)
        elif meta["sha256"] != digest:
            raise DamagedEntry(f"{final}: content does not match the checksum recorded in {side} when it was "
                             "written (changed or corrupted on disk); delete both to rebuild")
        _VERIFIED.add(stamp)

    @staticmethod
    def _read_sidecar(path: Path) -> dict | None:
        if not path.is_file():
            return None
        try:
            meta = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise DamagedEntry(f"{path}: malformed feature-cache sidecar ({e}); delete it to rebuild") from None
        for k in ("shape", "dtype", "done", "keys"):
            if k not in meta:
                raise DamagedEntry(f"{path}: feature-cache sidecar lacks key {k!r}; delete it to rebuild")
        return meta

    def get_or_build(self, model: Any, model_key: str, views: ObjectViews, refset_key: str,
                     batch: int = 64, device: str | torch.device = "cpu", progress: bool = True) -> np.memmap:
        """Return cached features of ``views``, encoding (or finishing) them first if needed.

        Args:
            model: object with ``encode`` (see :func:`encode_views`).
            model_key: identifies the weights, e.g. :func:`model_fingerprint`.
            views: the reference views; ``views.images`` is read one batch at a time.
            refset_key: identifies the view set (e.g. the render cache key).
            batch: images per forward pass; also the progress-saving granularity.
            device: where the model runs.
            progress: show a tqdm bar.

        Returns:
            (N, C, L) float16 read-only memmap.
        """
        images = views.images
        _check_images(images, f"get_or_build({views.name!r})")
        n = len(images)
        if n == 0:
            raise ValueError(f"get_or_build: views {views.name!r} is empty")
        keys = {"model_key": model_key, "refset_key": refset_key, "name": views.name, "n_views": n,
                "image_shape": list(images.shape[1:]), "probe": _probe(images)}
        final, side, _ = self.paths(model_key, refset_key)
        done = self._finished(model_key, refset_key, keys)
        if done is not None:
            settle(final)
            return done
        # One builder per file; a process that waited finds it finished and loads it.
        with entry_lock(final, f"features of {views.name} ({model_key}/{refset_key})"):
            done = self._finished(model_key, refset_key, keys, rebuild_damaged=True)
            if done is not None:
                return done
            return self._build(model, model_key, refset_key, images, keys, views.name, batch, device, progress)

    def _finished(self, model_key: str, refset_key: str, keys: dict, rebuild_damaged: bool = False
                  ) -> np.memmap | None:
        """The finished, intact file, or None. A damaged one is reported; with ``rebuild_damaged``
        (under the entry's lock) it is deleted so that it is rebuilt."""
        final, side, _ = self.paths(model_key, refset_key)
        try:
            meta = self._read_sidecar(side) if side.is_file() and final.is_file() else None
            _check_keys(side, meta, keys)
            return self.load(model_key, refset_key)
        except DamagedEntry as e:
            if not rebuild_damaged:
                return None
            warnings.warn(f"{e}; rebuilding it", RuntimeWarning, stacklevel=3)
            final.unlink(missing_ok=True)
            side.unlink(missing_ok=True)
            return None

    def _build(self, model: Any, model_key: str, refset_key: str, images: np.ndarray, keys: dict, name: str,
               batch: int, device: str | torch.device, progress: bool) -> np.memmap:
        """Encode ``images`` into the partial file (resuming where its sidecar says), then rename it into place."""
        final, side, tmp = self.paths(model_key, refset_key)
        n = len(images)
        for stray in side.parent.glob(f".{side.name}.*.tmp"):  # a killed writer's; we hold the lock
            stray.unlink(missing_ok=True)
        meta = self._read_sidecar(side) if side.is_file() else None
        _check_keys(side, meta, keys)
        if meta is not None and meta.get("complete") and tmp.is_file() and meta.get("sha256") == sha256_file(tmp):
            os.replace(tmp, final)  # killed between recording the checksum and the rename: nothing to redo
            return self.load(model_key, refset_key)
        # Resume only if the temporary file and its recorded progress agree.
        start, mm = 0, None
        if meta is not None and tmp.is_file() and not meta.get("complete", False):
            shape = tuple(meta["shape"])
            if tmp.stat().st_size == int(np.prod(shape)) * 2 and 0 < meta["done"] <= n:
                mm = np.memmap(tmp, dtype=np.float16, mode="r+", shape=shape)
                start = int(meta["done"])
        bar = tqdm(total=n, initial=start, desc=f"features {name}", unit="view", disable=not progress)
        try:
            pos = start
            for feats in encode_views(model, images, batch, device, start=start):
                if mm is None:
                    # Shape is known only after the first batch.
                    shape = (n, *feats.shape[1:])
                    preallocate(tmp, int(np.prod(shape)) * 2)  # full disk: an error now, not SIGBUS later
                    mm = np.memmap(tmp, dtype=np.float16, mode="r+", shape=shape)
                elif tuple(feats.shape[1:]) != mm.shape[1:]:
                    raise ValueError(f"get_or_build: model features {tuple(feats.shape[1:])} do not match "
                                     f"the partial cache {mm.shape[1:]} in {tmp}; delete it to rebuild")
                b = feats.shape[0]
                half = feats.numpy().astype(np.float16)
                if not np.isfinite(half).all():
                    raise ValueError(f"get_or_build: the model produced non-finite features for views "
                                     f"{pos}..{pos + b - 1} of {name!r} (NaN/inf, or beyond float16); "
                                     "not cached")
                mm[pos:pos + b] = half
                pos += b
                # Data first, then progress: the sidecar never claims unwritten rows.
                mm.flush()
                self._write_sidecar(side, mm.shape, pos, False, keys)
                bar.update(b)
        finally:
            bar.close()
        if pos != n:
            raise RuntimeError(f"get_or_build: encoded {pos} of {n} views of {name!r}")
        shape = mm.shape
        del mm  # close the writable map before the rename
        digest = sha256_file(tmp)
        # Checksum first, then the rename: a finished file always has its sha256 beside it.
        self._write_sidecar(side, shape, n, True, keys, digest)
        os.replace(tmp, final)
        out = self.load(model_key, refset_key)
        assert out is not None
        return out

    @staticmethod
    def _write_sidecar(path: Path, shape: tuple, done: int, complete: bool, keys: dict,
                       sha256: str | None = None) -> None:
        atomic_write_json(path, {"version": SIDECAR_VERSION, "shape": list(shape), "dtype": "float16",
                                 "done": int(done), "complete": bool(complete), "keys": keys,
                                 "sha256": sha256, "made_by": made_by()})

