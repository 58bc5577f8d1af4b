import json

import pytest

from helpers.study.parameters import (
    ParameterError,
    check_mapping,
    check_parameters,
    declared_parameters,
    notebook_path,
    parameters_source,
)
from helpers.study.cli.runner import notebooks, preset_parameters


def test_every_notebook_has_a_literal_parameters_cell():
    names = notebooks()
    assert names[:3] == ["01_render", "02_train", "03_evaluate"] and names[-2:] == ["13_budget", "14_extra_objects"]
    assert len(names) == 14
    for n in names:
        d = declared_parameters(notebook_path(n))
        assert "out_dir" in d and d["out_dir"] == f"reports/smoke/{n}"
        src = parameters_source(notebook_path(n))
        # every parameter line carries a comment
        for line in src.splitlines():
            if "=" in line:
                assert "#" in line, f"{n}: parameter line without a comment: {line}"


def test_papermill_sees_every_declared_parameter():
    """papermill's own parser (``--help-notebook``, its unknown-parameter warning) must read every line."""
    from papermill.inspection import inspect_notebook

    for n in notebooks():
        seen = set(inspect_notebook(notebook_path(n)))
        want = set(declared_parameters(notebook_path(n)))
        assert seen == want, f"{n}: papermill cannot parse {sorted(want - seen)}"


def test_notebooks_are_committed_without_outputs():
    from helpers.study.parameters import NOTEBOOK_DIR

    for p in NOTEBOOK_DIR.glob("*.ipynb"):
        nb = json.loads(p.read_text())
        for c in nb["cells"]:
            if c["cell_type"] == "code":
                assert c.get("outputs") == [] and c.get("execution_count") is None, f"{p.name} has outputs"


def test_unknown_and_mistyped_parameters():
    declared = {"epochs": 2, "lr": 0.1, "name": "x", "flag": True, "levels": [1, 2]}
    assert check_mapping("nb", declared, {"lr": 1})["lr"] == 1.0  # int accepted for float
    with pytest.raises(ParameterError, match=r"nb: unknown parameter\(s\) \['epoch'\]"):
        check_mapping("nb", declared, {"epoch": 3})
    with pytest.raises(ParameterError, match="'epochs' expects int, got str '3'"):
        check_mapping("nb", declared, {"epochs": "3"})
    with pytest.raises(ParameterError, match="'epochs' expects int, got bool"):
        check_mapping("nb", declared, {"epochs": True})
    with pytest.raises(ParameterError, match="'levels' expects list of int"):
        check_mapping("nb", declared, {"levels": [1, "2"]})
    with pytest.raises(ParameterError, match="'flag' expects bool"):
        check_mapping("nb", declared, {"flag": 1})


def test_kernel_namespace_check():
    ns = {"In": [], "Out": {}, "_": None, "get_ipython": print, "epochs": 2, "out_dir": "x"}
    d = declared_parameters(notebook_path("02_train"))
    ns.update({k: v for k, v in d.items()})
    assert check_parameters("02_train", ns)["epochs"] == d["epochs"]
    ns["epoch"] = 5  # a typo papermill would inject silently
    with pytest.raises(ParameterError, match="epoch"):
        check_parameters("02_train", ns)


def test_byo_queries_fit_the_test_queries():
    from helpers.study.parameters import check_values

    P = {**declared_parameters(notebook_path("10_explore")), "n_test_queries": 10}
    check_values("10_explore", {**P, "byo_queries": 10})
    with pytest.raises(ParameterError, match=r"'byo_queries' expects 0 \(all\) or at most n_test_queries=10"):
        check_values("10_explore", {**P, "byo_queries": 11})
    with pytest.raises(ParameterError, match=r"'byo_queries' expects an int >= 0"):
        check_values("10_explore", {**P, "byo_queries": -1})


@pytest.mark.parametrize("notebook,name", [("03_evaluate", "held_out_model"), ("10_explore", "byo_model")])
def test_held_out_and_byo_models_must_be_zoo_models_of_the_crop_size(notebook, name):
    from helpers.study.parameters import check_values

    P = declared_parameters(notebook_path(notebook))
    check_values(notebook, {**P, "image_size": 64, name: "all"})
    with pytest.raises(ParameterError, match=rf"'{name}' expects a zoo model among .*'all'"):
        check_values(notebook, {**P, name: "everything"})
    with pytest.raises(ParameterError, match=rf"'{name}' expects a model taking image_size=128"):
        check_values(notebook, {**P, "image_size": 128, "render_size": 160, name: "all"})


def test_budget_pairs_are_checked():
    """Notebook 13: [shorter, longer] zoo models of one split, the shorter first, one pair per split."""
    from helpers.study.parameters import check_values

    P = declared_parameters(notebook_path("13_budget"))
    check_values("13_budget", {**P, "budgets": [["split1", "split1-12k"], ["split2", "split2-12k"]]})
    check_values("13_budget", {**P, "budgets": []})  # nothing to compare: allowed, the notebook says so
    for bad, match in ((["split1-12k", "split1"], "shorter budget first"), (["split1", "split2-12k"], "same split"),
                       (["split1", "nope"], "zoo model among"), (["split1"], r"\[shorter, longer\]"),
                       (["all", "split1-12k"], "same split"),
                       (["split1-seed1", "split1-12k"], r"also differ in \['train.seed'\]"),
                       (["avg", "split1-12k"], "one recipe at two budgets")):
        with pytest.raises(ParameterError, match=match):
            check_values("13_budget", {**P, "budgets": [bad]})
    with pytest.raises(ParameterError, match="one pair per split"):
        check_values("13_budget", {**P, "budgets": [["split1", "split1-12k"], ["split1", "split1-12k"]]})


def test_all_presets_validate_and_bad_preset_is_refused(tmp_path, monkeypatch):
    for preset in ("smoke", "quick", "long", "paper"):
        for n in notebooks():
            p = preset_parameters(preset, n)
            assert p["out_dir"] == f"reports/{preset}/{n}"
    with pytest.raises(ParameterError, match="preset must be one of"):
        preset_parameters("huge", "02_train")
    import helpers.study.cli.runner as r

    (tmp_path / "quick").mkdir()
    (tmp_path / "quick" / "02_train.yaml").write_text("epochs: ten\n")
    monkeypatch.setattr(r, "PRESET_DIR", tmp_path)
    with pytest.raises(ParameterError, match=r"02_train.yaml.*'epochs' expects int"):
        preset_parameters("quick", "02_train")


@pytest.mark.slow
def test_papermill_run_with_a_wrong_parameter_fails_clearly(tmp_path):
    import papermill as pm

    from helpers.study.parameters import notebook_path

    with pytest.raises(pm.PapermillExecutionError, match="unknown parameter.*n_referencez"):
        pm.execute_notebook(str(notebook_path("01_render")), str(tmp_path / "o.ipynb"),
                            parameters={"n_referencez": 3}, kernel_name="python3", progress_bar=False)
    with pytest.raises(pm.PapermillExecutionError, match="'n_references' expects int, got str"):
        pm.execute_notebook(str(notebook_path("01_render")), str(tmp_path / "o.ipynb"),
                            parameters={"n_references": "many"}, kernel_name="python3", progress_bar=False)
