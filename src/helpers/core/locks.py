"""One builder per cache entry: inter-process locks that say who holds them.

Every cache entry (a render set, a feature file, a training run, a bring-your-own reference
set, a runner's report folder) is built under :func:`entry_lock`. The lock is an OS file lock
(``filelock``, i.e. ``flock``): the kernel drops it when its process dies, so a killed builder
never leaves a lock that blocks the next run. Beside the lock file an *owner record* names the
holding process; it is written after the lock is taken and removed before it is released, so an
owner record found by a process that just took the lock means its previous holder died while
building (reported with a warning; the entry's resumable state is then reused or rebuilt by the
caller). A process waiting for a live builder prints what it waits for every ``report_every``
seconds and gives up after ``timeout`` seconds (``$HELPERS_LOCK_TIMEOUT``, default 6 h) with an
error naming the entry, the lock and the holder.

Why filelock and not the fusion kernel's O_EXCL lock file: an flock cannot outlive its process,
so no stale-lock guessing (pid checks, host names) is needed, and waiting costs no polling race.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from filelock import FileLock, Timeout

from .fileio import atomic_write_json

#: Default limit on waiting for another process's build, seconds (override: $HELPERS_LOCK_TIMEOUT).
DEFAULT_TIMEOUT_S = 6 * 3600.0
#: How often a waiting process says what it waits for, seconds.
REPORT_EVERY_S = 30.0

# Locks this process holds: path -> [FileLock, depth] (re-entrant: a holder may take it again).
_HELD: dict[str, list] = {}


class LockTimeout(TimeoutError):
    """Waited longer than the limit for another process building the same entry."""


def made_by() -> str:
    """Who is building: ``$HELPERS_MADE_BY`` (the runner sets ``<preset>/<notebook>``), else the
    program's name ("notebook" for an interactive kernel)."""
    env = os.environ.get("HELPERS_MADE_BY")
    if env:
        return env
    prog = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "python"
    return "notebook" if prog in ("ipykernel_launcher.py", "-c") and "ipykernel" in sys.modules else prog


def lock_path(entry: str | os.PathLike) -> Path:
    """The lock file of ``entry`` (a file or folder): ``.<name>.lock`` beside it."""
    entry = Path(entry)
    return entry.with_name(f".{entry.name}.lock")


def _owner_path(lock: Path) -> Path:
    return lock.with_name(lock.name + ".owner")


