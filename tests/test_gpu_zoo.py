"""The GPU-lease tooling (scripts/gpu_zoo): what comes back fits the device tool's limits, and a copy of
the tree records the revision it was bundled from."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from helpers.study import provenance

REPO = Path(__file__).resolve().parents[1]


def _run_module():
    spec = importlib.util.spec_from_file_location("gpu_zoo_run", REPO / "scripts" / "gpu_zoo" / "run.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_fit_splits_big_files_and_respects_the_limits(tmp_path, monkeypatch):
    run = _run_module()
    monkeypatch.setattr(run, "FILE_LIMIT", 100)
    monkeypatch.setattr(run, "TOTAL_LIMIT", 400)
    monkeypatch.setattr(run, "MAX_FILES", 5)
    big = tmp_path / "a.ckpt.tgz"
    payload = bytes(range(256)) + bytes(10)
    big.write_bytes(payload)
    budget = {"bytes": 0, "files": 1}
    assert run.fit(big, budget) == 3 and not big.exists()
    parts = sorted(tmp_path.glob("a.ckpt.tgz.part*"))
    assert [p.stat().st_size for p in parts] == [100, 100, 66]
    assert b"".join(p.read_bytes() for p in parts) == payload  # `cat` rejoins it
    assert budget == {"bytes": 266, "files": 4}
    too_many = tmp_path / "b.zoo.tgz"
    too_many.write_bytes(bytes(150))  # 2 parts: 6 files > 5
    assert run.fit(too_many, budget) == 0 and not too_many.exists()
    small = tmp_path / "c.zoo.tgz"
    small.write_bytes(bytes(50))
    assert run.fit(small, budget) == 1 and small.exists() and budget == {"bytes": 316, "files": 5}
    over = tmp_path / "d.zoo.tgz"
    over.write_bytes(bytes(10))  # no file left
    assert run.fit(over, budget) == 0


def test_git_revision_from_the_bundle_overrides_git(monkeypatch):
    monkeypatch.setenv("HELPERS_GIT_REVISION", '{"commit": "abc123", "dirty": false}')
    assert provenance.git_revision() == {"commit": "abc123", "dirty": False, "via": "HELPERS_GIT_REVISION"}
    monkeypatch.setenv("HELPERS_GIT_REVISION", "not json")
    assert provenance.git_revision() == {"commit": None, "dirty": None}
    monkeypatch.delenv("HELPERS_GIT_REVISION")
    rev = provenance.git_revision()
    assert "via" not in rev and (rev["commit"] is None or len(rev["commit"]) == 40)


@pytest.mark.parametrize("name", ["split1-12k", "split2-12k", "split3-12k"])
def test_long_budget_recipes_differ_from_the_4000_step_models_only_in_budget(name):
    from helpers.study import zoo

    r, base = zoo.recipe(name), zoo.recipe(name.removesuffix("-12k"))
    assert r.split == base.split and r.data == base.data and r.val_refs == base.val_refs
    assert r.train.epochs * r.train.steps_per_epoch == 12000
    assert {k: v for k, v in r.train.to_dict().items() if k != "epochs"} == \
        {k: v for k, v in base.train.to_dict().items() if k != "epochs"}


def test_find_takes_the_shortest_budget_unless_told_and_names_the_budgets(tmp_path):
    """Notebooks load the zoo's 4,000-step models (every ablation variant has that budget) unless
    ``zoo_steps`` names a longer one, whatever order zoo.yaml lists them in."""
    import yaml

    from helpers.study import zoo

    base = zoo.entry("split1")
    longer = {**base, "steps": 12000}
    (tmp_path / "zoo.yaml").write_text(yaml.safe_dump({"models": {"split1-12k": longer, "split1": base}}))
    cfg = zoo.recipe("split1").train
    assert zoo.find(1, cfg, tmp_path) == "split1"
    assert zoo.find(1, cfg, tmp_path, steps=12000) == "split1-12k"
    assert zoo.find(1, cfg, tmp_path, steps=4000) == "split1"
    with pytest.raises(ValueError, match=r"zoo_steps=8000.*\[4000, 12000\]"):
        zoo.find(1, cfg, tmp_path, steps=8000)


def test_zoo_steps_must_be_a_published_budget():
    from helpers.study.parameters import ParameterError, check_values

    check_values("03_evaluate", {"models": "zoo", "zoo_steps": 4000})
    check_values("03_evaluate", {"models": "train", "zoo_steps": 999})  # unused without the zoo
    with pytest.raises(ParameterError, match=r"zoo_steps.*4000"):
        check_values("03_evaluate", {"models": "zoo", "zoo_steps": 999})
    with pytest.raises(ParameterError, match="zoo_steps"):
        check_values("03_evaluate", {"models": "zoo", "zoo_steps": -1})
