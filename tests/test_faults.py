"""Faults a user meets: bad values before work, --only without names, resumed runs, bad query
images, corrupted feature caches, bring-your-own inputs (RGBA, non-square, broken meshes)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from helpers.core.configs import ModelConfig
from helpers.core.views import ObjectViews
from helpers.net.model import OrientationNet
from helpers.search.features import FeatureCache
from helpers.study import byo
from helpers.study.cli import runner
from helpers.study.parameters import ParameterError, check_parameters, check_values

# ------------------------------------------------------------------ parameter values and the runner


@pytest.mark.parametrize("name,value,match", [
    ("fusion", "adaptve", "'fusion' expects one of"),
    ("epochs", -1, "'epochs' expects an int >= 1"),
    ("lr", 0.0, "'lr' expects a learning rate > 0"),
    ("split", 4, "'split' expects one of"),
    ("scales", "32,8", "'scales' expects"),
    ("query_style", "lineMOD", "'query_style' expects one of"),
    ("device", "gpu", "'device' expects"),
    ("image_size", 72, "multiple of 16"),
])
def test_bad_values_stop_the_parameter_check(name, value, match):
    with pytest.raises(ParameterError, match=match):
        check_parameters("02_train", {name: value})


def test_bad_variant_values_are_named():
    with pytest.raises(ParameterError, match="bad: \\['attention'\\]"):
        check_parameters("05_ablation_fusion", {"variants": ["avg", "attention"]})
    with pytest.raises(ParameterError, match="reference_counts' expects a non-empty ascending list"):
        check_parameters("06_reference_count", {"reference_counts": [48, 6]})
    with pytest.raises(ParameterError, match="reference_counts"):
        check_parameters("06_reference_count", {"reference_counts": [0, 6]})
    check_parameters("06_reference_count", {"reference_counts": [6, 4800]})  # the sweep renders its own set


@pytest.mark.parametrize("value,match", [
    ({"coarse_k": [8, 8]}, "'coarse_k' expects a list of distinct ints >= 1"),
    ({"coarse_k": [5]}, "'coarse_k' expects candidates < k_ac=5"),  # smoke: the paper ratio of 48 references
    ({"refine_objects": []}, "'refine_objects' expects a list of distinct ints >= 1, got"),
    ({"halving_refine_objects": [0]}, "'halving_refine_objects' expects"),
    ({"c2f_min_agreement": 1.5}, "'c2f_min_agreement' expects a share in"),
    ({"fast_variants": [[8]]}, "'fast_variants' expects a list of \\[k_ac, fps_k\\] pairs"),
    ({"fast_variants": [[8, 0]]}, "'fast_variants' expects a list of \\[k_ac, fps_k\\] pairs"),
])
def test_bad_coarse_to_fine_candidates_are_named(value, match):
    with pytest.raises(ParameterError, match=match):
        check_parameters("07_fast_vs_greedy", value)
    check_parameters("07_fast_vs_greedy", {"coarse_k": [], "halving_refine_objects": []})  # empty: rows skipped


@pytest.mark.parametrize("value,match", [
    ({"report_dir": "/nonexistent/report"}, "'report_dir' expects '' or an existing report folder"),
    ({"old_k_ac": 0}, "'old_k_ac' expects an int >= 1"),
    ({"old_fps_k": -1}, "'old_fps_k' expects an int >= 1"),
])
def test_bad_gap_account_inputs_are_named(value, match):
    with pytest.raises(ParameterError, match=match):
        check_parameters("11_gap_to_paper", value)


def test_every_preset_passes_the_value_check():
    for preset in runner.PRESETS:
        for nb in runner.preset_notebooks(preset):
            P = runner.preset_parameters(preset, nb)
            if P.get("bop_root") and "bop_split" not in P:  # real-lm: its data are not on this machine
                with pytest.raises(ParameterError, match="parameter 'bop_root'.*not a folder"):
                    check_values(nb, P)
                P = {**P, "bop_root": ""}  # every other value still passes
            check_values(nb, P)


def test_runner_refuses_only_without_names(capsys):
    assert runner.main(["smoke", "--only"]) == 2
    assert "--only: name at least one notebook" in capsys.readouterr().err


def test_runner_refuses_a_bad_value_before_any_notebook_runs(tmp_path, monkeypatch, capsys):
    preset = tmp_path / "presets" / "smoke"
    preset.mkdir(parents=True)
    (preset / "02_train.yaml").write_text("epochs: -1\n")
    monkeypatch.setattr(runner, "PRESET_DIR", tmp_path / "presets")
    ran = []
    monkeypatch.setattr("papermill.execute_notebook", lambda *a, **k: ran.append(a))
    assert runner.main(["smoke"]) == 2
    assert "'epochs' expects an int >= 1" in capsys.readouterr().err and not ran


def test_only_keeps_the_timings_of_the_notebooks_it_does_not_run(tmp_path, monkeypatch):
    """A fresh clone has committed timings but no runner state: --only must not drop the others'."""
    monkeypatch.setattr(runner, "REPO_ROOT", tmp_path)
    out = tmp_path / "reports" / "smoke"
    out.mkdir(parents=True)
    (out / "timings.json").write_text(json.dumps({"03_evaluate": 123.0, "07_fast_vs_greedy": 9.0}))
    monkeypatch.setattr("papermill.execute_notebook", lambda src, dst, parameters, **kw: open(dst, "w").write("{}"))
    runner.run("smoke", only=["07_fast_vs_greedy"], html=False, report=False)
    t = json.loads((out / "timings.json").read_text())
    assert t["03_evaluate"] == 123.0 and t["07_fast_vs_greedy"] != 9.0 and set(t) == {"03_evaluate", "07_fast_vs_greedy"}


