"""The real-data path (``bop_root``): a LineMOD / LineMOD-O pair in BOP format, written from the rendered benchmark
by :func:`helpers.data.bop_export.export_linemod_like`, read back as the study's data: crops by the paper's rule,
the paper's splits, the seen objects' train / validation / test views kept apart, the declared symmetries."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from helpers.core.configs import DataConfig
from helpers.data.bop import BOPFormatError, crop_instance, iter_scene_instances
from helpers.data.bop_export import export_linemod_like
from helpers.data.linemod_real import bop_folders, real_views, spread

#: Benchmark objects standing for LineMOD ids: ape (split 1), cat and duck (2), glue and holepuncher (3); all
#: five are annotated in LineMOD-O too.
STAND_INS = {"duck": 1, "ant": 6, "bread": 9, "husky": 11, "panda_hand": 12}


@pytest.fixture(scope="module")
def bop_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("bop") / "datasets"
    return export_linemod_like(root, STAND_INS, n_views=20, n_occluded=4)


def test_the_exported_pair_has_linemods_layout_ids_and_depth(bop_root):
    folders = bop_folders(bop_root)
    info = json.loads((folders["lm"] / "models" / "models_info.json").read_text())
    assert sorted(map(int, info)) == sorted(STAND_INS.values())
    assert sorted(p.name for p in (folders["lm"] / "test").iterdir()) == [f"{i:06d}" for i in sorted(STAND_INS.values())]
    scene = folders["lm"] / "test" / "000001"
    assert len(list((scene / "rgb").glob("*.png"))) == 20 and len(list((scene / "depth").glob("*.png"))) == 20
    cam = json.loads((scene / "scene_camera.json").read_text())["0"]
    assert len(cam["cam_K"]) == 9 and cam["depth_scale"] > 0
    assert [p.name for p in (folders["lmo"] / "test").iterdir()] == ["000002"]  # LineMOD-O: one scene
    assert len(list((folders["lmo"] / "test" / "000002" / "rgb").glob("*.png"))) == 4 * len(STAND_INS)


def test_crops_follow_the_papers_rule_box_made_square_without_margin(bop_root):
    lm = bop_folders(bop_root)["lm"]
    inst = next(iter_scene_instances(lm, "test", [1]))
    x, y, w, h = inst.bbox_obj
    crop, mask = crop_instance(inst, 64, 1.0, "obj")
    # The object's box, made square on its longer side, fills the crop: its mask touches two opposite borders.
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if w >= h:
        assert cols[0] <= 1 and cols[-1] >= 62
    else:
        assert rows[0] <= 1 and rows[-1] >= 62
    views = real_views(lm, "lm", "ape", 64, 1.0, cache=bop_root / "cache", progress=False)
    assert np.array_equal(views.images[0], crop) and views.meta["box"] == "obj"
    occ = real_views(bop_folders(bop_root)["lmo"], "lmo", "ape", 64, 1.0, cache=bop_root / "cache", progress=False)
    assert occ.meta["box"] == "visib" and len(occ) == 4  # LineMOD-O: the visible box


def test_real_data_keeps_train_val_and_the_ten_percent_seen_test_views_apart(bop_root):
    from helpers.study.pipeline import prepare_data

    cfg = DataConfig(n_references=8, n_train_queries=100, n_val_queries=3, n_test_queries=100, workers=0,
                     cache_dir=str(bop_root / "cache"))
    data = prepare_data(cfg, bop_root=str(bop_root))
    m = data.manifest
    assert m.split_objects(1) == ["ape"] and m.split_objects(2) == ["cat", "duck"] and m.held_out_objects() == []
    for n in m.object_names():
        inst = {k: set(getattr(data, k)[n].meta["instances"]) for k in ("train_q", "val_q", "seen_test_q")}
        assert len(inst["val_q"]) == 3 and len(inst["seen_test_q"]) == 2  # every tenth of 20 views
        assert not (inst["train_q"] & inst["val_q"]) and not (inst["train_q"] & inst["seen_test_q"])
        assert not (inst["val_q"] & inst["seen_test_q"])
        assert len(data.test_q[n]) == 20 and data.seen_test(n) is data.seen_test_q[n]  # unseen: every view
        assert data.train_q[n].images.shape[1] == round(cfg.image_size * cfg.train_context)  # with context
        assert len(data.occluded_q[n]) == 4 and len(data.refs[n]) == 8
    assert len({data.key(n, "train_q") for n in m.object_names()}) == 5  # keyed by object and selection
    from helpers.data.linemod_bop import LM_OBJECTS
    from helpers.data.manifest import load_manifest

    bench = load_manifest()
    for name, oid in STAND_INS.items():  # each stand-in's declared symmetries reach references and queries
        want = np.asarray(getattr(bench.object(name).symmetry_group(), "discrete", bench.object(name).symmetry_group()))
        for got in (data.refs[LM_OBJECTS[oid]].symmetries, data.test_q[LM_OBJECTS[oid]].symmetries):
            got = np.asarray(getattr(got, "discrete", got))
            assert got.shape == want.shape and np.allclose(got, want, atol=1e-6), name


def test_wrong_folders_and_missing_entries_are_named(bop_root, tmp_path):
    with pytest.raises(BOPFormatError, match="not a folder"):
        bop_folders(tmp_path / "nowhere")
    part = tmp_path / "only_lm"
    shutil.copytree(bop_root / "lm", part / "lm")
    assert set(bop_folders(part)) == {"lm"}  # LineMOD-O is optional: the occluded part is then left out
    (part / "lmo").mkdir()
    with pytest.raises(BOPFormatError, match=r"lmo/models: folder does not exist"):
        bop_folders(part)
    (part / "lmo").rmdir()
    with pytest.raises(BOPFormatError, match=r"lm/test: folder does not exist"):
        shutil.rmtree(part / "lm" / "test")
        bop_folders(part)
    with pytest.raises(ValueError, match="not one of the paper's LineMOD objects"):
        real_views(bop_root / "lm", "lm", "bowl", 64)
    with pytest.raises(BOPFormatError, match="object 2 \\(benchvise\\) is not listed"):
        real_views(bop_root / "lm", "lm", "benchvise", 64)


def test_notebook_parameters_refuse_real_data_with_the_zoo_or_a_bad_folder(bop_root, tmp_path):
    from helpers.study.parameter_rules import ParameterError
    from helpers.study.parameters import check_values, declared_parameters, notebook_path

    P = declared_parameters(notebook_path("03_evaluate"))
    check_values("03_evaluate", {**P, "bop_root": str(bop_root)})
    with pytest.raises(ParameterError, match="parameter 'bop_root'.*not a folder"):
        check_values("03_evaluate", {**P, "bop_root": str(tmp_path / "nowhere")})
    with pytest.raises(ParameterError, match="'models'.*'train' with bop_root"):
        check_values("03_evaluate", {**P, "bop_root": str(bop_root), "models": "zoo"})


def test_spread_picks_evenly_and_all_when_asked():
    assert spread(10, 0).tolist() == list(range(10)) and spread(10, 20).tolist() == list(range(10))
    assert spread(10, 3).tolist() == [0, 4, 9] or spread(10, 3).tolist() == [0, 5, 9]


#: Per notebook: what the real-data run changes beyond bop_root (fewer ablation variants keep the suite short).
NOTEBOOK_RUNS = {"01_render": {}, "02_train": {}, "03_evaluate": {}, "04_ablation_scales": {"variants": ["global", "32,16,13"]},
                 "05_ablation_fusion": {"variants": ["avg", "adaptive"], "n_seeds": 1, "seeded_variants": ["adaptive"]},
                 "06_reference_count": {}, "07_fast_vs_greedy": {}, "08_components": {}, "10_explore": {}}


@pytest.fixture(scope="module")
def real_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("real_cache")  # shared by the notebooks below, in order (renders, runs)


@pytest.fixture(scope="module")
def real_reports(tmp_path_factory):
    return tmp_path_factory.mktemp("reports")  # <reports>/real-lm/<notebook>, as the runner writes them


@pytest.mark.slow
@pytest.mark.parametrize("nb", list(NOTEBOOK_RUNS))
def test_notebooks_run_on_real_data_through_bop_root(nb, bop_root, real_cache, real_reports, tmp_path):
    """Each notebook of Table 1, the ablations, the reference count and fast-vs-greedy, and the explorer, end to
    end with ``bop_root`` (its smoke parameters otherwise): a real LineMOD / LineMOD-O pair takes the same path."""
    import papermill as pm

    from helpers.study.parameters import NOTEBOOK_DIR

    out = real_reports / "real-lm" / nb
    pm.execute_notebook(str(NOTEBOOK_DIR / f"{nb}.ipynb"), str(tmp_path / f"{nb}.ipynb"), cwd=str(NOTEBOOK_DIR),
                        parameters={"bop_root": str(bop_root), "cache_dir": str(real_cache), "out_dir": str(out),
                                    "workers": 0, **NOTEBOOK_RUNS[nb]}, progress_bar=False)
    run = json.loads((out / "run.json").read_text())
    assert run["parameters"]["bop_root"].endswith(f"{bop_root.parent.name}/{bop_root.name}")  # portable form
    if nb == "01_render":
        s = json.loads((out / "render_summary.json").read_text())
        assert s["objects"] == ["ape", "cat", "duck", "glue", "holepuncher"]
        assert any(k.startswith("test_q/ape") and v.startswith("real-lm-") for k, v in s["cache_keys"].items())
    if nb == "03_evaluate":
        m = json.loads((out / "metrics.json").read_text())
        assert m["held_out"] is None and [r["split"] for r in m["table1"]] == ["#1", "#2", "#3", "mean"]
        assert all(0 <= r["occluded unseen rot_acc"] <= 100 for r in m["table1"])
        assert not (out / "per_query_held_out.csv").exists()
    if nb == "10_explore":  # no held-out objects: bring-your-own answers the split's first unseen object
        assert json.loads((out / "byo.json").read_text())["object"] == "ape"


@pytest.mark.slow
def test_the_report_of_real_data_runs_builds_and_says_so(real_reports):
    """REPORT.md and claims.json from the notebooks' real-data runs above (skipped when they did not run)."""
    from helpers.study.report import build_report

    if not (real_reports / "real-lm" / "03_evaluate" / "metrics.json").exists():
        pytest.skip("the real-data notebook runs did not run in this session")
    report = build_report("real-lm", real_reports).read_text()
    assert "on real LineMOD / LineMOD-O photographs in BOP format" in report and "held-out objects" not in report
    claims = {c["id"]: c for c in json.loads((real_reports / "real-lm" / "claims.json").read_text())}
    assert "unseen_rot_acc" in claims and "held_out_rot_acc" not in claims


