"""Shared measurement helpers of the CPU benchmark (``benchmarks/bench.py`` and its sections).

* :class:`Probe`: wall time, own CPU time and the share of the machine used by
  OTHER processes (from ``/proc/stat``) over a block;
* :func:`measure`: median of ``repeats`` timed runs after ``warmup`` untimed
  ones, re-running repeats that other processes disturbed;
* :func:`background_load` and the quiet gate (:func:`configure`,
  :func:`wait_quiet`): how busy the machine is, and waiting (within a budget)
  until it is quiet;
* :class:`PeakSampler` and :func:`memory_snapshot`: resident memory;
* :func:`log` and :func:`source_hashes` (which code was measured).

Only the standard library is imported at module level: the rendering workers
are *spawned* and re-import ``bench.py`` (and so this file) as ``__mp_main__``,
so heavy imports would inflate the measured worker start-up.
"""

from __future__ import annotations

import os
import resource
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

_CLK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
_NCPU = os.cpu_count() or 1


def _sys_jiffies() -> tuple[int, int] | None:
    """(busy, total) jiffies over all CPUs from /proc/stat, or None off Linux."""
    try:
        with open("/proc/stat") as f:
            vals = [int(v) for v in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    idle = vals[3] + vals[4]
    return sum(vals) - idle, sum(vals)


def _own_cpu_s() -> float:
    """CPU seconds of this process (all threads) plus its reaped children."""
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


class Probe:
    """Wall time, own CPU time and the share of the machine used by OTHER processes."""

    def __enter__(self) -> "Probe":
        self.j0, self.c0, self.t0 = _sys_jiffies(), _own_cpu_s(), time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        self.wall = time.perf_counter() - self.t0
        self.cpu = _own_cpu_s() - self.c0
        j1 = _sys_jiffies()
        self.others = None
        if self.j0 is not None and j1 is not None and j1[1] > self.j0[1]:
            busy_s = (j1[0] - self.j0[0]) / _CLK
            cap_s = (j1[1] - self.j0[1]) / _CLK  # = n_cpu x wall
            self.others = max(0.0, min(1.0, (busy_s - self.cpu) / cap_s))


def background_load(seconds: float = 1.0) -> float | None:
    """Fraction of all CPUs busy while this process sleeps (other processes' load)."""
    with Probe() as p:
        time.sleep(seconds)
    return p.others


class QuietGate:
    """Waits (within a total budget) until other processes leave the CPUs alone."""

    def __init__(self, threshold: float, budget_s: float):
        self.threshold, self.budget_s, self.waited_s = threshold, budget_s, 0.0

    def wait(self) -> float | None:
        """Block until background load < threshold or the budget is spent; returns the last load."""
        load = background_load(0.5)
        while load is not None and load >= self.threshold and self.waited_s < self.budget_s:
            t = time.perf_counter()
            time.sleep(2.0)
            load = background_load(1.0)
            self.waited_s += time.perf_counter() - t
        return load


# The gate and retry count of the current run; :func:`configure` replaces them
# (``bench.run`` does, from the run's config). Section modules read them through
# :func:`gate` / :func:`wait_quiet` at call time, never by importing the names.
_GATE = QuietGate(0.2, 0.0)
_RETRIES = 2


def configure(threshold: float, budget_s: float, retries: int) -> QuietGate:
    """Install a fresh quiet gate (threshold, waiting budget) and the retry count for contended repeats."""
    global _GATE, _RETRIES
    _GATE = QuietGate(threshold, budget_s)
    _RETRIES = retries
    return _GATE


def gate() -> QuietGate:
    """The current quiet gate (its ``threshold`` marks a contended run; ``waited_s`` the time spent waiting)."""
    return _GATE


def wait_quiet() -> float | None:
    """Wait (within the gate's budget) until other processes leave the CPUs; returns the last load."""
    return _GATE.wait()


def measure(fn: Callable[[Any], Any], repeats: int, warmup: int = 1, setup: Callable[[], Any] | None = None,
            teardown: Callable[[Any], None] | None = None, retries: int | None = None) -> dict:
    """Median wall time of ``fn(setup())`` over ``repeats`` runs after ``warmup`` runs.

    ``setup``/``teardown`` run outside the timed region. A repeat during which
    other processes used more than the gate's threshold of the machine is
    re-run (after waiting for quiet, within the gate's budget) up to
    ``retries`` times; the last attempt is kept either way and the
    contention it saw is recorded.
    """
    if repeats < 1:
        raise ValueError(f"measure: repeats must be >= 1, got {repeats}")
    retries = _RETRIES if retries is None else retries

    def once() -> Probe:
        arg = setup() if setup else None
        try:
            with Probe() as p:
                fn(arg)
        finally:
            if teardown:
                teardown(arg)
        return p

    for _ in range(warmup):
        once()
    walls, cpus, others, n_retried = [], [], [], 0
    for _ in range(repeats):
        p = once()
        for _ in range(retries):
            if p.others is None or p.others < _GATE.threshold:
                break
            n_retried += 1
            _GATE.wait()
            p = once()
        walls.append(p.wall)
        cpus.append(p.cpu)
        others.append(p.others)
    med = statistics.median(walls)
    known = [o for o in others if o is not None]
    return {"median_s": med, "min_s": min(walls), "max_s": max(walls), "all_s": walls,
            "repeats": repeats, "warmup": warmup,
            "cpu_s_per_wall_s": statistics.median(cpus) / med if med > 0 else None,
            "others_cpu_fraction": statistics.median(known) if known else None,
            "contended_repeats": sum(1 for o in known if o >= _GATE.threshold),
            "retried_repeats": n_retried}


def _proc_status() -> dict:
    out = {}
    try:
        with open("/proc/self/status") as f:
            for line in f:
                k, _, v = line.partition(":")
                if k in ("VmHWM", "VmRSS", "RssAnon", "RssFile"):
                    out[k] = int(v.split()[0]) * 1024
    except OSError:
        pass
    return out


class PeakSampler:
    """Background thread recording the peak anonymous and file-backed RSS (every 0.1 s)."""

    def __init__(self, interval: float = 0.1):
        import threading

        self.interval, self.peak = interval, {"RssAnon": 0, "RssFile": 0}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            st = _proc_status()
            for k in self.peak:
                self.peak[k] = max(self.peak[k], st.get(k, 0))
            self._stop.wait(self.interval)

    def start(self) -> "PeakSampler":
        self._thread.start()
        return self

    def reset(self) -> dict:
        """Return the peaks since the last reset and start again from the current values."""
        out = dict(self.peak)
        st = _proc_status()
        self.peak = {k: st.get(k, 0) for k in self.peak}
        return out

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def memory_snapshot() -> dict:
    """Peak RSS of this process (ru_maxrss) and its current anonymous / file-backed RSS."""
    out = {"maxrss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
           "children_maxrss_bytes": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024}
    out.update(_proc_status())
    return out


def log(msg: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


MEASURED_MODULES = ("net/model.py", "core/configs/model.py", "core/configs/search.py", "core/configs/train.py",
                    "core/configs/data.py", "core/configs/_checks.py", "net/fusion_kernel.py",
                    "net/fusion_kernel.cpp", "search/retrieval.py", "search/bank.py", "search/fps.py", "search/features.py",
                    "data/datasets.py", "data/render.py", "data/gl.py", "core/rotations.py", "training/losses.py",
                    "training/train.py", "training/augment.py")


def source_hashes() -> dict:
    """sha256 of the helpers modules whose speed is measured (the working tree may differ from git HEAD)."""
    import helpers
    from helpers.core.fileio import sha256_file

    root = Path(helpers.__file__).parent
    return {m: sha256_file(root / m)[:16] for m in MEASURED_MODULES if (root / m).exists()}
