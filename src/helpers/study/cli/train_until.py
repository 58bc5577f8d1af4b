"""Train a zoo recipe up to a deadline: ``python -m helpers.study.cli.zoo train NAME --until HH:MM`` (or
``--minutes N``).

The training runs in a child process (``zoo train NAME`` without a deadline); this process watches the run folder's
``history.json``, the last file an epoch writes. When the next epoch would end after the deadline (estimated from the
last epoch, validation included), the child is stopped at that epoch boundary, so no finished step is lost, and the
run's ``last.pt`` is copied to ``models/checkpoints/`` (:func:`helpers.study.zoo.snapshot`), ready to commit; a later
``zoo train NAME`` resumes from it on any machine. Why a child and not a flag inside ``train``: stopping between
epochs needs nothing from the training code, and a resumed run is already identical to an uninterrupted one.
"""

from __future__ import annotations

import datetime as dt
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...core.fileio import read_json
from ..pipeline import run_folder
from ..zoo import Recipe, recipe_data, snapshot

#: Allowance on a first epoch's recorded training seconds for its validation and checkpoint (no interval measured yet).
FIRST_EPOCH_SLACK = 1.15


def deadline_from(until: str = "", minutes: float = 0.0, now: dt.datetime | None = None) -> float:
    """Epoch seconds of the deadline: ``until`` "HH:MM" (local time, today, or tomorrow when already past) or
    ``minutes`` from now. ValueError naming the option when neither or both is given, or a value is malformed."""
    now = now or dt.datetime.now()
    if bool(until) == bool(minutes):
        raise ValueError("zoo train: give exactly one of --until HH:MM and --minutes N")
    if minutes:
        if minutes <= 0:
            raise ValueError(f"zoo train --minutes: expected a positive number, got {minutes}")
        return (now + dt.timedelta(minutes=minutes)).timestamp()
    try:
        t = dt.datetime.strptime(until, "%H:%M").time()
    except ValueError:
        raise ValueError(f"zoo train --until: expected HH:MM (24 h, local time), got {until!r}") from None
    at = dt.datetime.combine(now.date(), t)
    return (at if at > now else at + dt.timedelta(days=1)).timestamp()


def next_epoch_fits(now: float, deadline: float, epoch_s: float) -> bool:
    """Whether an epoch that starts at ``now`` and takes ``epoch_s`` seconds ends by ``deadline`` (all seconds)."""
    return now + epoch_s <= deadline


def _mtime(path: Path) -> float | None:
    try:
        return path.stat().st_mtime
    except FileNotFoundError:
        return None


def _stop(child: Any, grace_s: float = 60.0) -> None:
    """Terminate ``child`` (SIGTERM; SIGKILL after ``grace_s`` seconds) and reap it."""
    child.terminate()
    try:
        child.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        child.kill()
        child.wait()


def watch(child: Any, history: Path, deadline: float, epochs: int, poll_s: float = 5.0,
          clock: Callable[[], float] = time.time, sleep: Callable[[float], None] = time.sleep) -> str:
    """Wait for training process ``child`` (``poll``/``terminate``/``wait``/``kill``, as subprocess.Popen) whose run
    writes ``history`` ({"history": [{"epoch": e, "seconds": s, ...}, ...]}) at the end of each of its ``epochs``.

    Returns "finished" (the child exited 0), "stopped" (stopped at an epoch boundary because the next epoch would
    end after ``deadline``) or "deadline" (stopped at the deadline inside an epoch: only that epoch's steps are lost).
    RuntimeError when the child fails."""
    seen, boundary, epoch_s, final = _mtime(history), None, None, False
    while True:
        rc = child.poll()
        if rc is not None:
            if rc != 0:
                raise RuntimeError(f"zoo train: the training process exited with status {rc} (its output is above)")
            return "finished"
        now, m = clock(), _mtime(history)
        if m is not None and m != seen:  # an epoch has just ended: the child is at the start of the next one
            seen = m
            last = read_json(history)["history"][-1]
            # Between two boundaries seen here the interval is the whole epoch (validation, saving); before that,
            # the recorded training seconds with an allowance.
            epoch_s = now - boundary if boundary is not None else float(last.get("seconds", 0.0)) * FIRST_EPOCH_SLACK
            boundary = now
            # After the last epoch the child is finishing (done.json), not starting another: let it.
            final = int(last.get("epoch", 0)) >= epochs
            if not final and not next_epoch_fits(now, deadline, epoch_s):
                _stop(child)
                return "stopped"
        if now >= deadline and not final:
            _stop(child)
            return "deadline"
        sleep(poll_s)


def train_until(r: Recipe, deadline: float, recipes_path: str | Path, device: str = "auto",
                workers: int = 0) -> str:
    """Train (or resume) recipe ``r`` in a child process until it finishes or until the last epoch boundary before
    ``deadline`` (epoch seconds); a stopped run is snapshotted to ``models/checkpoints/``. Returns :func:`watch`'s
    answer. The views are rendered (or loaded) here first, so the child only loads them."""
    run = run_folder(r.split, r.train, recipe_data(r), r.val_refs)
    cmd = [sys.executable, "-m", "helpers.study.cli.zoo", "train", r.name, "--recipes", str(recipes_path),
           "--device", device] + (["--workers", str(workers)] if workers else [])
    env = {**os.environ, **({"HELPERS_CACHE_DIR": r.data.cache_dir} if r.data.cache_dir else {})}
    child = subprocess.Popen(cmd, env=env)
    try:
        how = watch(child, run / "history.json", deadline, r.train.epochs)
    except BaseException:
        if child.poll() is None:  # interrupted here (Ctrl-C): the child goes too, nothing trains unwatched
            _stop(child)
        raise
    if how != "finished":
        try:
            kept = f"checkpoint {snapshot(r)}"
        except FileNotFoundError:  # stopped inside its first epoch, with no committed checkpoint to resume from
            kept = "no epoch had finished, nothing to keep"
        print(f"{r.name}: stopped ({how}) at {time.strftime('%H:%M')}; {kept}", flush=True)
    return how
