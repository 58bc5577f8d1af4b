"""Per-query evaluations kept on disk (helpers.study.protocols.eval_cache): read back unchanged, and never
across a change of search, reference count or queries."""

import numpy as np
import pandas as pd

from helpers.core.configs import GREEDY, DataConfig, SearchConfig
from helpers.core.rotations import haar_uniform
from helpers.core.views import ObjectViews
from helpers.data.manifest import load_manifest
from helpers.evaluation.baselines import HogModel
from helpers.study.pipeline import StudyData
from helpers.study.protocols import eval_cache


def _views(name: str, n: int, seed: int, kind: str) -> ObjectViews:
    rng = np.random.default_rng(seed)
    imgs = rng.integers(0, 255, (n, 32, 32, 3), dtype=np.uint8)
    return ObjectViews(name, imgs, haar_uniform(n, seed).astype(np.float32), kind=kind,
                       meta={"key": f"{name}-{kind}-{n}-{seed}"})


def _data(tmp_path) -> StudyData:
    names = ["bunny", "duck"]
    # one set of reference rotations for every object, as the bank requires
    refs = {n: ObjectViews(n, _views(n, 12, 1 + i, "reference").images, haar_uniform(12, 7).astype(np.float32),
                           meta={"key": f"{n}-refs"}) for i, n in enumerate(names)}
    return StudyData(cfg=DataConfig(cache_dir=str(tmp_path / "cache")), manifest=load_manifest(), refs=refs,
                     test_q={n: _views(n, 4, 10 + i, "query") for i, n in enumerate(names)})


def test_an_evaluation_is_read_back_only_for_the_same_search_refs_and_queries(tmp_path, monkeypatch):
    data, hog, folder = _data(tmp_path), HogModel(), tmp_path / "evals"
    calls = []
    real = eval_cache.evaluate
    monkeypatch.setattr(eval_cache, "evaluate", lambda *a, **k: calls.append(a[3]) or real(*a, **k))
    bench, queries = ["bunny", "duck"], {"bunny": data.test_q["bunny"]}

    first = eval_cache.cached_evaluate(hog, data, bench, queries, GREEDY, folder, device="cpu")
    again = eval_cache.cached_evaluate(hog, data, bench, queries, GREEDY, folder, device="cpu")
    assert len(calls) == 1 and "cached" in again and again["seconds_per_query"] == []
    pd.testing.assert_frame_equal(first["per_query"], again["per_query"], check_dtype=False)
    assert again["means"]["rot_acc"] == first["means"]["rot_acc"]

    eval_cache.cached_evaluate(hog, data, bench, queries, SearchConfig(method="fast", k_ac=4), folder, device="cpu")
    eval_cache.cached_evaluate(hog, data, bench, queries, GREEDY, folder, n_refs=6, device="cpu")
    eval_cache.cached_evaluate(hog, data, bench, {"duck": data.test_q["duck"]}, GREEDY, folder, device="cpu")
    assert len(calls) == 4 and len(list(folder.glob("*.csv"))) == 4


def test_greedy_is_keyed_by_its_method_alone(tmp_path):
    """Greedy's answers depend on no other field of the search config (anchors, batching), fast search's do."""
    data, hog = _data(tmp_path), HogModel()
    queries = {"bunny": data.test_q["bunny"]}
    key = eval_cache.eval_key(hog, data, ["bunny", "duck"], queries, 0, SearchConfig("greedy"))
    assert key == eval_cache.eval_key(hog, data, ["bunny", "duck"], queries, 0, GREEDY)
    assert key == eval_cache.eval_key(hog, data, ["bunny", "duck"], queries, 0, SearchConfig("greedy", k_ac=7))
    assert key != eval_cache.eval_key(hog, data, ["bunny", "duck"], queries, 0, SearchConfig("fast", k_ac=4))


def test_a_table_of_older_scoring_code_is_not_read_back(tmp_path, monkeypatch):
    """The key covers the search, evaluate, metric and rotation code: edit any of them and the table is new."""
    data, hog = _data(tmp_path), HogModel()
    queries = {"bunny": data.test_q["bunny"]}
    names = {p.name for p in eval_cache.scoring_sources()}
    assert {"search", "fusion_kernel.cpp", "metrics.py", "rotations.py"} <= names
    src = tmp_path / "scoring.py"
    src.write_text("y = 1\n")
    monkeypatch.setattr(eval_cache, "scoring_sources", lambda: [src])
    before = eval_cache.eval_key(hog, data, ["bunny", "duck"], queries, 0, GREEDY)
    src.write_text("y = 2\n")
    assert eval_cache.eval_key(hog, data, ["bunny", "duck"], queries, 0, GREEDY) != before