@pytest.mark.parametrize("killed_at", range(len(runner.notebooks())))
def test_killed_run_resumes_without_redoing_finished_notebooks(tmp_path, monkeypatch, killed_at):
    names = runner.notebooks()
    monkeypatch.setattr(runner, "REPO_ROOT", tmp_path)
    calls, kill = [], [True]

    def fake_execute(src, dst, parameters, **kw):
        name = src.rsplit("/", 1)[-1][:-6]
        calls.append(name)
        if name == names[killed_at] and kill:
            kill.pop()
            raise KeyboardInterrupt  # the run is killed inside this notebook, once
        open(dst, "w").write("{}")

    monkeypatch.setattr("papermill.execute_notebook", fake_execute)
    with pytest.raises(KeyboardInterrupt):
        runner.run("smoke", html=False, report=False)
    assert calls == names[:killed_at + 1]
    calls.clear()
    runner.run("smoke", html=False, report=False)
    assert calls == names[killed_at:]  # finished notebooks are skipped, the killed one reruns
    timings = json.loads((tmp_path / "reports" / "smoke" / "timings.json").read_text())
    assert sorted(timings) == sorted(names)
    calls.clear()
    runner.run("smoke", html=False, report=False, restart=True)
    assert calls == names


# ---------------------------------------------------------------------------- model inputs


def test_wrong_query_images_into_the_model_are_refused():
    m = OrientationNet(ModelConfig(image_size=64)).eval()
    with pytest.raises(ValueError, match=r"expected \(B,3,64,64\)"):
        m.encode(torch.rand(1, 3, 96, 96))
    with pytest.raises(ValueError, match="uint8 in \\[0, 255\\] or float in \\[0, 1\\]"):
        m.encode(torch.randint(0, 255, (1, 3, 64, 64), dtype=torch.int32))
    with pytest.raises(ValueError, match="divide 8-bit values by 255"):
        m.encode(torch.rand(1, 3, 64, 64) * 255)
    with pytest.raises(ValueError, match="torch tensor"):
        m.encode(np.zeros((1, 3, 64, 64), np.float32))
    f = m.encode(torch.rand(2, 3, 64, 64))
    with pytest.raises(ValueError, match="q: expected features"):
        m.score(f[:, :, :10], f)


# ---------------------------------------------------------------------------- feature cache


def _cache_with_features(tmp_path):
    class Enc:
        def encode(self, x):
            return x.mean(dim=1).flatten(1)[:, None, :8].repeat(1, 2, 1)

    views = ObjectViews("o", np.random.default_rng(0).integers(0, 255, (5, 8, 8, 3), dtype=np.uint8),
                        np.tile(np.eye(3), (5, 1, 1)), None, "reference")
    fc = FeatureCache(tmp_path)
    fc.get_or_build(Enc(), "m", views, "k", batch=2, progress=False)
    return fc, Enc(), views


