"""glibc malloc settings for CPU training: keep freed tensor memory in the process.

Why: a training step on CPU allocates and frees activations of tens of MB (48 images x 64
channels x 64 x 64 x 4 bytes = 50 MB). glibc serves such blocks with ``mmap`` and returns
them to the kernel on ``free``, so every step maps fresh pages and the kernel zeroes each
4 KiB page on first touch: measured on a 2-core AMD EPYC VM (AVX2, fp32) as about 30,000
minor page faults per second and a third of the CPU time in the kernel
(``benchmarks/malloc_ab.py`` measures the images/s ratio). Raising the mmap threshold and the
trim threshold makes glibc keep freed blocks on its heap for the next step.

Why not a library: jemalloc or tcmalloc would do the same but must be preloaded
(``LD_PRELOAD``) before Python starts, which a Jupyter kernel or a papermill run cannot do
for itself; ``mallopt`` is glibc's documented run-time switch, reached through ctypes.
Where libc is not glibc (musl, macOS, Windows) nothing is changed and the result says so.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from functools import lru_cache

# mallopt parameter numbers from glibc's <malloc.h>
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3

MMAP_THRESHOLD = 1 << 30     # bytes: blocks below 1 GiB come from the heap, not from mmap
TRIM_THRESHOLD = (1 << 31) - 1  # bytes: the heap's free top is kept up to 2 GiB (mallopt takes an int)
TOP_PAD = 256 << 20          # bytes: extra heap requested per growth, so growth happens rarely

ENV_OPT_OUT = "HELPERS_KEEP_FREED_MEMORY"  # "0": leave glibc's defaults (for A/B runs)


def _glibc() -> ctypes.CDLL | None:
    """The process's C library when it is glibc, else None."""
    try:
        libc = ctypes.CDLL(None)
        version = libc.gnu_get_libc_version
    except (OSError, AttributeError):
        return None
    version.restype = ctypes.c_char_p
    libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    libc.mallopt.restype = ctypes.c_int
    return libc


@lru_cache(maxsize=1)
def keep_freed_memory() -> dict:
    """Set glibc's mmap and trim thresholds (once per process; later calls return the first result).

    Returns a record for run files: ``{"allocator": "glibc 2.36", "keep_freed_memory": True,
    "mmap_threshold": bytes, "trim_threshold": bytes, "top_pad": bytes}``, or
    ``keep_freed_memory: False`` with ``reason`` where nothing was changed (not glibc, opted out
    with ``HELPERS_KEEP_FREED_MEMORY=0``, or mallopt refused). Process-wide and not undone: the
    memory kept is reused by the next step (peak resident memory grows by about one step's
    activations, 0.2 GB at batch 16 and 64 px).
    """
    if os.environ.get(ENV_OPT_OUT, "1") == "0":
        return {"allocator": None, "keep_freed_memory": False, "reason": f"{ENV_OPT_OUT}=0"}
    libc = _glibc()
    if libc is None:
        return {"allocator": None, "keep_freed_memory": False, "reason": "C library is not glibc"}
    name = "glibc " + libc.gnu_get_libc_version().decode()
    wanted = ((_M_MMAP_THRESHOLD, MMAP_THRESHOLD, "mmap_threshold"), (_M_TRIM_THRESHOLD, TRIM_THRESHOLD,
              "trim_threshold"), (_M_TOP_PAD, TOP_PAD, "top_pad"))
    refused = [key for param, value, key in wanted if libc.mallopt(param, value) != 1]
    if refused:
        return {"allocator": name, "keep_freed_memory": False, "reason": f"mallopt refused {refused}"}
    return {"allocator": name, "keep_freed_memory": True, **{key: value for _, value, key in wanted}}
