"""Fused CPU kernels: the inference-time fusion of one query against many references, and
farthest point sampling on SO(3) (the inner loop of fast retrieval's rotation stage).

The eager PyTorch fusion (:func:`helpers.net.model._fuse_block`) runs five or six
element-wise passes over each (references x C x X) block and pays Python
dispatch per small block; on CPU it reaches 1-3 % of the machine's GEMM rate
(``benchmarks/README.md``). This kernel does the same arithmetic in two
passes over each reference, in cache:

1. ``p = q * r_j`` (float16 references converted with F16C when the compiler
   targets it) and the logits ``l_k(x) = sum_c W[k, c] p[c, x] + b[k]``;
2. the normalised fusion weights ``a(x)`` (stable softmax of the variant's
   log-weights, as :meth:`helpers.net.model.Fusion.log_weights`) and
   ``v[c] = sum_x a(x) p[c, x]``,

parallel over references with torch's intra-op threads (each reference is
computed by one thread, so results do not depend on the thread count).
``fuse`` does one level for a block of references; ``fuse_levels`` does every
level of each reference in one call and reads the references it is given by
row index in place (a whole memory-mapped bank, no gathered copy): one Python
call per query instead of one per level, which is what made small scoring calls
(the coarse-to-fine search's rounds) pay more for overhead than for arithmetic.
The weighted sum of pass 2 runs four channels at a time (independent sums).

The C++ lives in ``fusion_kernel.cpp`` beside this loader. It is built on first use with
``torch.utils.cpp_extension.load_inline`` (gcc
and ninja, about 30 s once per machine) into ``<cache>/ext/<hash>`` and
loaded from there afterwards. Importing this module builds nothing. If the
build fails (no compiler, no ninja) or ``HELPERS_FUSION_KERNEL=0`` is set,
:func:`get` returns None and callers use the eager path; :func:`status`
says which and why. Inference only: there is no backward. ``fps`` returns exactly the
indices of the numpy loop in :func:`helpers.core.rotations.farthest_point_sampling`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import platform
import socket
import threading
import time
import warnings
from pathlib import Path
from typing import Any

from ..core.paths import cache_dir

#: log-weight rule per fusion variant (see helpers.net.model.Fusion.log_weights).
MODES = {"adaptive": 0, "sigmoid": 1, "softmax": 2}

#: The kernels' C++ source, next to this file (read when building, never at import).
_CPP = Path(__file__).with_name("fusion_kernel.cpp")


def _source() -> str:
    return _CPP.read_text()


# -ffast-math lets gcc vectorise the sums (the kernel needs no inf/NaN semantics: the max starts
# from the first value); -fopenmp makes at::parallel_for actually use torch's threads.
_CFLAGS = ["-O3", "-march=native", "-ffast-math", "-fopenmp"]
_LDFLAGS = ["-fopenmp"]

_lock = threading.Lock()
_state: dict[str, Any] = {"module": None, "tried": False, "reason": "not built yet", "build_seconds": None,
                          "build_dir": None}


def _cpu_tag() -> str:
    """Distinguishes machines for -march=native builds (ISA flags of this CPU)."""
    flags = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                flags = line
                break
    except OSError:
        pass
    return hashlib.sha256(f"{platform.machine()}|{flags}".encode()).hexdigest()[:8]


def build_dir() -> Path:
    """Where the extension is built: ``$HELPERS_EXT_DIR`` or ``<cache>/ext``, then a content hash."""
    import torch

    root = Path(os.environ["HELPERS_EXT_DIR"]) if os.environ.get("HELPERS_EXT_DIR") else cache_dir() / "ext"
    key = hashlib.sha256("|".join([_source(), " ".join(_CFLAGS + _LDFLAGS), torch.__version__, _cpu_tag()]).encode())
    return root / f"fusion_{key.hexdigest()[:16]}"


def _build() -> tuple[Any, Path]:
    """Build (or load an earlier build of) the extension; returns (module, its build folder)."""
    import torch.utils.cpp_extension as ext

    try:
        import ninja  # noqa: F401  (the PyPI wheel ships the binary torch's builder calls)
        ninja_bin = getattr(ninja, "BIN_DIR", None)
    except ImportError:
        ninja_bin = None
    where = build_dir()
    where.mkdir(parents=True, exist_ok=True)
    old_path = os.environ.get("PATH", "")
    if ninja_bin:
        # torch looks ninja up on PATH; a venv used without activation does not have it there.
        os.environ["PATH"] = f"{ninja_bin}{os.pathsep}{old_path}"
    try:
        module = ext.load_inline(name=f"helpers_fusion_{where.name.split('_')[1]}", cpp_sources=_source(),
                                 functions=["fuse", "fuse_levels", "fps"],  # copies: torch appends to the lists it is given
                                 extra_cflags=list(_CFLAGS), extra_ldflags=list(_LDFLAGS),
                                 build_directory=str(where), verbose=False)
        return module, where
    finally:
        os.environ["PATH"] = old_path


BUILD_TIMEOUT_S = 600.0
"""Default for ``$HELPERS_KERNEL_BUILD_TIMEOUT``: the longest a run waits for the kernel (another
process's build, or its own) before it goes on with the eager fusion."""

_LOCK_NAME = "helpers_build.lock"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _lock_owner(path: Path) -> dict | None:
    """{"pid", "host", "started"} recorded in a build lock, or None if unreadable."""
    try:
        d = json.loads(path.read_text())
        return d if isinstance(d, dict) and "pid" in d else None
    except (OSError, ValueError):
        return None


def _stale(owner: dict | None, path: Path, timeout: float) -> bool:
    """A lock is stale when its process is gone (same host), or, where that cannot be
    checked (another host, unreadable file), when it is older than ``timeout``."""
    if owner is not None and owner.get("host") == socket.gethostname():
        return not _pid_alive(int(owner["pid"]))
    try:
        return time.time() - path.stat().st_mtime > timeout
    except OSError:
        return True


def acquire_build_lock(where: Path, timeout: float, poll: float = 0.5, report_every: float = 30.0) -> bool:
    """Take the build lock of ``where`` (created atomically), clearing stale ones.

    While another live process builds, waits up to ``timeout`` seconds with a
    warning every ``report_every`` seconds naming the process and the lock file.
    Returns False if the lock is still held by a live process after ``timeout``.
    Every process takes this lock before calling torch's builder, so a leftover
    torch ``lock`` file found while holding it is stale and is removed (torch's own
    wait on it has no time limit).
    """
    path = where / _LOCK_NAME
    t0 = last = time.monotonic()
    while True:
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            owner = _lock_owner(path)
            if _stale(owner, path, timeout):
                warnings.warn(f"helpers.net.fusion_kernel: removing stale build lock {path} (owner {owner}: process "
                              "gone)", RuntimeWarning, stacklevel=3)
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
                continue
            now = time.monotonic()
            if now - t0 >= timeout:
                return False
            if now - last >= report_every:
                warnings.warn(f"helpers.net.fusion_kernel: waiting {now - t0:.0f} s (limit {timeout:.0f} s) for the "
                              f"kernel build of process {owner and owner.get('pid')} on {owner and owner.get('host')} "
                              f"(lock {path})", RuntimeWarning, stacklevel=3)
                last = now
            time.sleep(poll)
            continue
        with os.fdopen(fd, "w") as f:
            json.dump({"pid": os.getpid(), "host": socket.gethostname(), "started": time.time()}, f)
        torch_lock = where / "lock"
        if torch_lock.exists():
            warnings.warn(f"helpers.net.fusion_kernel: removing torch's leftover build lock {torch_lock} "
                          "(from an interrupted build)", RuntimeWarning, stacklevel=3)
            with contextlib.suppress(FileNotFoundError):
                torch_lock.unlink()
        return True


def release_build_lock(where: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        (where / _LOCK_NAME).unlink()


def _timeout() -> float:
    raw = os.environ.get("HELPERS_KERNEL_BUILD_TIMEOUT", "")
    try:
        return float(raw) if raw.strip() else BUILD_TIMEOUT_S
    except ValueError:
        raise ValueError(f"HELPERS_KERNEL_BUILD_TIMEOUT: expected seconds, got {raw!r}") from None


def _build_limited(timeout: float) -> tuple[Any, Path]:
    """:func:`_build` under the cross-process build lock, the whole of it (waiting for another
    build, then building) limited to ``timeout`` seconds; raises TimeoutError past it."""
    where = build_dir()
    where.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    if not acquire_build_lock(where, timeout):
        owner = _lock_owner(where / _LOCK_NAME)
        raise TimeoutError(f"waited {timeout:.0f} s for the build of process {owner and owner.get('pid')} "
                           f"(lock {where / _LOCK_NAME})")
    result: dict[str, Any] = {}

    def work() -> None:
        try:
            result["value"] = _build()
        except BaseException as e:  # handed to the caller below
            result["error"] = e
        finally:
            release_build_lock(where)

    # A daemon thread so that a compiler that never returns cannot hold the run: past the limit the
    # caller goes on (eager fusion); if the process then exits, the lock it leaves names a dead pid.
    th = threading.Thread(target=work, name="fusion-kernel-build", daemon=True)
    th.start()
    th.join(max(1.0, timeout - (time.monotonic() - t0)))
    if th.is_alive():
        raise TimeoutError(f"the kernel build in {where} did not finish within {timeout:.0f} s")
    if "error" in result:
        raise result["error"]
    return result["value"]


def get() -> Any | None:
    """The compiled module (with ``fuse``), building it on first call; None if unavailable.

    Disabled by ``HELPERS_FUSION_KERNEL=0``. A failed build is reported once
    as a warning and not retried in this process. Builds of several processes are
    serialised by a lock file that names its process; a lock left by a dead process
    is cleared, and waiting plus building is limited to ``$HELPERS_KERNEL_BUILD_TIMEOUT``
    seconds (default :data:`BUILD_TIMEOUT_S`), after which the eager fusion is used
    with a warning.
    """
    if os.environ.get("HELPERS_FUSION_KERNEL", "1").strip().lower() in ("0", "false", "no", "off"):
        _state["reason"] = "disabled by HELPERS_FUSION_KERNEL"
        return None
    if _state["tried"]:
        return _state["module"]
    with _lock:
        if not _state["tried"]:
            t0 = time.perf_counter()
            try:
                module, where = _build_limited(_timeout())
                _state["module"] = module
                _state["reason"] = None
                _state["build_dir"] = str(where)
            except Exception as e:  # compiler, ninja or headers missing: fall back, say why
                _state["module"] = None
                _state["reason"] = f"build failed: {type(e).__name__}: {str(e).splitlines()[0][:300] if str(e) else ''}"
                warnings.warn(f"helpers.net.fusion_kernel: {_state['reason']}; using the eager PyTorch fusion "
                              "and numpy farthest point sampling (slower, same results)", RuntimeWarning, stacklevel=2)
            _state["build_seconds"] = time.perf_counter() - t0
            _state["tried"] = True
    return _state["module"]


def status() -> dict[str, Any]:
    """{"available", "reason" (None when available), "build_seconds" (this process), "build_dir"}."""
    return {"available": _state["module"] is not None, "reason": _state["reason"],
            "build_seconds": _state["build_seconds"], "build_dir": _state["build_dir"]}
