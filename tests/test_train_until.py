"""Training up to a deadline (helpers.study.cli.train_until): the child is stopped at the last epoch boundary
before the deadline, never after its last epoch (a real child trains in tests/test_zoo.py)."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import pytest

from helpers.study.cli import train_until as tu


class FakeChild:
    """A training process as watch() sees it: epoch ``e`` lasts ``epoch_s[e]`` seconds of the fake clock (one number:
    all alike) and is recorded in ``history`` as it ends; the process exits ``finish_s`` seconds after the last."""

    def __init__(self, history: Path, clock: list[float], epochs: int, epoch_s, finish_s: float = 2.0):
        lengths = list(epoch_s) if isinstance(epoch_s, (list, tuple)) else [epoch_s] * epochs
        self.ends = [clock[0] + sum(lengths[:e + 1]) for e in range(epochs)]
        self.history, self.clock, self.epochs, self.finish_s = history, clock, epochs, finish_s
        self.written, self.terminated = 0, False

    def step(self) -> None:
        """Record every epoch that has ended by now (the fake clock)."""
        n = sum(1 for t in self.ends if t <= self.clock[0])
        if n > self.written:
            self.written = n
            self.history.write_text(json.dumps({"history": [{"epoch": e + 1, "seconds": 90.0} for e in range(n)]}))

    def poll(self):
        if self.terminated:
            return -2
        return 0 if self.clock[0] >= self.ends[-1] + self.finish_s else None

    def send_signal(self, sig):
        self.terminated = True

    def terminate(self):
        self.terminated = True

    def wait(self, timeout=None):
        return -2

    def kill(self):
        self.terminated = True


def _watch(tmp_path: Path, epochs: int, epoch_s, deadline_after: float) -> tuple[str, FakeChild]:
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


def test_the_longest_epoch_seen_decides(tmp_path):
    """Epochs that validate take longer: the estimate is the longest interval between two boundaries."""
    # boundaries at 100, 260, 360: after 360 the longest epoch (160 s) would end at 520, after the deadline (500)
    how, child = _watch(tmp_path, epochs=10, epoch_s=[100.0, 160.0, 100.0, 100.0, 100.0, 100.0, 100.0, 100.0,
                                                      100.0, 100.0], deadline_after=500.0)
    assert how == "stopped" and child.written == 3


def test_the_deadline_stops_a_first_epoch_that_cannot_end_in_time(tmp_path):
    how, child = _watch(tmp_path, epochs=10, epoch_s=100.0, deadline_after=50.0)
    assert how == "deadline" and child.terminated and child.written == 0


def test_a_run_past_its_last_epoch_is_never_stopped(tmp_path):
    """Its history already holds every epoch (it is writing done.json): even past the deadline it finishes."""
    clock = [1000.0]
    child = FakeChild(tmp_path / "history.json", clock, 2, [-20.0, 10.0])  # both epochs ended before the watch
    child.step()

    def sleep(s: float) -> None:
        clock[0] += s

    assert tu.watch(child, child.history, 999.0, 2, poll_s=1.0, clock=lambda: clock[0], sleep=sleep) == "finished"
    assert not child.terminated


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

