import json

import pytest

from helpers.report import build_report
from helpers.runner import run


@pytest.mark.slow
def test_runner_executes_a_notebook_and_builds_the_report():
    out = run("smoke", only=["01_render"], html=True, report=True)
    assert (out / "01_render.ipynb").exists() and (out / "01_render.html").exists()
    summary = json.loads((out / "01_render" / "render_summary.json").read_text())
    rep = (out / "REPORT.md").read_text()
    assert f"{len(summary['objects'])} objects" in rep
    assert "## Provenance" in rep and "git commit" in rep
    assert json.loads((out / "timings.json").read_text())["01_render"] > 0


def test_report_marks_missing_sections_and_trends(tmp_path):
    d = tmp_path / "x" / "05_ablation_fusion"
    d.mkdir(parents=True)
    (d / "metrics.json").write_text(json.dumps({
        "table": [{"variant": "avg", "unseen rot_acc": 10.0}, {"variant": "adaptive", "unseen rot_acc": 20.0}],
        "trend": {"adaptive_is_best": True, "paper_order_avg<sigmoid<softmax<adaptive": False}}))
    rep = build_report("x", root=tmp_path).read_text()
    assert "## 1 · Rendered benchmark" in rep and "_not run_" in rep
    assert "adaptive is best: **holds**" in rep
    assert "**does not hold**" in rep
    assert "| adaptive" in rep
