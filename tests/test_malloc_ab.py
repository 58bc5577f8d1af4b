"""benchmarks/malloc_ab.py end to end at toy size: A (glibc defaults) and B (freed memory kept) train alike."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "malloc_ab.py"


def test_malloc_ab_runs_and_compares(tmp_path):
    out = tmp_path / "ab.json"
    r = subprocess.run([sys.executable, str(SCRIPT), "--epochs", "2", "--steps", "1", "--pairs", "1",
                        "--objects", "2", "--refs", "8", "--queries", "4", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    assert math.isfinite(res["ratio_B_over_A"]) and res["ratio_B_over_A"] > 0
    a, b = res["runs"]["A"][0], res["runs"]["B"][0]
    assert a["allocator"]["keep_freed_memory"] is False and a["allocator"]["reason"] == "HELPERS_KEEP_FREED_MEMORY=0"
    assert b["allocator"]["keep_freed_memory"] in (True, False)  # False only where libc is not glibc
    # Where memory lives does not change the arithmetic: identical losses.
    assert res["max_epoch_loss_diff_A_B"] == 0.0
    assert res["setup"]["precision"] in ("fp32", "bf16")


def test_malloc_ab_rejects_too_few_epochs(tmp_path):
    r = subprocess.run([sys.executable, str(SCRIPT), "--epochs", "1", "--out", str(tmp_path / "x.json")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--epochs" in r.stderr
