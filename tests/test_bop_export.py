"""BOP export of the T-LESS-like set and of predictions, read back with helpers.data.bop (round trip)."""

from __future__ import annotations

import numpy as np
import pytest

from helpers.core.configs import TlessConfig
from helpers.data.bop import iter_scene_instances, load_bop_views, load_models_info
from helpers.data.bop_export import export_tless_like, read_results_csv, tless_like_results, write_results_csv
from helpers.data.tless import load_tless
from helpers.evaluation.baselines import HogModel
from helpers.study.protocols.tless import evaluate_tless

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    ts = load_tless(TlessConfig(n_references=8, n_queries=2), cache=cache, progress=False)
    return ts, export_tless_like(ts, tmp_path_factory.mktemp("bop") / "tless_like", cache=cache), cache


def test_the_exported_dataset_reads_back_with_the_same_views_and_labels(exported):
    ts, root, _ = exported
    info = load_models_info(root)
    assert sorted(info) == list(range(1, len(ts.names) + 1))
    insts = list(iter_scene_instances(root, "test"))
    assert len(insts) == 2 * len(ts.names)
    for oid, name in enumerate(ts.names, start=1):
        assert np.isclose(info[oid].diameter, ts.parts[name].diameter * 1000, rtol=1e-6)
        assert len(info[oid].symmetries) == len(ts.parts[name].symmetries)  # same group, discretised alike
        v = load_bop_views(root, "test", oid, size=64, box="visib")
        assert len(v) == 2 and np.allclose(v.rotations, ts.queries[name].rotations, atol=1e-6)
        ours = ts.queries[name].masks
        for i in range(2):  # same object, same place: the BOP crop's visible mask overlaps ours (jitter <= 3 %)
            iou = (v.masks[i] & ours[i]).sum() / max(1, (v.masks[i] | ours[i]).sum())
            assert iou > 0.6, (name, i, iou)
    depth = __import__("cv2").imread(str(root / "test" / "000001" / "depth" / "000000.png"), -1)
    assert depth.dtype == np.uint16
    assert np.allclose(depth * 0.1 / 1000, ts.depth[ts.names[0]][0].astype(np.float64), atol=2e-4)


def test_predictions_round_trip_through_the_results_csv(exported, tmp_path):
    ts, _, cache = exported
    res = evaluate_tless(HogModel(), ts, device="cpu", cache=cache, progress=False)
    rows = tless_like_results(ts, res)
    back = read_results_csv(write_results_csv(rows, tmp_path / "hog_tless-like-test.csv"))
    assert len(back) == len(rows) == 2 * len(ts.names)
    for a, b in zip(rows, back):
        assert (a["scene_id"], a["im_id"], a["obj_id"]) == (b["scene_id"], b["im_id"], b["obj_id"])
        assert np.allclose(a["R"], b["R"], atol=1e-7) and np.allclose(a["t"], b["t"], atol=1e-3)
    with pytest.raises(ValueError, match="expected a BOP results CSV"):
        (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
        read_results_csv(tmp_path / "bad.csv")


def test_a_bop_dataset_on_disk_is_scored_the_same_way(exported):
    """The exported set read as a real BOP dataset (helpers.data.tless.load_bop_tless): its queries, and err_vsd from
    its depth PNGs, at its cameras and poses: 0 for the true rotations, as on the rendered set."""
    from helpers.data.tless import load_bop_tless
    from helpers.evaluation.tless_scoring import vsd_errors

    ts, root, _ = exported
    bop = load_bop_tless(root, split="test", size=64, n_references=8, progress=False)
    assert sorted(bop.names) == [f"obj_{i:06d}" for i in range(1, len(ts.names) + 1)]
    name, part = "obj_000009", ts.names[8]
    assert np.allclose(bop.queries[name].rotations, ts.queries[part].rotations, atol=1e-6)
    R = bop.queries[name].rotations.astype(np.float64)
    assert np.allclose(vsd_errors(bop, name, R), 0.0)
    assert np.allclose(vsd_errors(bop, name, R[::-1].copy()), vsd_errors(ts, part, R[::-1].copy()), atol=0.05)
    res = evaluate_tless(HogModel(), bop, device="cpu", progress=False)
    assert len(res["per_query"]) == 2 * len(ts.names) and res["per_query"]["vsd"].between(0, 1).all()


@pytest.mark.slow
def test_notebook_09_runs_on_a_bop_dataset_on_disk(exported, tmp_path):
    """Notebook 09 with bop_root: a real T-LESS would take the same path (here the exported fixture)."""
    import json

    import papermill as pm

    from helpers.study.parameters import NOTEBOOK_DIR

    _, root, cache = exported
    out = tmp_path / "out"
    pm.execute_notebook(str(NOTEBOOK_DIR / "09_tless.ipynb"), str(tmp_path / "09.ipynb"), cwd=str(NOTEBOOK_DIR),
                        parameters={"bop_root": str(root), "bop_split": "test", "n_references": 8, "n_queries": 2,
                                    "cache_dir": str(cache), "out_dir": str(out)}, progress_bar=False)
    m = json.loads((out / "metrics.json").read_text())
    assert m["set"]["source"].startswith("BOP dataset") and len(m["set"]["parts"]) >= 15
    assert {r["method"] for r in m["table"]} >= {"HOG"} and (out / "per_query_ours.csv").exists()
