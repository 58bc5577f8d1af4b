"""The experiment registry (helpers.study.experiments) against the notebooks."""

import re
from pathlib import Path

import pytest

from helpers.core.paths import REPO_ROOT
from helpers.study.experiments import REGISTRY, experiment
from helpers.study.parameter_rules import ParameterError
from helpers.study.parameters import check_values
from helpers.study.cli.runner import notebooks

EVALUATION = REPO_ROOT / "src" / "helpers" / "evaluation"


def test_every_notebook_has_one_experiment_and_every_experiment_a_notebook():
    names = [e.notebook for e in REGISTRY]
    assert len(set(names)) == len(names)
    assert names == sorted(names)  # notebook order: the report's sections follow it
    assert set(names) == set(notebooks()), "a notebook without an experiment module, or a module without notebook"
    for e in REGISTRY:
        assert e.question and (e.claims or e.section or e.check), e.notebook
        assert experiment(e.notebook) is e
    assert experiment("99_nothing") is None


def test_no_notebook_name_in_the_evaluation_layer():
    pattern = re.compile("|".join(re.escape(e.notebook) for e in REGISTRY))
    hits = [f"{p.relative_to(REPO_ROOT)}:{i}" for p in sorted(EVALUATION.rglob("*.py"))
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not hits, hits


def test_an_experiment_checks_its_own_parameters():
    with pytest.raises(ParameterError, match="notebook 05_ablation_fusion: parameter 'variants' expects fusions"):
        check_values("05_ablation_fusion", {"variants": ["avg", "mean"]})
    with pytest.raises(ParameterError, match="notebook 04_ablation_scales: parameter 'variants' expects scale sets"):
        check_values("04_ablation_scales", {"variants": ["32", "8"]})
    check_values("04_ablation_scales", {"variants": ["32", "global"]})  # valid: no error
    # A notebook without its own checks takes the shared ones only.
    check_values(Path("01_render").name, {"n_references": 4})


@pytest.mark.parametrize("preset", ["quick", "screens"])
def test_the_committed_report_is_rebuilt_identically(tmp_path, preset):
    """The claims and the report are a function of the committed result files: rebuilding them from
    reports/<preset> gives the committed claims.json and REPORT.md (but the line naming the assembling commit)."""
    import shutil

    from helpers.study.cli.runner import preset_notebooks
    from helpers.study.report import build_report

    src = REPO_ROOT / "reports" / preset
    if not (src / "claims.json").exists():
        pytest.skip(f"no committed {preset} report")
    shutil.copytree(src, tmp_path / preset, ignore=shutil.ignore_patterns("*.ipynb", "*.html", "*.png"))
    build_report(preset, root=tmp_path, notebooks=preset_notebooks(preset))
    assert (tmp_path / preset / "claims.json").read_text() == (src / "claims.json").read_text()

    def body(p: Path) -> list[str]:
        return [ln for ln in p.read_text().splitlines() if not ln.startswith("- notebooks ran at")]

    assert body(tmp_path / preset / "REPORT.md") == body(src / "REPORT.md")


def _screens(**over):
    P = {"image_size": 64, "split": 1, "screen_queries": 8, "baseline": ["split1", "split1-seed1"],
         "arms": [["avg-fusion", "avg", "avg-seed1"]]}
    return {**P, **over}


@pytest.mark.parametrize("over, message", [
    ({"baseline": []}, "'baseline' expects a non-empty list"),
    ({"arms": [["only-a-label"]]}, "'arms' expects a list of \\[label, zoo model"),
    ({"arms": [["current", "avg"]]}, "distinct labels other than 'current'"),
    ({"arms": [["a", "avg"], ["a", "sigmoid"]]}, "distinct labels"),
    ({"arms": [["x", "split2"]]}, "zoo models trained on split 1 \\(split2 is split 2\\)"),
    ({"arms": [["x", "no-such-model"]]}, "a zoo model among"),
    ({"image_size": 128}, "image_size=128"),
    ({"arms": [["x", "models/avg.pt"]]}, "zoo model names \\(their recipes are compared\\)"),
])
def test_the_screens_check_their_models(over, message):
    with pytest.raises(ParameterError, match=message):
        check_values("12_training_screens", _screens(**over))
    check_values("12_training_screens", _screens())


def test_the_readme_headline_is_the_committed_claims():
    """README.md's headline block is generated from reports/quick and reports/screens claims.json: no number in it
    can go stale, and the screens' verdicts are in it."""
    from helpers.study.cli.readme import README, block, current_block, load_claims

    claims = load_claims()
    assert current_block(README.read_text()) == block(claims), \
        "README headline differs from the reports' claims.json: run `.venv/bin/python -m helpers.study.cli.readme`"
    lines = block(claims).splitlines()
    assert len(lines) > 10 and all(ln.startswith("- ") for ln in lines[1:-1])
    assert any("12_training_screens" in ln for ln in lines) and any("14_extra_objects" in ln for ln in lines)


def test_readme_stays_short():
    assert len((REPO_ROOT / "README.md").read_text().splitlines()) <= 150


def test_notebook_14_checks_its_validation_extras():
    P = {"image_size": 64, "split": 1, "baseline": ["split1", "split1-seed1"], "arms": [], "extra_val_objects": 25,
         "extra_val_references": 8, "extra_val_queries": 2}
    with pytest.raises(ParameterError, match="'extra_val_objects' expects an int in 1..24"):
        check_values("14_extra_objects", P)
    with pytest.raises(ParameterError, match="'extra_val_queries' expects an int >= 1"):
        check_values("14_extra_objects", {**P, "extra_val_objects": 24, "extra_val_queries": 0})
    check_values("14_extra_objects", {**P, "extra_val_objects": 24})  # valid: no error