def test_a_smaller_sample_of_real_views_is_spread_over_the_scenes(bop_root):
    from helpers.study.pipeline import cap_test_queries, first, prepare_data

    cfg = DataConfig(n_references=8, n_train_queries=100, n_val_queries=3, n_test_queries=100, workers=0,
                     cache_dir=str(bop_root / "cache"))
    data = prepare_data(cfg, bop_root=str(bop_root))
    views = data.test_q["ape"]
    assert [i[1] for i in first(views, 3).meta["instances"]] == [0, 10, 19]  # spread, not images 0, 1, 2
    capped = cap_test_queries(data, 4)
    assert len(capped.test_q["ape"]) == 4 and len(capped.seen_test_q["ape"]) == 2
    assert first(views, 3).meta["key"] != views.meta["key"]  # a smaller sample is another set


def test_without_linemod_o_the_occluded_part_is_left_out(bop_root, tmp_path):
    from helpers.core.configs import GREEDY
    from helpers.evaluation.baselines import HogModel
    from helpers.study.pipeline import prepare_data
    from helpers.study.protocols.linemod import evaluate_split, table1

    only_lm = tmp_path / "only_lm"
    shutil.copytree(bop_root / "lm", only_lm / "lm")
    cfg = DataConfig(n_references=8, n_train_queries=8, n_val_queries=3, n_test_queries=4, workers=0,
                     cache_dir=str(bop_root / "cache"))
    data = prepare_data(cfg, bop_root=str(only_lm))
    assert data.occluded_q == {} and len(data.test_q["ape"]) == 4
    r = evaluate_split(HogModel(), data, 1, GREEDY, device="cpu")
    assert "occluded" not in r and {"unseen", "seen"} <= set(r)
    assert table1({1: r})["occluded unseen rot_acc"].isna().all()


