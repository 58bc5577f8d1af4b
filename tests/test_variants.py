"""The shared variant-comparison helper: configs, tables, paired claims."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from helpers.core.configs import ModelConfig, TrainConfig, parse_scales
from helpers.evaluation.paper import COMPONENT_LABELS
from helpers.evaluation.stats import accuracy_ci
from helpers.study.pipeline import _train_key
from helpers.study.protocols.variants import Trained, model_source, variant_config, variant_table, with_seeds


def _base() -> TrainConfig:
    return TrainConfig(epochs=2, steps_per_epoch=3, lr=1e-3, model=ModelConfig(image_size=64))


def test_variant_config_changes_only_the_named_switch():
    base = _base()
    v = variant_config(base, fusion="avg")
    assert v.model.fusion == "avg" and base.model.fusion == "adaptive"  # the base is not modified
    d_base, d_v = _train_key(base), _train_key(v)
    assert {k for k in d_base if d_base[k] != d_v[k]} == {"model"}
    assert {k for k in d_base["model"] if d_base["model"][k] != d_v["model"][k]} == {"fusion"}
    assert variant_config(base, scales="13").model.scales == (13,)
    assert variant_config(base, scales="global").model.is_global
    w = variant_config(base, local_norm=False, weighted_loss=False)
    assert (w.model.local_norm, w.weighted_loss) == (False, False)
    # No change at all: the same training run (same cache key) as the main model.
    assert _train_key(variant_config(base)) == _train_key(base)


def test_parse_scales():
    assert parse_scales("32,16,13") == (32, 16, 13) and parse_scales("global") == "global"
    for bad in ("", "8", "32,x", "globl"):
        with pytest.raises(ValueError, match="scales"):
            parse_scales(bad)


def _pq(correct: np.ndarray, n_obj: int = 4) -> pd.DataFrame:
    n = len(correct)
    return pd.DataFrame({"query_id": [f"q{i}" for i in range(n)], "obj": [f"o{i % n_obj}" for i in range(n)],
                         "rot_ok": correct.astype(bool), "class_ok": np.ones(n, bool),
                         "err_deg": np.where(correct, 5.0, 90.0)})


def test_variant_table_rows():
    means = {"rot_acc": 10.0, "class_acc": 50.0, "median_err_deg": 80.0, "n_queries": 40}
    five_of_50 = _pq(np.arange(50) < 5, n_obj=1)  # one object, the first 5 of its 50 queries right
    res = {"a": {"means": means, "per_query": five_of_50}, "b": {"means": means, "per_query": five_of_50}}
    hist = {"best_epoch": 1, "history": [{"epoch": 1, "global_step": 15}, {"epoch": 2, "global_step": 30}]}
    zoo_entry = {"sha256": "ab" * 32, "steps": 4000, "best_step": 3200}
    trained = {"a": Trained(None, Path("/x/split1-abc"), {"history": hist}),
               "b": Trained(None, Path("/m/avg.pt"), {"zoo": "avg", "zoo_entry": zoo_entry})}
    t = variant_table(trained, res, extra={"a": {"paper": 80.9}, "b": {"paper": 70.0}})
    lo, hi = accuracy_ci(five_of_50)[1]
    assert lo < 10.0 < hi  # the interval of 5 right answers out of 50 queries
    row = {"unseen rot_acc": 10.0, "ci95 lo": lo, "ci95 hi": hi, "unseen class_acc": 50.0,
           "unseen median_err_deg": 80.0, "n_queries": 40}
    assert t.to_dict(orient="records") == [{"variant": "a", **row, "steps": "30", "run": "split1-abc", "paper": 80.9},
                                           {"variant": "b", **row, "steps": "4000", "run": "avg", "paper": 70.0}]
    assert model_source(trained["a"]) == {"source": "train", "model": "split1-abc", "steps": 30, "best_step": 15}
    assert model_source(trained["b"]) == {"source": "zoo", "model": "avg", "sha256": "ab" * 32, "steps": 4000,
                                          "best_step": 3200}
    assert model_source(Trained(None, Path("/x/r"), {}))["steps"] is None


# ---------------------------------------------------------------------------- training seeds


def test_with_seeds_gives_seeded_variants_consecutive_seeds_and_keeps_the_others():
    base = _base()
    configs = {"avg": variant_config(base, fusion="avg"), "adaptive": base, "softmax": variant_config(base, fusion="softmax")}
    runs = with_seeds(configs, ["avg", "adaptive"], n_seeds=3)
    assert [c.seed for c in runs["avg"]] == [0, 1, 2] and [c.seed for c in runs["softmax"]] == [0]
    assert runs["avg"][1].model.fusion == "avg"  # only the seed changes
    # The first seed is the unseeded run itself (same cache key as the main model).
    assert _train_key(runs["adaptive"][0]) == _train_key(base)
    with pytest.raises(ValueError, match=r"seeded_variants: \['attention'\]"):
        with_seeds(configs, ["attention"], 2)


def test_variant_table_with_seeds_shows_each_seed_and_the_range():
    res = {"a": [{"means": {"rot_acc": 10.0, "class_acc": 50.0, "median_err_deg": 80.0, "n_queries": 40},
                  "per_query": _pq(np.arange(50) < 5, n_obj=1)},
                 {"means": {"rot_acc": 14.0, "class_acc": 52.0, "median_err_deg": 70.0, "n_queries": 40},
                  "per_query": _pq(np.arange(50) < 7, n_obj=1)}],
           "b": [{"means": {"rot_acc": 20.0, "class_acc": 60.0, "median_err_deg": 60.0, "n_queries": 40},
                  "per_query": _pq(np.arange(50) < 10, n_obj=1)}]}
    tr = {"a": [Trained(None, Path("/x/split1-s0"), {}), Trained(None, Path("/x/split1-s1"), {})],
          "b": [Trained(None, Path("/x/split1-b"), {})]}
    t = variant_table(tr, res).set_index("variant")
    assert t.loc["a", "unseen rot_acc"] == 12.0 and t.loc["a", "seed range (pts)"] == 4.0
    assert t.loc["a", "rot_acc per seed"] == "10.0, 14.0" and t.loc["a", "run"] == "split1-s0, split1-s1"
    assert t.loc["b", "seeds"] == 1 and pd.isna(t.loc["b", "seed range (pts)"])
    # The interval is that of the seed mean (12 %): both seeds answer the same 50 queries.
    s0, s1 = res["a"][0]["per_query"], res["a"][1]["per_query"]
    seed_mean_pq = s0.assign(rot_ok=(s0["rot_ok"].astype(float) + s1["rot_ok"]) / 2)
    assert [t.loc["a", "ci95 lo"], t.loc["a", "ci95 hi"]] == accuracy_ci(seed_mean_pq)[1]
    assert t.loc["a", "ci95 lo"] < 12.0 < t.loc["a", "ci95 hi"]


def test_seeded_variants_are_checked_before_any_work():
    from helpers.study.parameters import ParameterError, check_parameters

    with pytest.raises(ParameterError, match="seeded_variants"):
        check_parameters("05_ablation_fusion", {"seeded_variants": ["attention"]})
    with pytest.raises(ParameterError, match="seeded_variants"):
        check_parameters("08_components", {"seeded_variants": ["LN on"]})
    with pytest.raises(ParameterError, match="n_seeds"):
        check_parameters("04_ablation_scales", {"n_seeds": 0})
    with pytest.raises(ParameterError, match="test_queries"):
        check_parameters("07_fast_vs_greedy", {"test_queries": 99})  # smoke renders 4 per object
    assert COMPONENT_LABELS == ("LN off, wInfoNCE off", "LN off, wInfoNCE on", "LN on, wInfoNCE off",
                                "LN on, wInfoNCE on")


def test_ablation_bars_draw_each_variants_interval(monkeypatch, tmp_path):
    """The ablation charts carry the table's 95 % intervals as error bars (lower, upper around the value)."""
    from matplotlib.container import ErrorbarContainer

    from helpers.study import figures

    drawn = {}
    monkeypatch.setattr(figures, "save", lambda fig, path: drawn.setdefault("fig", fig) and Path(path))
    df = pd.DataFrame({"variant": ["a", "b"], "unseen rot_acc": [50.0, 60.0], "ci95 lo": [45.0, 52.0],
                       "ci95 hi": [56.0, 67.0], "paper": [80.0, None]})
    figures.bars(df, "variant", "unseen rot_acc", tmp_path / "x.png", "t", paper_col="paper",
                 ci_cols=("ci95 lo", "ci95 hi"))
    ax = drawn["fig"].axes[0]
    (bars_err,) = [c for c in ax.containers if isinstance(c, ErrorbarContainer)]
    segs = bars_err.lines[2][0].get_segments()
    assert [(s[0][1], s[1][1]) for s in segs] == [(45.0, 56.0), (52.0, 67.0)]
