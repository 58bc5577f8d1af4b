import json

import pytest

from helpers.study.report import build_report
from helpers.study.cli.runner import run


@pytest.mark.slow
def test_runner_executes_a_notebook_and_builds_the_report():
    out = run("smoke", only=["01_render"], html=True, report=True)
    assert (out / "01_render.ipynb").exists() and (out / "01_render.html").exists()
    summary = json.loads((out / "01_render" / "render_summary.json").read_text())
    rep = (out / "REPORT.md").read_text()
    assert f"{len(summary['objects'])} objects" in rep
    assert "## Provenance" in rep and "git commit" in rep
    assert json.loads((out / "timings.json").read_text())["01_render"] > 0


def _claim(diff: float, ci: list[float], verdict: str, compare: str = "b vs a", **extra) -> dict:
    """A paired claim as helpers.evaluation.stats.claim writes it."""
    return {"compare": compare, "diff_pts": diff, "ci": ci, "level": 0.95, "n_queries": 100,
            "point_estimate_agrees": diff > 0, "seeds": [1, 1], "matched_seeds": 1, "per_seed_diff_pts": [diff],
            "seed_spread_pts": None, "verdict": verdict, **extra}


def test_report_marks_missing_sections_and_trends(tmp_path):
    d = tmp_path / "x" / "05_ablation_fusion"
    d.mkdir(parents=True)
    (d / "metrics.json").write_text(json.dumps({
        "table": [{"variant": "avg", "unseen rot_acc": 10.0}, {"variant": "adaptive", "unseen rot_acc": 20.0}],
        "split": 1, "trend": {"adaptive_beats_avg": _claim(10.0, [4.0, 16.0], "holds", "adaptive vs avg")}}))
    rep = build_report("x", root=tmp_path).read_text()
    assert "## 1 · Rendered benchmark" in rep and "_not run_" in rep
    assert "adaptive beats avg: the point estimate agrees (adaptive vs avg: +10.0 pts, 95 % CI [+4.0, +16.0]): " \
           "**holds**" in rep
    assert "| adaptive" in rep and "Not read" not in rep


def test_a_folder_written_by_other_code_is_named_not_read(tmp_path, capsys):
    d = tmp_path / "w" / "08_components"
    d.mkdir(parents=True)
    old = {"holds": True, "compare": "b vs a", "diff_pts": 3.0, "ci": [1.0, 5.0], "verdict": "significant"}
    (d / "metrics.json").write_text(json.dumps({"table": [{"variant": "a", "unseen rot_acc": 1.0}], "split": 1,
                                                "trend": {"both_beats_neither": old}}))
    rep = build_report("w", root=tmp_path).read_text()
    assert "**Not read** (written by another version of the code; rerun these notebooks): `08_components`" in rep
    assert "rerun notebook 08_components" in rep and "rerun notebook 08_components" in capsys.readouterr().err
    assert json.loads((tmp_path / "w" / "claims.json").read_text()) == []


def test_report_states_noise_of_claims(tmp_path):
    d = tmp_path / "y" / "08_components"
    d.mkdir(parents=True)
    c = _claim(3.0, [-1.5, 7.25], "within noise")
    chain = {"point_estimate_agrees": False, "verdict": "within noise",
             "pairs": [c, _claim(-2.0, [-1.5, 7.25], "within noise")]}
    (d / "metrics.json").write_text(json.dumps({"table": [{"variant": "a", "unseen rot_acc": 1.0}], "split": 1,
                                                "trend": {"both_beats_neither": c, "order": chain},
                                                "noise": "paired bootstrap"}))
    rep = build_report("y", root=tmp_path).read_text()
    claims = json.loads((tmp_path / "y" / "claims.json").read_text())
    assert {c["id"] for c in claims} == {"components:both_beats_neither", "components:order:b>a"}
    assert "## Claims (`claims.json`)" in rep and "| `components:both_beats_neither` |" in rep
    assert "both beats neither: the point estimate agrees (b vs a: +3.0 pts, 95 % CI [-1.5, +7.2]): " \
           "**within noise**" in rep
    assert "order: the point estimate disagrees (b vs a +3.0 [-1.5, +7.2]; b vs a -2.0" in rep
    assert "_Noise: paired bootstrap._" in rep


def test_tables_format_numbers_by_magnitude():
    import pandas as pd

    from helpers.study.report_format import md_table as _md

    df = pd.DataFrame([{"refs": 32.0, "rot_acc": 4.1666, "s/query": 0.0213, "split": "#1", "ok": True},
                       {"refs": 512.0, "rot_acc": 8.3, "s/query": 0.61, "split": "mean", "ok": False}])
    lines = _md(df).splitlines()
    assert lines[0].split("|")[1].strip() == "split"  # label column first
    row = [c.strip() for c in lines[2].split("|")[1:-1]]
    assert row == ["#1", "32", "4.2", "0.021", "True"]
    assert "512" in lines[3] and "0.610" in lines[3]


