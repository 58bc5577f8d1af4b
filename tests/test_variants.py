"""The shared variant-comparison helper: configs, tables, paired claims."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from helpers.model import ModelConfig
from helpers.study import _train_key
from helpers.train import TrainConfig
from helpers.variants import (Trained, chain, claim, claims_table, parse_scales, variant_config, variant_table)


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


def test_claims_detect_a_real_gap_and_tables_show_it():
    rng = np.random.default_rng(0)
    worse = rng.random(400) < 0.2
    better = worse | (rng.random(400) < 0.4)
    pq = {"a": _pq(worse), "b": _pq(better), "same": _pq(worse.copy())}
    c = claim(pq, "a", "b")
    assert c["holds"] and c["verdict"] == "significant" and c["ci"][0] > 0
    assert claim(pq, "a", "same")["verdict"] == "within noise"
    assert claim(pq, "a", "missing") is None
    ch = chain(pq, ["a", "b"])
    assert ch["holds"] and len(ch["pairs"]) == 1
    t = claims_table({"gap": c, "note": "text is skipped"})
    assert list(t["claim"]) == ["gap"] and t["verdict"][0] == "significant"


def test_variant_table_rows():
    res = {"a": {"means": {"rot_acc": 10.0, "class_acc": 50.0, "median_err_deg": 80.0, "n_queries": 40}}}
    t = variant_table({"a": Trained(None, Path("/x/split1-abc"), {})}, res, extra={"a": {"paper": 80.9}})
    assert t.to_dict(orient="records") == [{"variant": "a", "unseen rot_acc": 10.0, "unseen class_acc": 50.0,
                                            "unseen median_err_deg": 80.0, "n_queries": 40, "run": "split1-abc",
                                            "paper": 80.9}]
