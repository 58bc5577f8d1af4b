"""benchmarks/ddp_cpu_ab.py end to end at toy size: A (1 process) and B (2 gloo processes) train alike."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "ddp_cpu_ab.py"


def test_ddp_cpu_ab_runs_and_compares(tmp_path):
    out = tmp_path / "ab.json"
    r = subprocess.run([sys.executable, str(SCRIPT), "--epochs", "2", "--steps", "1", "--pairs", "1",
                        "--objects", "2", "--refs", "8", "--queries", "4", "--no-single-thread", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    assert set(res["images_per_s_median"]) == {"A", "B"}
    assert math.isfinite(res["ratio_B_over_A"]) and res["ratio_B_over_A"] > 0
    a, b = res["runs"]["A"][0], res["runs"]["B"][0]
    assert a["global_step"] == b["global_step"] == 2
    assert (a["processes"], a["threads_per_process"], b["processes"], b["threads_per_process"]) == (1, 2, 2, 1)
    # Same global batch and data: the two trainings differ only by the order of float sums. Adam can turn that
    # noise into up to lr (1e-3) per step in a weight whose gradient is near zero, and how much noise there is
    # depends on the CPU's kernels (see tests/test_ddp.py), so the median bound is 5 % of one step: trainings
    # that did not synchronise would differ by about a step in most weights.
    assert res["loss_per_epoch_max_abs_diff_A_vs_B"] < 1e-4
    assert res["weights_median_abs_diff_A_vs_B"] < 5e-5, res["weights_median_abs_diff_A_vs_B"]


def test_ddp_cpu_ab_rejects_too_few_epochs(tmp_path):
    r = subprocess.run([sys.executable, str(SCRIPT), "--epochs", "1", "--out", str(tmp_path / "x.json")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--epochs" in r.stderr