def test_byo_line_reads_the_photos_accuracy():
    from helpers.study.experiments.explore import byo_line

    byo = {"object": "racecar", "model": "all", "n_refs": 512, "error_deg": 176.04, "n_queries": 40,
           "threshold_deg": 30.0, "rot_acc": 25.0, "ci95": [12.5, 40.0], "median_err_deg": 151.26}
    line = byo_line(byo, None)
    assert line.startswith("Bring your own object (all): `racecar` from its mesh file, 512 references: ")
    assert "25.0 % [12.5, 40.0] of its 40 test photos within 30°" in line
    assert "median error 151.3°" in line and line.endswith("error 176.0°.")
    assert "[12.5, 40.0]" in byo_line({k: v for k, v in byo.items() if k != "ci95"}, {"ci95": [12.5, 40.0]})


def test_report_shows_seed_spread_and_a_reexecution(tmp_path):
    d = tmp_path / "z" / "05_ablation_fusion"
    d.mkdir(parents=True)
    c = _claim(3.0, [1.0, 5.0], "within seed spread", "adaptive vs avg", seeds=[2, 2], matched_seeds=2,
               per_seed_diff_pts=[2.0, 4.0], seed_spread_pts=5.9)
    (d / "metrics.json").write_text(json.dumps({"table": [{"variant": "avg", "unseen rot_acc": 1.0}], "split": 1,
                                                "trend": {"adaptive_beats_avg": c},
                                                "seeds": {"avg": {"compare": "avg seed 2 vs seed 1", "diff_pts": -5.6,
                                                                  "ci": [-7.9, -3.2]}}}))
    (d / "run.json").write_text(json.dumps({"git": {"commit": "abc"}}))
    (tmp_path / "z" / "timings.json").write_text(json.dumps({"05_ablation_fusion": 1464.0}))
    (tmp_path / "z" / "reexecuted.json").write_text(json.dumps(
        {"commit": "def", "reason": "matched seeds", "notebooks": {"05_ablation_fusion": 61.0}}))
    rep = build_report("z", root=tmp_path).read_text()
    assert "per seed +2.0/+4.0, seed spread 5.9): **within seed spread**" in rep
    assert "training noise, avg seed 2 vs seed 1: -5.6 pts" in rep
    assert "| `fusion:adaptive_beats_avg` | adaptive beats avg" in rep and "| 5.9 |" in rep
    assert "re-executed after the timed run" in rep and "05_ablation_fusion 61 s" in rep
    assert "| 05_ablation_fusion | 1464 |" in rep  # the timed run's wall time stays in the table


def test_provenance_names_each_commit_with_its_notebooks_after_a_partial_rerun(tmp_path):
    for nb, commit in (("01_render", "aaa"), ("02_train", "aaa"), ("03_evaluate", "bbb")):
        (tmp_path / "z" / nb).mkdir(parents=True)
        run_json = {"git": {"commit": commit, "dirty": nb == "03_evaluate"}}
        (tmp_path / "z" / nb / "run.json").write_text(json.dumps(run_json))
    rep = build_report("z", root=tmp_path).read_text()
    assert ("notebooks ran at git commits `aaa` (01_render, 02_train); `bbb` (uncommitted changes) (03_evaluate)"
            in rep)
    (tmp_path / "z" / "03_evaluate" / "run.json").write_text(json.dumps({"git": {"commit": "aaa"}}))
    assert "notebooks ran at git commit `aaa`; " in build_report("z", root=tmp_path).read_text()


def test_report_shows_the_budget_comparison_with_its_claims(tmp_path):
    """Notebook 13's section: the budget table and the paired longer-minus-shorter lines when it wrote them."""
    import numpy as np
    import pandas as pd

    d = tmp_path / "b" / "13_budget"
    d.mkdir(parents=True)
    q = pd.DataFrame({"split": 1, "obj": "a", "query_id": [f"a:{i}" for i in range(40)], "part": "unseen",
                      "class_ok": True})
    pd.concat([q.assign(rot_ok=np.arange(40) < 10, budget="shorter", steps=4000),
               q.assign(rot_ok=np.arange(40) < 20, budget="longer", steps=12000)]).to_csv(
        d / "per_query_budget.csv", index=False)
    pd.DataFrame([{"split": "#1", "unseen rot_acc, 4000 steps": 25.0, "unseen rot_acc, 12000 steps": 50.0}]).to_csv(
        d / "budget_splits.csv", index=False)
    rep = build_report("b", root=tmp_path).read_text()
    assert "## 13 · Training budget" in rep and "unseen rot_acc, 4000 steps" in rep
    assert "- the longer budget on unseen objects (longer minus shorter): +25.00 points" in rep
    (d / "budget_splits.csv").unlink()
    (d / "per_query_budget.csv").unlink()
    assert "Training budget" not in build_report("b", root=tmp_path).read_text()