def test_nan_in_a_cached_feature_file_is_detected(tmp_path):
    fc, _, _ = _cache_with_features(tmp_path)
    final, side, _ = fc.paths("m", "k")
    raw = np.fromfile(final, dtype=np.float16)
    raw[3] = np.nan
    raw.tofile(final)
    with pytest.raises(ValueError, match="does not match the checksum"):
        FeatureCache(tmp_path).load("m", "k")


def test_old_cache_without_checksum_is_scanned_for_nan(tmp_path):
    fc, _, _ = _cache_with_features(tmp_path)
    final, side, _ = fc.paths("m", "k")
    meta = json.loads(side.read_text())
    meta.pop("sha256")
    side.write_text(json.dumps(meta))
    raw = np.fromfile(final, dtype=np.float16)
    raw[0] = np.inf
    raw.tofile(final)
    with pytest.raises(ValueError, match="NaN/inf"):
        FeatureCache(tmp_path).load("m", "k")


def test_model_producing_nan_is_not_cached(tmp_path):
    class Bad:
        def encode(self, x):
            return torch.full((x.shape[0], 2, 4), float("nan"))

    views = ObjectViews("o", np.zeros((3, 8, 8, 3), np.uint8), np.tile(np.eye(3), (3, 1, 1)), None, "reference")
    with pytest.raises(ValueError, match="non-finite features for views 0..2"):
        FeatureCache(tmp_path).get_or_build(Bad(), "m", views, "k", batch=4, progress=False)
    assert FeatureCache(tmp_path).load("m", "k") is None


# ---------------------------------------------------------------------------- bring your own


def test_rgba_query_is_composited_over_black_not_read_as_stored(tmp_path):
    img = np.full((40, 40, 4), 255, np.uint8)  # white everywhere underneath
    img[..., 3] = 0
    img[10:30, 10:30, :3] = (0, 0, 200)  # BGR: a red square, the only opaque part
    img[10:30, 10:30, 3] = 255
    p = tmp_path / "q.png"
    cv2.imwrite(str(p), img)
    out = byo.load_query_image(p, 40)
    assert out[0, 0].tolist() == [0, 0, 0] and out[20, 20].tolist() == [200, 0, 0]
    cropped = byo.load_query_image(p, 20, alpha="crop")
    assert (cropped[..., 0] == 200).all()  # cut to the opaque box
    with pytest.raises(ValueError, match="alpha"):
        byo.load_query_image(p, 20, alpha="ignore")


def test_non_square_query_is_padded_not_cut(tmp_path):
    img = np.zeros((20, 60, 3), np.uint8)
    img[:, :5] = 255  # object content at the far left and right edges
    img[:, -5:] = 255
    p = tmp_path / "wide.png"
    cv2.imwrite(str(p), img)
    out = byo.load_query_image(p, 60)
    assert out.shape == (60, 60, 3)
    assert out[30, :5].min() == 255 and out[30, -5:].min() == 255  # both edges survive
    assert out[:20].max() == 0 and out[-20:].max() == 0  # black bands above and below


