"""Training up to a deadline (helpers.study.cli.train_until): the child is stopped at the last epoch boundary
before the deadline, never after its last epoch, and a stopped run can be resumed from its snapshot."""

from __future__ import annotations

import datetime as dt
import json
import os
from pathlib import Path

import pytest

from helpers.study.cli import train_until as tu


class FakeChild:
    """A training process as watch() sees it: it writes one history entry per ``epoch_s`` seconds of the fake
    clock and exits after ``epochs`` epochs (+ ``finish_s`` seconds)."""

    def __init__(self, history: Path, clock: list[float], epochs: int, epoch_s: float, finish_s: float = 2.0):
        self.history, self.clock, self.epochs, self.epoch_s, self.finish_s = history, clock, epochs, epoch_s, finish_s
        self.written, self.terminated, self.start = 0, False, clock[0]

    def step(self) -> None:
        """Write the entries of every epoch that has ended by now (the fake clock)."""
        while self.written < self.epochs and self.clock[0] >= self.start + (self.written + 1) * self.epoch_s:
            self.written += 1
            entries = [{"epoch": e + 1, "seconds": self.epoch_s * 0.9} for e in range(self.written)]
            self.history.write_text(json.dumps({"history": entries}))
            self.clock[0] += 0.001  # a distinct modification time per write on any file system clock
            os.utime(self.history, (self.clock[0], self.clock[0]))

    def poll(self):
        if self.terminated:
            return -15
        done = self.written == self.epochs and self.clock[0] >= self.start + self.epochs * self.epoch_s + self.finish_s
        return 0 if done else None

    def terminate(self):
        self.terminated = True

    def wait(self, timeout=None):
        return -15

    def kill(self):
        self.terminated = True


def _watch(tmp_path: Path, epochs: int, epoch_s: float, deadline_after: float) -> tuple[str, FakeChild]:
    clock = [1000.0]
    child = FakeChild(tmp_path / "history.json", clock, epochs, epoch_s)

    def sleep(s: float) -> None:
        clock[0] += s
        child.step()

    how = tu.watch(child, child.history, clock[0] + deadline_after, epochs, poll_s=1.0,
                   clock=lambda: clock[0], sleep=sleep)
    return how, child


def test_the_child_stops_at_the_last_epoch_boundary_before_the_deadline(tmp_path):
    # 100 s epochs, deadline 350 s away: epochs 1-3 fit, the fourth would end at about 400 s
    how, child = _watch(tmp_path, epochs=10, epoch_s=100.0, deadline_after=350.0)
    assert how == "stopped" and child.terminated and child.written == 3


def test_a_run_that_finishes_before_the_deadline_is_left_to_finish(tmp_path):
    how, child = _watch(tmp_path, epochs=3, epoch_s=100.0, deadline_after=301.0)  # the last epoch ends at 300 s
    assert how == "finished" and not child.terminated and child.written == 3


def test_the_deadline_stops_a_first_epoch_that_cannot_end_in_time(tmp_path):
    how, child = _watch(tmp_path, epochs=10, epoch_s=100.0, deadline_after=50.0)
    assert how == "deadline" and child.terminated and child.written == 0


def test_a_failing_child_is_an_error(tmp_path):
    class Failed(FakeChild):
        def poll(self):
            return 1
    child = Failed(tmp_path / "history.json", [0.0], 1, 1.0)
    with pytest.raises(RuntimeError, match="status 1"):
        tu.watch(child, child.history, 100.0, 1, clock=lambda: 0.0, sleep=lambda s: None)


def test_deadlines_are_read_from_either_option_and_bad_ones_are_named():
    now = dt.datetime(2026, 12, 8, 23, 0)
    assert tu.deadline_from(minutes=30, now=now) == dt.datetime(2026, 12, 8, 23, 30).timestamp()
    assert tu.deadline_from(until="23:45", now=now) == dt.datetime(2026, 12, 8, 23, 45).timestamp()
    assert tu.deadline_from(until="01:10", now=now) == dt.datetime(2026, 12, 9, 1, 10).timestamp()  # tomorrow
    for kw, match in (({}, "exactly one"), ({"until": "1:10", "minutes": 5}, "exactly one"),
                      ({"until": "25:00"}, "--until: expected HH:MM"), ({"minutes": -5}, "--minutes")):
        with pytest.raises(ValueError, match=match):
            tu.deadline_from(now=now, **kw)


def test_a_real_training_child_finishes_and_its_run_is_the_one_loaded(tmp_path, capsys):
    """The child is ``zoo train NAME`` on the same recipe file and cache: with a far deadline it trains the tiny
    recipe to the end, and the run this process then loads is the one it finished."""
    import yaml

    from helpers.study import zoo
    from test_zoo import TINY

    path = tmp_path / "zoo.yaml"
    path.write_text(yaml.safe_dump(TINY))
    r = zoo.recipes(path, cache_dir=str(tmp_path / "cache"), device="cpu")["tiny"]
    assert tu.train_until(r, dt.datetime.now().timestamp() + 1800, path, "cpu") == "finished"
    model, run, info, _ = zoo.train_recipe(r)
    assert (run / "done.json").exists() and len(info["history"]["history"]) == TINY["train"]["epochs"]
