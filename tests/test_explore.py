"""The explorer's steps (helpers.study.explorer.query) and panels (helpers.study.explorer.panels) on a tiny untrained network."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from helpers.core.configs import ModelConfig
from helpers.core.rotations import haar_uniform
from helpers.core.views import ObjectViews
from helpers.net.model import OrientationNet
from helpers.search.bank import ReferenceBank
from helpers.study.explorer.query import Explorer, figure_png, inspect_query, query_figure
from helpers.study.explorer.panels import byo_panel, query_panel
from helpers.study.parameters import ParameterError, check_values, declared_parameters, notebook_path
from helpers.study.pipeline import encode_queries


@pytest.fixture(scope="module")
def explorer():
    """Two objects x 6 references at shared rotations; object a's 3 queries sit exactly at references 0-2."""
    torch.manual_seed(0)
    model = OrientationNet(ModelConfig(image_size=64)).eval()
    rng = np.random.default_rng(0)
    R = haar_uniform(6, seed=0).astype(np.float32)
    refs = {n: ObjectViews(n, rng.integers(0, 255, (6, 64, 64, 3), dtype=np.uint8), R) for n in ("a", "b")}
    queries = {"a": ObjectViews("a", refs["a"].images[:3].copy(), R[:3].copy(), kind="query")}
    feats = [encode_queries(model, refs[n], "cpu").numpy().astype(np.float16) for n in ("a", "b")]
    bank = ReferenceBank(feats, R, ["a", "b"], k_ac=1)
    data = SimpleNamespace(refs=refs, test_q=queries)
    return Explorer(model, "tiny", data, bank, {"a": encode_queries(model, queries["a"], "cpu")}, torch.device("cpu"))


def test_inspect_query_lists_the_best_references_with_errors_and_verdicts(explorer):
    v = inspect_query(explorer, "a", 1, top_k=4)
    scores = [t["score"] for t in v.top]
    assert len(v.top) == 4 and scores == sorted(scores, reverse=True)
    S = explorer.scores("a", 1)
    assert S.shape == (2, 6) and np.isclose(S.max(), scores[0])
    for t in v.top:  # the error is the distance of the reference's rotation to the true one
        assert np.isclose(t["err_deg"], v.dist_deg[t["ref"]], atol=1e-6)
        assert t["ok"] == (t["obj"] == "a" and t["err_deg"] < 30)
    assert v.dist_deg.shape == (6,) and v.dist_deg[1] < 1e-3  # query 1 of a is reference 1's rotation
    assert np.allclose(v.true_scores, S[0])
    assert set(v.maps) == {32, 16, 13} and all(np.isclose(m.sum(), 1, atol=1e-4) for m in v.maps.values())
    rec = v.record()
    assert rec["query"] == "a:1" and rec["nearest_ref_deg"] < 1e-3
    assert v.summary().startswith("query a #1: top-1 ")


def test_inspect_query_refuses_a_query_that_does_not_exist(explorer):
    with pytest.raises(IndexError, match="query 3 of 'a': it has 3 test queries"):
        inspect_query(explorer, "a", 3)


def test_query_figure_and_png(explorer, tmp_path):
    v = inspect_query(explorer, "a", 0, top_k=3)
    path = query_figure(explorer, v, tmp_path / "q.png")
    assert path.stat().st_size > 5000
    assert figure_png(explorer, v)[:8] == b"\x89PNG\r\n\x1a\n"


def test_query_panel_follows_its_slider(explorer):
    panel = query_panel(lambda name: explorer, ["tiny"], ["a"], explorer, "a", 0, top_k=3)
    (_, _, slider), summary, image = panel.children[0].children, panel.children[1], panel.children[2]
    before = (summary.value, bytes(image.value))
    assert "query a #0" in before[0] and slider.max == 2
    slider.value = 2
    assert "query a #2" in summary.value and bytes(image.value) != before[1]


def test_byo_panel_asks_for_both_files_before_running(explorer):
    panel = byo_panel(explorer.model, 4)
    button, answer = panel.children[0].children[3], panel.children[1]
    button.click()
    assert "upload a mesh file and a crop image first" in answer.value


def test_byo_panel_keeps_no_upload_files_after_answering(explorer, tmp_path, monkeypatch):
    import datetime
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # where the panel's temporary files go
    panel = byo_panel(explorer.model, 4)
    mesh_up, crop_up, _, button = panel.children[0].children
    answer = panel.children[1]
    upload = {"size": 4, "type": "", "last_modified": datetime.datetime(2026, 1, 1, tzinfo=datetime.timezone.utc)}
    mesh_up.value = ({**upload, "name": "broken.obj", "content": memoryview(b"junk")},)
    crop_up.value = ({**upload, "name": "crop.png", "content": memoryview(b"junk")},)
    button.click()
    assert "crop.png is not a readable image" in answer.value  # the file's own error, shown in the panel
    assert list(tmp_path.iterdir()) == []


def _explore_parameters(**over):
    P = declared_parameters(notebook_path("10_explore"))
    P.update(over)
    return P


@pytest.mark.parametrize("over, match", [
    ({"model": "no-such-model"}, r"'model' expects a zoo model among \["),
    ({"model": "missing/best.pt"}, r"'model' expects a zoo model name or an existing checkpoint"),
    ({"model": "split1", "image_size": 128, "render_size": 160}, r"'model' expects a model taking image_size=128"),
    ({"object_name": "teapot"}, r"'object_name' expects '' or a benchmark object among"),
    ({"query": 4}, r"'query' expects an index below n_test_queries=4"),
    ({"top_k": 0}, r"'top_k' expects an int >= 1"),
])
def test_explorer_parameters_are_checked_before_any_work(over, match):
    with pytest.raises(ParameterError, match=match):
        check_values("10_explore", _explore_parameters(**over))
    check_values("10_explore", _explore_parameters())  # the defaults pass
