"""Atomic file writes and content hashes.

Every artefact is written to a temporary file in the same directory and moved
into place with ``os.replace`` so an interrupted run never leaves a half
file that a later run would mistake for a finished one.
"""

from __future__ import annotations

import errno
import hashlib
import io
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd


def sha256_file(path: str | os.PathLike, bufsize: int = 1 << 20) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(bufsize):
            h.update(chunk)
    return h.hexdigest()


class DamagedEntry(ValueError):
    """A cached or committed file does not match the checksum recorded when it was written."""


# Files whose sha256 matched in this process: (path, size, mtime_ns) -> digest.
_VERIFIED: dict[tuple[str, int, int], str] = {}


def check_sha256(path: str | os.PathLike, expected: str, recorded_in: str | os.PathLike, recover: str) -> None:
    """Raise :class:`DamagedEntry` naming ``path`` unless its sha256 is ``expected``.

    A file is hashed once per process and version (path, size, mtime), so repeated loads
    cost nothing. ``recover`` says what the user can do ("delete <folder> to re-render").
    """
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise DamagedEntry(f"{path}: missing (recorded in {recorded_in}); {recover}") from None
    stamp = (str(path), st.st_size, st.st_mtime_ns)
    if _VERIFIED.get(stamp) == expected:
        return
    digest = sha256_file(path)
    if digest != expected:
        raise DamagedEntry(f"{path}: content does not match the sha256 recorded in {recorded_in} when it was "
                           f"written (changed, truncated or corrupted on disk); {recover}")
    _VERIFIED[stamp] = digest


def stable_hash(obj: Any, n: int = 16) -> str:
    """Short hex sha256 of a JSON-serialisable object (keys sorted)."""
    blob = json.dumps(obj, sort_keys=True, default=_json_default).encode()
    return hashlib.sha256(blob).hexdigest()[:n]


def source_digest(paths: list[str | os.PathLike], n: int = 16) -> str:
    """Short hex sha256 of the bytes of the source files ``paths`` (a folder: its regular ``*.py`` and ``*.cpp``
    files, not hidden ones such as an editor's ``.#x.py`` lock, not recursively), each with its folder/file name,
    in the order of those names.

    Cache keys take it so that an entry computed by older code is never read back after that code changed
    (what a file says, not its modification time or where the clone lies: two clones of one revision agree)."""
    files: dict[str, Path] = {}
    for p in map(Path, paths):
        for f in (sorted(p.iterdir()) if p.is_dir() else [p]):
            if f.suffix in (".py", ".cpp") and f.is_file() and not f.name.startswith("."):
                files[f"{f.parent.name}/{f.name}"] = f
    h = hashlib.sha256()
    for name in sorted(files):
        h.update(f"{name}\0".encode())
        h.update(files[name].read_bytes())
    return h.hexdigest()[:n]


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, Path):
        return str(o)
    if isinstance(o, (set, tuple)):
        return list(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _check_writable(directory: Path) -> None:
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OSError(f"cannot create output directory {directory}: {e.strerror}") from e
    if not os.access(directory, os.W_OK):
        raise PermissionError(f"output directory {directory} is not writable")


_WRITE_ERRORS = {errno.ENOSPC: "no space left on the device", errno.EDQUOT: "disk quota exceeded",
                 errno.EROFS: "the file system is read-only", errno.EACCES: "permission denied",
                 errno.EPERM: "operation not permitted"}


def _free_bytes(path: Path) -> int | None:
    for p in (path, *path.parents):
        if p.exists():
            try:
                return shutil.disk_usage(p).free
            except OSError:
                return None
    return None


@contextmanager
def output_errors(path: str | os.PathLike, nbytes: int | None = None) -> Iterator[None]:
    """Turn a full, read-only or forbidden output location into an error that names ``path``.

    The OSError keeps its errno; its message says which file could not be
    written, why, and (for a full disk) how many bytes were needed and free.
    """
    path = Path(path)
    try:
        yield
    except OSError as e:
        if e.errno not in _WRITE_ERRORS or str(path) in str(e):
            raise
        msg = f"cannot write {path}: {_WRITE_ERRORS[e.errno]}"
        if e.errno in (errno.ENOSPC, errno.EDQUOT):
            free = _free_bytes(path.parent)
            need = f"{nbytes} bytes needed, " if nbytes is not None else ""
            msg += f" ({need}{free if free is not None else '?'} bytes free)"
        msg += "; free some space or choose another output/cache directory (cache_dir, $HELPERS_CACHE_DIR)"
        raise OSError(e.errno, msg) from e


def preallocate(path: str | os.PathLike, nbytes: int) -> Path:
    """Create ``path`` with ``nbytes`` reserved on disk before it is memory-mapped.

    A memory map over a sparse file on a full disk dies with SIGBUS at the
    first page that cannot be stored; reserving the blocks first turns that
    into an ordinary, explained OSError here.
    """
    path = Path(path)
    _check_writable(path.parent)
    with output_errors(path, nbytes):
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            if nbytes > 0:
                if hasattr(os, "posix_fallocate"):
                    try:
                        os.posix_fallocate(fd, 0, nbytes)
                    except OSError as e:
                        if e.errno not in (errno.EOPNOTSUPP, errno.EINVAL):
                            raise
                        os.ftruncate(fd, nbytes)  # file system without fallocate: sparse is all we get
                else:
                    os.ftruncate(fd, nbytes)
        finally:
            os.close(fd)
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path.

    On any failure (full disk included) the temporary file is removed and an
    existing ``path`` is left untouched.
    """
    path = Path(path)
    _check_writable(path.parent)
    with output_errors(path, len(data)):
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, 0o644)  # mkstemp creates 0600; results are meant to be shared
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 text atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write JSON (indented, keys sorted) atomically."""
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


def atomic_save_npy(path: str | os.PathLike, array: np.ndarray) -> Path:
    """Save one array as ``.npy`` atomically (serialised in memory first)."""
    buf = io.BytesIO()
    np.save(buf, array)
    return atomic_write_bytes(path, buf.getvalue())


def touch(path: str | os.PathLike) -> None:
    """Set ``path``'s modification time to now (a cache entry's "last use"); a read-only cache is no error."""
    try:
        os.utime(path)
    except OSError:
        pass


def read_json(path: str | os.PathLike) -> Any:
    """Read JSON with an error that names the file."""
    path = Path(path)
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise FileNotFoundError(f"expected JSON file {path} does not exist") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: malformed JSON ({e.msg} at line {e.lineno} column {e.colno})") from None


def write_table(df: pd.DataFrame, path_stem: str | os.PathLike, floatfmt: str = ".2f",
                index: bool = False) -> tuple[Path, Path]:
    """Write ``<stem>.csv`` and ``<stem>.md`` (Markdown, floats as ``floatfmt``) atomically; returns both paths."""
    stem = Path(path_stem)
    csv = atomic_write_text(stem.with_suffix(".csv"), df.to_csv(index=index))
    md = atomic_write_text(stem.with_suffix(".md"), df.to_markdown(index=index, floatfmt=floatfmt) + "\n")
    return csv, md
