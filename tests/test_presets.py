"""A preset's files agree with each other: parameters once (presets/<preset>/common.yaml), and the
notebooks that share a benchmark or a model get the same data and training parameters."""

from pathlib import Path

import pytest
import yaml

from helpers.study.cli import runner
from helpers.study.parameters import _DATA, _MODEL, _TRAIN, ParameterError

PRESETS = runner.PRESETS  # "smoke" is the notebooks' own defaults (no folder)
#: Notebooks that render or load the LineMOD-like benchmark: one set of data parameters.
BENCHMARK = ("01_render", "02_train", "03_evaluate", "04_ablation_scales", "05_ablation_fusion",
             "06_reference_count", "07_fast_vs_greedy", "08_components")
#: Notebooks that train (or load) the split's main model: one run, so one set of training parameters.
#: Notebook 03 may give its models a longer budget (``epochs``; the zoo's 12,000-step models), nothing else.
MAIN_MODEL = ("02_train", "03_evaluate", "06_reference_count", "07_fast_vs_greedy")
#: Ablation notebooks: every variant at one budget (which may be smaller than the main model's).
ABLATIONS = ("04_ablation_scales", "05_ablation_fusion", "08_components")
TRAINING = _MODEL + _TRAIN + ("val_refs",)


def _params(preset: str) -> dict[str, dict]:
    return {nb: runner.preset_parameters(preset, nb) for nb in runner.preset_notebooks(preset)}


def _disagreements(P: dict[str, dict], notebooks: tuple[str, ...], keys: tuple[str, ...]) -> dict:
    out = {}
    for k in keys:
        vals = {nb: P[nb][k] for nb in notebooks if k in P.get(nb, {})}
        if len(set(map(repr, vals.values()))) > 1:
            out[k] = vals
    return out


@pytest.mark.parametrize("preset", PRESETS)
def test_notebooks_sharing_data_or_a_model_agree(preset):
    P = _params(preset)
    assert not _disagreements(P, BENCHMARK, _DATA), f"{preset}: data parameters differ between notebooks"
    assert not _disagreements(P, MAIN_MODEL, tuple(k for k in TRAINING if k != "epochs")), \
        f"{preset}: the main model's training parameters differ"
    assert not _disagreements(P, tuple(nb for nb in MAIN_MODEL if nb != "03_evaluate"), ("epochs",)), \
        f"{preset}: 02, 06 and 07 train the main model for different budgets"
    assert not _disagreements(P, ABLATIONS, TRAINING), f"{preset}: the ablations' training parameters differ"
    # Notebook 13 compares zoo models (64 px) on notebook 03's queries wherever 03 runs at that crop size; where it
    # does not (paper: 128 px), 13 evaluates on the quick-size benchmark, as the explorer does.
    if "13_budget" in P and P["03_evaluate"]["image_size"] == P["13_budget"]["image_size"]:
        assert not _disagreements(P, ("03_evaluate", "13_budget"), _DATA + ("k_ac", "fps_k", "eval_method")), \
            f"{preset}: notebook 13 answers other queries, references or search than notebook 03"


@pytest.mark.parametrize("preset", [p for p in PRESETS if (runner.PRESET_DIR / p).is_dir()])
def test_parameters_once(preset):
    """A notebook's file never repeats a value common.yaml already gives it."""
    d = runner.PRESET_DIR / preset
    common = yaml.safe_load((d / runner.COMMON).read_text())
    for f in sorted(d.glob("[0-9][0-9]_*.yaml")):
        own = yaml.safe_load(f.read_text()) or {}
        repeated = sorted(k for k, v in own.items() if k in common and common[k] == v)
        assert not repeated, f"{f}: {repeated} repeat presets/{preset}/common.yaml"


def test_common_file_is_merged_and_checked(tmp_path, monkeypatch):
    d = tmp_path / "quick"
    d.mkdir()
    (d / runner.COMMON).write_text("epochs: 3\nimage_size: 64\n")
    (d / "02_train.yaml").write_text("epochs: 5\n")
    monkeypatch.setattr(runner, "PRESET_DIR", Path(tmp_path))
    assert runner.preset_parameters("quick", "02_train")["epochs"] == 5  # the notebook's own file wins
    assert runner.preset_parameters("quick", "03_evaluate")["epochs"] == 3  # common applies to every notebook
    assert "epochs" not in runner.preset_parameters("quick", "01_render")  # ... that declares the name
    (d / runner.COMMON).write_text("epoch: 3\n")
    with pytest.raises(ParameterError, match=r"common.yaml: parameter\(s\) \['epoch'\] are declared by no notebook"):
        runner.preset_parameters("quick", "02_train")
    (d / runner.COMMON).write_text("epochs: three\n")
    with pytest.raises(ParameterError, match=r"common.yaml.*'epochs' expects int"):
        runner.preset_parameters("quick", "03_evaluate")


def test_the_real_data_preset_runs_the_notebooks_of_real_data_only(tmp_path, monkeypatch):
    """real-lm lists its notebooks (01-08); every one reads bop_root and trains here (the zoo's models know
    the rendered benchmark only); a bad list is an error naming the file."""
    names = runner.preset_notebooks("real-lm")
    assert names == list(BENCHMARK) and runner.preset_notebooks("long") == runner.notebooks()
    for nb in names:
        P = runner.preset_parameters("real-lm", nb)
        assert P["bop_root"] == "data/bop" and P.get("models", "train") == "train" and not P.get("held_out_model")
    monkeypatch.setattr(runner, "PRESET_DIR", tmp_path)
    (tmp_path / "real-lm").mkdir()
    (tmp_path / "real-lm" / runner.NOTEBOOK_LIST).write_text("- 01_render\n- 99_nothing\n")
    with pytest.raises(ParameterError, match="notebooks.yaml: expected a non-empty list of notebook names"):
        runner.preset_notebooks("real-lm")


def test_the_screens_are_their_own_job_on_the_quick_benchmark():
    """quick runs the study and screens the training-regime screens (12, 14): every notebook once between them,
    and the screens' shared parameters are quick's, so they score on the same rendered views and references."""
    quick, screens = runner.preset_notebooks("quick"), runner.preset_notebooks("screens")
    assert screens == ["12_training_screens", "14_extra_objects"]
    assert sorted(quick + screens) == runner.notebooks()

    def common(p: str) -> dict:
        return yaml.safe_load((runner.PRESET_DIR / p / runner.COMMON).read_text())

    assert common("screens") == common("quick")