def read_owner(entry: str | os.PathLike) -> dict | None:
    """The owner record of ``entry``'s lock ({"pid", "host", "started", "what"}), or None."""
    try:
        d = json.loads(_owner_path(lock_path(entry)).read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def _timeout(timeout: float | None) -> float:
    if timeout is not None:
        return float(timeout)
    env = os.environ.get("HELPERS_LOCK_TIMEOUT", "")
    try:
        return float(env) if env else DEFAULT_TIMEOUT_S
    except ValueError:
        raise ValueError(f"$HELPERS_LOCK_TIMEOUT: expected seconds (a number), got {env!r}") from None


def _describe(owner: dict | None) -> str:
    if not owner:
        return "another process"
    return f"process {owner.get('pid')} on {owner.get('host')} (since {owner.get('started')})"


def _key(lock: Path) -> str:
    lock.parent.mkdir(parents=True, exist_ok=True)
    return str(lock.parent.resolve() / lock.name)


@contextmanager
def _holding(fl: FileLock, key: str, entry: str | os.PathLike, what: str, warn_stale: bool) -> Iterator[None]:
    """With ``fl`` acquired: report a dead previous holder, record this process as owner, release at exit."""
    lock = Path(fl.lock_file)
    owner = _owner_path(lock)
    _HELD[key] = [fl, 1]
    try:
        stale = read_owner(entry)
        for stray in lock.parent.glob(f".{owner.name}.*.tmp"):  # a holder killed while writing its record
            stray.unlink(missing_ok=True)  # (only the holder writes it, and we hold the lock now)
        if stale is not None and warn_stale:
            warnings.warn(f"{what}: its previous builder, {_describe(stale)}, died before finishing (lock {lock}); "
                          "its finished parts are reused, the rest is rebuilt", RuntimeWarning, stacklevel=4)
        atomic_write_json(owner, {"pid": os.getpid(), "host": socket.gethostname(),
                                  "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                                  "what": what, "by": made_by()})
        yield
    finally:
        owner.unlink(missing_ok=True)
        del _HELD[key]
        fl.release()


@contextmanager
def _reenter(key: str) -> Iterator[None]:
    _HELD[key][1] += 1
    try:
        yield
    finally:
        _HELD[key][1] -= 1


@contextmanager
def entry_lock(entry: str | os.PathLike, what: str, timeout: float | None = None,
               report_every: float = REPORT_EVERY_S) -> Iterator[None]:
    """Hold the lock of cache entry ``entry`` (file or folder path) for the ``with`` block.

    Args:
        entry: the entry's final path; the lock is ``.<name>.lock`` beside it (the parent
            folder is created).
        what: the entry in words, for messages ("render set ape/reference-1a2b").
        timeout: give up waiting after this many seconds (None: $HELPERS_LOCK_TIMEOUT or 6 h).
        report_every: seconds between "waiting for ..." messages on stderr.

    Raises:
        LockTimeout: another live process held it for longer than ``timeout``.
    """
    lock = lock_path(entry)
    key = _key(lock)
    if key in _HELD:  # re-entrant within one process
        with _reenter(key):
            yield
        return
    fl = FileLock(str(lock), thread_local=False)
    limit, t0 = _timeout(timeout), time.monotonic()
    while True:
        try:
            fl.acquire(timeout=max(0.0, min(report_every, limit - (time.monotonic() - t0))))
            break
        except Timeout:
            waited = time.monotonic() - t0
            holder = _describe(read_owner(entry))
            if waited >= limit:
                raise LockTimeout(f"{what}: waited {waited:.0f} s for {holder} building it (lock {lock}); "
                                  "raise the limit with $HELPERS_LOCK_TIMEOUT (seconds) if that build is "
                                  "expected to take longer") from None
            print(f"[helpers] {what}: waiting for {holder}, which is building it ({waited:.0f} s so far; "
                  f"lock {lock})", file=sys.stderr, flush=True)
    with _holding(fl, key, entry, what, warn_stale=True):
        yield


def is_locked(entry: str | os.PathLike) -> bool:
    """Whether some live process (this one included) holds ``entry``'s lock right now."""
    lock = lock_path(entry)
    if not lock.exists():
        return False
    if _key(lock) in _HELD:
        return True
    fl = FileLock(str(lock), thread_local=False)
    try:
        fl.acquire(timeout=0)
    except Timeout:
        return True
    fl.release()
    return False


@contextmanager
def try_entry_lock(entry: str | os.PathLike, what: str) -> Iterator[bool]:
    """Take ``entry``'s lock only if it is free right now; yields whether it was taken.

    For cleaning up: an entry that a live process is building is left alone. A dead
    builder's owner record is not warned about (the caller reports what it removes)."""
    lock = lock_path(entry)
    key = _key(lock)
    if key in _HELD:
        with _reenter(key):
            yield True
        return
    fl = FileLock(str(lock), thread_local=False)
    try:
        fl.acquire(timeout=0)
    except Timeout:
        yield False
        return
    with _holding(fl, key, entry, what, warn_stale=False):
        yield True


def settle(entry: str | os.PathLike) -> None:
    """For an entry found finished without taking its lock: remove the owner record of a builder that
    died after finishing it but before releasing (the lock is free; one stat when there is none)."""
    if _owner_path(lock_path(entry)).exists():
        with try_entry_lock(entry, "settling a finished entry"):
            pass  # holding the free lock, then releasing it, removes the dead builder's record