def test_degenerate_and_broken_meshes_name_the_file(tmp_path):
    flat = tmp_path / "point.obj"
    flat.write_text("v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=str(flat)):
        byo.custom_object(flat)
    junk = tmp_path / "junk.ply"
    junk.write_text("not a mesh")
    with pytest.raises(ValueError, match=str(junk)):
        byo.custom_object(junk)


def test_second_byo_call_renders_and_encodes_nothing(tmp_path, manifest, monkeypatch):
    name = manifest.held_out_objects()[0]
    entry = manifest.object(name)
    model = OrientationNet(ModelConfig(image_size=64)).eval()
    q = np.zeros((64, 64, 3), np.uint8)
    q[20:44, 20:44] = 180
    qp = tmp_path / "q.png"
    cv2.imwrite(str(qp), q)
    kw = dict(n_refs=16, render_size=96, color=entry.color, device="cpu", cache=tmp_path / "cache")
    first = byo.estimate_rotation(model, entry.mesh.resolve(), qp, **kw)

    def forbidden(*_a, **_k):
        raise AssertionError("the second call must use the cached references and features")

    monkeypatch.setattr(byo, "render_custom_references", forbidden)
    monkeypatch.setattr(FeatureCache, "get_or_build", forbidden)
    monkeypatch.setattr(byo, "custom_object", forbidden)
    second = byo.estimate_rotation(model, entry.mesh.resolve(), qp, **kw)
    assert second.ref_index == first.ref_index and np.allclose(second.R_m2c, first.R_m2c)
    # Another model (other weights): its own features, so the cache must not be reused.
    other = OrientationNet(ModelConfig(image_size=64)).eval()
    with pytest.raises(AssertionError, match="cached"):
        byo.estimate_rotation(other, entry.mesh.resolve(), qp, **kw)


def test_answer_views_reads_each_photo_back_as_a_png_and_scores_it_with_the_object_symmetries(monkeypatch):
    """Notebook 10's bring-your-own check: the references are built once, every photo reaches the
    search as the user's PNG would (pixels unchanged), and errors use the benchmark's metric (an
    answer equal up to a symmetry is right)."""
    from types import SimpleNamespace

    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    R_gt = Rotation.random(3, random_state=1).as_matrix()
    flip = Rotation.from_euler("z", 180, degrees=True).as_matrix()
    views = ObjectViews("box", rng.integers(0, 255, (3, 16, 16, 3), dtype=np.uint8), R_gt.astype(np.float32),
                        kind="query", symmetries=np.stack([np.eye(3), flip]))
    answers = [R_gt[0], R_gt[1] @ flip, R_gt[2] @ Rotation.from_euler("x", 90, degrees=True).as_matrix()]
    seen, built = [], []

    def fake_answer(model, rs, query, n_alternatives=4):
        seen.append(query)
        i = len(seen) - 1
        return byo.ByoResult(answers[i], 0.5 + i, i, query, query)

    monkeypatch.setattr(byo, "reference_set", lambda model, mesh, **kw: built.append(kw) or "refs")
    monkeypatch.setattr(byo, "answer", fake_answer)
    model = SimpleNamespace(cfg=SimpleNamespace(image_size=16))
    table, results = byo.answer_views(model, "mesh.obj", views, n=0, n_refs=8)
    assert built == [{"n_refs": 8}] and all(np.array_equal(a, b) for a, b in zip(seen, views.images))
    assert np.allclose(table["err_deg"], [0.0, 0.0, 90.0], atol=0.05)  # float32 truths
    assert table["rot_ok"].tolist() == [True, True, False] and table["class_ok"].all()
    assert table["score"].tolist() == [0.5, 1.5, 2.5] and [r.ref_index for r in results] == [0, 1, 2]
    seen.clear()
    assert len(byo.answer_views(model, "mesh.obj", views, n=2)[0]) == 2  # the first n photos only
    with pytest.raises(ValueError, match="n expected 0"):
        byo.answer_views(model, "mesh.obj", views, n=-1)
    with pytest.raises(ValueError, match="box has no views"):
        byo.answer_views(model, "mesh.obj", views.subset(np.arange(0)))


def test_time_of_an_interrupted_notebook_counts_in_its_timing(tmp_path, monkeypatch):
    """A notebook killed once and rerun reports both attempts' wall time (heartbeat in the state)."""
    import time as _time

    names = runner.notebooks()
    monkeypatch.setattr(runner, "REPO_ROOT", tmp_path)
    monkeypatch.setattr(runner, "HEARTBEAT_S", 0.02)
    kill = [True]

    def fake_execute(src, dst, parameters, **kw):
        name = src.rsplit("/", 1)[-1][:-6]
        if name == names[1]:
            _time.sleep(0.3)
            if kill:
                kill.pop()
                raise KeyboardInterrupt
        open(dst, "w").write("{}")

    monkeypatch.setattr("papermill.execute_notebook", fake_execute)
    with pytest.raises(KeyboardInterrupt):
        runner.run("smoke", html=False, report=False)
    state = json.loads((tmp_path / "reports" / "smoke" / runner.STATE_FILE).read_text())
    assert state[names[1]]["done"] is False and state[names[1]]["seconds"] >= 0.3
    runner.run("smoke", html=False, report=False)
    timings = json.loads((tmp_path / "reports" / "smoke" / "timings.json").read_text())
    assert timings[names[1]] >= 0.6  # 0.3 s killed + 0.3 s rerun
    state = json.loads((tmp_path / "reports" / "smoke" / runner.STATE_FILE).read_text())
    assert state[names[1]]["attempts"] == 2 and state[names[1]]["done"] is True