def test_one_process_renders_the_benchmark_and_real_data_apart_in_process_and_in_workers(bop_root, tmp_path):
    """The rendering side follows the manifest it is handed: the benchmark's duck and LineMOD's duck (here the
    stand-in for id 9, bread) in one process are two meshes, and worker processes get a real data set's manifest
    itself (it is built from its folder, not read from a file)."""
    from helpers.data.datasets import ViewSetSpec, render_sets
    from helpers.data.linemod_bop import bop_manifest
    from helpers.data.manifest import load_manifest

    rc = DataConfig(workers=0).render_config()
    bench, real = load_manifest(), bop_manifest(bop_folders(bop_root)["lm"])
    a = render_sets([ViewSetSpec("duck", "reference", 2, 0, rc)], cache=tmp_path, workers=0, manifest=bench)[0]
    b = render_sets([ViewSetSpec("duck", "reference", 2, 0, rc)], cache=tmp_path, workers=0, manifest=real)[0]
    assert a.meta["key"] != b.meta["key"] and not np.array_equal(a.images, b.images)
    c = render_sets([ViewSetSpec("ape", "reference", 2, 0, rc)], cache=tmp_path / "w", workers=2, manifest=real)[0]
    d = render_sets([ViewSetSpec("ape", "reference", 2, 0, rc)], cache=tmp_path / "i", workers=0, manifest=real)[0]
    assert np.array_equal(c.images, d.images)  # the benchmark's duck, as LineMOD's ape, alike in workers
