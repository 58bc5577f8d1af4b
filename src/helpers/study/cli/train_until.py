"""Train a zoo recipe up to a deadline: ``python -m helpers.study.cli.zoo train NAME --until HH:MM`` (or
``--minutes N``).

The training runs in a child process (``zoo train NAME`` without a deadline); this process watches the run folder's
``history.json``, the last file an epoch writes. When the next epoch would end after the deadline (estimated by the
longest epoch seen, validation included), the child is stopped at that epoch boundary, so no finished step is lost, and the
run's ``last.pt`` is copied to ``models/checkpoints/`` (:func:`helpers.study.zoo.snapshot`), ready to commit; a later
``zoo train NAME`` resumes from it on any machine. Why a child and not a flag inside ``train``: stopping between
epochs needs nothing from the training code, and a resumed run is already identical to an uninterrupted one.
"""

from __future__ import annotations

import datetime as dt
import os
import signal
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


def _epochs_done(history: Path) -> tuple[int, float]:
    """(epochs recorded in ``history``, the last one's training seconds); (0, 0.0) before the first epoch. The file
    is replaced atomically, so a read never sees half of it."""
    try:
        entries = read_json(history)["history"]
    except FileNotFoundError:
        return 0, 0.0
    return (int(entries[-1]["epoch"]), float(entries[-1].get("seconds", 0.0))) if entries else (0, 0.0)


def _stop(child: Any, grace_s: float = 60.0) -> None:
    """Stop ``child`` as Ctrl-C would (SIGINT: its clean-up runs and its locks record no dead owner); SIGTERM, then
    SIGKILL, after ``grace_s`` seconds each. Reaps it."""
    for send in (lambda: child.send_signal(signal.SIGINT), child.terminate, child.kill):
        send()
        try:
            child.wait(timeout=grace_s)
            return
        except subprocess.TimeoutExpired:
            continue


def watch(child: Any, history: Path, deadline: float, epochs: int, poll_s: float = 5.0,
          clock: Callable[[], float] = time.time, sleep: Callable[[float], None] = time.sleep) -> str:
    """Wait for training process ``child`` (``poll``/``send_signal``/``terminate``/``wait``/``kill``, as
    subprocess.Popen) whose run records each of its ``epochs`` in ``history`` ({"history": [{"epoch": e,
    "seconds": s, ...}, ...]}) as the epoch ends; ``deadline`` and ``clock`` in seconds since the epoch.

    Returns "finished" (the child exited 0), "stopped" (stopped at an epoch boundary because the next epoch would
    end after ``deadline``) or "deadline" (stopped at the deadline inside an epoch: only that epoch's steps are lost).
    RuntimeError when the child fails."""
    done, _ = _epochs_done(history)
    boundary, longest = None, 0.0
    while True:
        rc = child.poll()
        if rc is not None:
            if rc != 0:
                raise RuntimeError(f"zoo train: the training process exited with status {rc} (its output is above)")
            return "finished"
        now = clock()
        n, seconds = _epochs_done(history)
        if n > done:  # an epoch has just ended (counted, not dated: a coarse file clock cannot hide one)
            done = n
            # The longest epoch seen, boundary to boundary (validation and saving included: a validating epoch
            # is the longer one when validation is not every epoch); before the second boundary, the recorded
            # training seconds with an allowance.
            if boundary is not None:
                longest = max(longest, now - boundary)
            epoch_s = longest if boundary is not None else seconds * FIRST_EPOCH_SLACK
            boundary = now
            if done < epochs and not next_epoch_fits(now, deadline, epoch_s):
                _stop(child)
                return "stopped"
        # After the last epoch the child is finishing (done.json), not starting another: let it.
        if now >= deadline and done < epochs:
            _stop(child)
            return "deadline"
        sleep(poll_s)


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def train_until(r: Recipe, deadline: float, recipes_path: str | Path, device: str = "auto",
                workers: int = 0) -> str:
    """Train (or resume) recipe ``r`` in a child process until it finishes or until the last epoch boundary before
    ``deadline`` (epoch seconds); a stopped run is snapshotted to ``models/checkpoints/``. Returns :func:`watch`'s
    answer, or "interrupted" (Ctrl-C or SIGTERM here: the child is stopped and its checkpoint kept as well). The
    views are rendered (or loaded) here first, so the child only loads them."""
    if os.environ.get("RANK") or os.environ.get("WORLD_SIZE", "1") != "1":
        raise ValueError("zoo train --until: not under torchrun (each rank would start its own training)")
    run = run_folder(r.split, r.train, recipe_data(r), r.val_refs)
    cmd = [sys.executable, "-m", "helpers.study.cli.zoo", "train", r.name, "--recipes", str(recipes_path),
           "--device", device] + (["--workers", str(workers)] if workers else [])
    env = {**os.environ, **({"HELPERS_CACHE_DIR": r.data.cache_dir} if r.data.cache_dir else {})}
    # Its own session: Ctrl-C here reaches this process alone, which then stops the child and keeps its checkpoint.
    # SIGINT back to its default: a shell's background job inherits it ignored, and then Python never raises
    # KeyboardInterrupt in the child (seen: the stop waited out its grace and fell to SIGTERM).
    child = subprocess.Popen(cmd, env=env, start_new_session=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    # SIGTERM here (kill, a scheduler) ends the watch like Ctrl-C: the child never trains on unwatched.
    old = signal.signal(signal.SIGTERM, _interrupt)
    try:
        how = watch(child, run / "history.json", deadline, r.train.epochs)
    except KeyboardInterrupt:
        _stop(child)
        how = "interrupted"
    finally:
        signal.signal(signal.SIGTERM, old)
        if child.poll() is None:  # an error in the watch itself: nothing trains unwatched
            _stop(child)
    if how != "finished":
        try:
            kept = f"checkpoint {snapshot(r)}"
        except FileNotFoundError:  # stopped inside its first epoch, with no committed checkpoint to resume from
            kept = "no epoch had finished, nothing to keep"
        print(f"{r.name}: stopped ({how}) at {time.strftime('%H:%M')}; {kept}", flush=True)
    return how
