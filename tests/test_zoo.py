"""The model zoo: committed files match their sha256, load, and reproduce their recorded scores;
a recipe trains (in a child process, as zoo train --until runs it), resumes from a committed checkpoint,
publishes and is refused when damaged."""

import json
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from helpers.core.precision import autocast, native_bf16, resolve_precision
from helpers.study import zoo
from helpers.study.cli.train_until import train_until

TINY = {
    "data": {"image_size": 64, "render_size": 64, "n_references": 8, "n_train_queries": 4, "n_val_queries": 2,
             "n_test_queries": 1, "query_style": "linemod", "train_context": 1.5, "seed": 0, "workers": 0},
    "val_refs": 6,
    "train": {"epochs": 1, "steps_per_epoch": 2, "batch_size": 2, "lr": 0.001, "lr_schedule": "cosine",
              "warmup_steps": 1, "clean_steps": 1, "random_ref": "own", "val_every": 1, "seed": 0,
              "precision": "fp32", "progress": False},
    "models": {"tiny": {"split": 1}, "tiny-avg": {"split": 1, "model": {"fusion": "avg"}, "train": {"seed": 1}}},
}


def _recipes(tmp_path: Path, epochs: int, cache: str) -> dict:
    spec = {**TINY, "train": {**TINY["train"], "epochs": epochs}}
    path = tmp_path / f"zoo-{epochs}.yaml"
    path.write_text(yaml.safe_dump(spec))
    return zoo.recipes(path, cache_dir=cache, device="cpu")


def test_zoo_speed_is_the_median_of_the_quiet_epochs():
    hist = [{"epoch": 1, "images_per_s": 60.0, "cpu_share": 0.95}, {"epoch": 2, "images_per_s": 20.0, "cpu_share": 0.4},
            {"epoch": 3, "images_per_s": 64.0, "cpu_share": 0.97}, {"epoch": 4, "images_per_s": 30.0, "cpu_share": 0.8}]
    s = zoo.quiet_speed(hist)  # epochs 2 (shared) and 4 (paused for a while) are left out
    assert s["train_images_per_s"] == 62.0 and s["train_speed_epochs"] == 2 and "0.97" in s["train_speed_rule"]
    old = [{k: v for k, v in h.items() if k != "cpu_share"} for h in hist]  # histories from before cpu_share
    assert zoo.quiet_speed(old)["train_images_per_s"] == 45.0 and zoo.quiet_speed(old)["train_speed_epochs"] == 4
    mixed = zoo.quiet_speed(old[:2] + hist[2:])  # resumed from an older run: not every epoch has a share
    assert mixed["train_speed_epochs"] == 4 and "2 of 4" in mixed["train_speed_rule"]
    assert zoo.quiet_speed([{"epoch": 1}], 7.0) == {"train_images_per_s": 7.0, "train_speed_epochs": 0,
                                                    "train_speed_rule": zoo.quiet_speed([], 7.0)["train_speed_rule"]}


def test_refresh_speeds_rewrites_each_entry_from_its_history(tmp_path):
    hist = [{"epoch": 1, "images_per_s": 60.0, "cpu_share": 0.95}, {"epoch": 2, "images_per_s": 20.0, "cpu_share": 0.4}]
    (tmp_path / "a.history.json").write_text(json.dumps({"history": hist}))
    (tmp_path / "zoo.yaml").write_text(yaml.safe_dump({"models": {"a": {
        "file": "a.pt", "history": "a.history.json", "train_images_per_s": 40.0, "train_seconds": 9.0}}}))
    assert zoo.refresh_speeds(tmp_path) == {"a": 60.0}
    e = zoo.entries(tmp_path)["a"]
    assert list(e) == ["file", "history", "train_images_per_s", "train_speed_epochs", "train_speed_rule",
                       "train_seconds"]
    assert e["train_speed_epochs"] == 1 and zoo.refresh_speeds(tmp_path) == {"a": 60.0}  # idempotent


def test_progress_tells_published_from_checkpointed_from_untrained(tmp_path):
    path = tmp_path / "zoo.yaml"
    path.write_text(yaml.safe_dump({**TINY, "models": {**TINY["models"], "tiny-wl": {"split": 1,
                                                                                    "train": {"weighted_loss": False}}}}))
    zdir = tmp_path / "models"
    (zdir / "checkpoints").mkdir(parents=True)
    (zdir / "zoo.yaml").write_text(yaml.safe_dump({"models": {"tiny": {"steps": 2, "val": {"rot_acc": 0.5},
                                                                  "train_seconds": 90.0, "precision": "fp32",
                                                                  "train_images_per_s": 30.0}}}))
    torch.save({"global_step": 1}, zdir / "checkpoints" / "tiny-avg.last.pt")
    rows = {r["name"]: r for r in zoo.progress(path, zdir)}
    assert [rows[n]["state"] for n in ("tiny", "tiny-avg", "tiny-wl")] == ["published", "checkpoint", "untrained"]
    assert [rows[n]["steps"] for n in ("tiny", "tiny-avg", "tiny-wl")] == [2, 1, 0]
    assert rows["tiny"]["val"] == {"rot_acc": 0.5} and all(r["budget"] == 2 for r in rows.values())
    assert (rows["tiny"]["train_seconds"], rows["tiny"]["precision"], rows["tiny"]["images_per_s"]) == (90.0, "fp32", 30.0)
    assert rows["tiny-avg"]["train_seconds"] is None
    rows = zoo.progress(path, tmp_path / "empty")  # nothing published yet
    assert [r["state"] for r in rows] == ["untrained"] * 3


def test_committed_zoo_files_match_load_and_reproduce_their_scores():
    models = zoo.entries()
    assert models, "models/zoo.yaml lists no model"
    assert zoo.verify() == []
    for name, e in models.items():
        model, got = zoo.load(name, device="cpu")
        assert got["sha256"] == e["sha256"]
        chk = np.load(zoo.ZOO_DIR / e["check"])
        scores = zoo.check_scores(model, chk["queries"], chk["refs"])
        np.testing.assert_allclose(scores, chk["scores"], atol=2e-3, err_msg=name)
        assert (zoo.ZOO_DIR / e["history"]).exists()
        for key in ("git", "device", "train", "data", "steps", "seed", "val", "train_images_per_s"):
            assert e.get(key) is not None, f"{name}: zoo.yaml entry lacks {key}"


def test_recipes_merge_overrides_and_name_bad_entries(tmp_path):
    rs = _recipes(tmp_path, 1, str(tmp_path))
    assert rs["tiny-avg"].train.model.fusion == "avg" and rs["tiny-avg"].train.seed == 1
    assert rs["tiny"].train.model.fusion == "adaptive" and rs["tiny"].train.seed == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**TINY, "models": {"x": {"split": 5}}}))
    with pytest.raises(ValueError, match=r"bad.yaml: model 'x': split"):
        zoo.recipes(bad)
    bad.write_text(yaml.safe_dump({**TINY, "models": {"x": {"split": 1, "lr": 1}}}))
    with pytest.raises(ValueError, match="unknown keys"):
        zoo.recipes(bad)


def test_recipe_trains_resumes_from_committed_checkpoint_publishes_and_refuses_damage(tmp_path):
    zdir = tmp_path / "models"
    r1 = _recipes(tmp_path, 1, str(tmp_path / "cacheA"))["tiny"]
    # Trained by a real child `zoo train tiny` (zoo train --until, far deadline): same recipe file and cache, so
    # the run this process then loads is the one the child finished.
    assert train_until(r1, time.time() + 1800, tmp_path / "zoo-1.yaml", "cpu") == "finished"
    _, run1, _, _ = zoo.train_recipe(r1, zoo_dir=zdir)
    assert (run1 / "done.json").exists()
    zoo.snapshot(r1, zoo_dir=zdir)
    assert (zdir / "checkpoints" / "tiny.last.pt").exists() and (zdir / "checkpoints" / "tiny.best.pt").exists()
    # Another machine (empty cache, other precision), longer budget: resumes from the committed checkpoint.
    from dataclasses import replace

    r2 = _recipes(tmp_path, 2, str(tmp_path / "cacheB"))["tiny"]
    r2 = replace(r2, train=replace(r2.train, precision="bf16"))
    _, run2, info, data = zoo.train_recipe(r2, zoo_dir=zdir)
    hist = info["history"]["history"]
    assert [h["epoch"] for h in hist] == [1, 2] and [h["precision"] for h in hist] == ["fp32", "bf16"]
    first = torch.load(run1 / "last.pt", weights_only=True)["history"][0]
    assert hist[0]["train_loss"] == first["train_loss"]  # epoch 1 came from the checkpoint, not retrained
    best = torch.load(run2 / "best.pt", weights_only=True)
    assert best["epoch"] == info["history"]["best_epoch"]  # epoch 1's weights came along when it stays the best
    # A run behind the committed checkpoint never replaces it (cacheA is at step 2, the committed one now too).
    torch.save({**torch.load(zdir / "checkpoints" / "tiny.last.pt", weights_only=True), "global_step": 9},
               zdir / "checkpoints" / "tiny.last.pt")
    with pytest.raises(ValueError, match="further than this run"):
        zoo.snapshot(r1, zoo_dir=zdir)

    wfile = zoo.publish(r2, run2, data, zoo_dir=zdir)
    e = zoo.entry("tiny", zdir)
    assert e["steps"] == 4 and e["dtype"] == "float16" and e["precision"] == "bf16+fp32"
    assert e["git"]["commit"] and e["device"]["resolved"] == "cpu"
    assert [sess["from_step"] for sess in e["sessions"]] == [0, 2]  # cacheA's session, then cacheB's
    for k in ("class_acc", "rot_acc"):  # float16 weights: validation as recorded in training
        assert abs(e["val"][k] - e["val_recorded"][k]) <= 0.5 + 1e-9
    model, _ = zoo.load("tiny", device="cpu", zoo_dir=zdir)
    chk = np.load(zdir / e["check"])
    np.testing.assert_allclose(zoo.check_scores(model, chk["queries"], chk["refs"]), chk["scores"], atol=1e-5)
    assert zoo.verify(zdir) == []

    # Notebooks with models="zoo": the same split, architecture and seed find it, another seed does not.
    m2, where, info2 = zoo.model_for(1, replace(r2.train, epochs=7, lr=0.5), data, 6, "zoo", zoo_dir=zdir)
    assert where == wfile and info2["zoo"] == "tiny" and info2["history"]["history"]
    with pytest.raises(ValueError, match="no zoo model for split 1"):
        zoo.model_for(1, replace(r2.train, seed=3), data, 6, "zoo", zoo_dir=zdir)
    with pytest.raises(ValueError, match="models: expected one of"):
        zoo.model_for(1, r2.train, data, 6, "zoo!", zoo_dir=zdir)

    raw = bytearray(wfile.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    wfile.write_bytes(bytes(raw))
    assert any("sha256" in b for b in zoo.verify(zdir))
    with pytest.raises(ValueError, match="tiny.pt does not match the sha256"):
        zoo.load("tiny", device="cpu", zoo_dir=zdir)
    with pytest.raises(ValueError, match="no model 'nope'"):
        zoo.entry("nope", zdir)


def test_precision_auto_follows_the_hardware_and_bf16_stays_close():
    cpu = torch.device("cpu")
    assert resolve_precision("auto", cpu) == ("bf16" if native_bf16(cpu) else "fp32")
    with pytest.raises(ValueError, match="precision"):
        resolve_precision("fp16", cpu)
    from helpers.core.configs import ModelConfig
    from helpers.net.model import OrientationNet

    torch.manual_seed(0)
    m = OrientationNet(ModelConfig(image_size=64)).eval()
    x = torch.rand(2, 3, 64, 64)
    with torch.inference_mode():
        f32 = m.encode(x)
        m.precision = "bf16"
        f16 = m.encode(x)
    assert f16.dtype == torch.float32  # features leave the network as float32 either way
    assert (f32 - f16).abs().max() < 0.1 and torch.nn.functional.cosine_similarity(f32, f16, dim=1).min() > 0.97
    with autocast("fp32", cpu):
        assert not torch.is_autocast_enabled("cpu")


@pytest.mark.slow
def test_notebook_evaluates_the_zoo_model_with_models_zoo(tmp_path):
    """Notebook 06 (smoke data) with models="zoo" loads the committed split-1 model instead of training."""
    import json

    import papermill as pm

    from helpers.study.parameters import notebook_path

    out = tmp_path / "06.ipynb"
    pm.execute_notebook(str(notebook_path("06_reference_count")), str(out), kernel_name="python3",
                        parameters={"models": "zoo", "out_dir": str(tmp_path / "06")}, progress_bar=False)
    text = json.dumps(json.loads(out.read_text())["cells"])
    assert "models/split1.pt" in text
    assert (tmp_path / "06" / "metrics.json").exists()


@pytest.mark.slow
def test_ablation_notebook_evaluates_zoo_variants_and_records_them(tmp_path):
    """Notebook 05 (smoke data) with models="zoo" and two seeds of Avg and adaptive fusion evaluates the four
    committed models seed by seed, records each one's zoo name, sha256 and steps in metrics.json, keeps
    its per-query evaluations in the cache (nothing is written into models/), and reads them back."""
    import papermill as pm

    from helpers.core.paths import cache_dir
    from helpers.study.parameters import notebook_path

    before = sorted(p.name for p in zoo.ZOO_DIR.rglob("*"))
    params = {"models": "zoo", "variants": ["avg", "adaptive"], "seeded_variants": ["avg", "adaptive"], "n_seeds": 2}
    evals = cache_dir() / "evals"
    counts = []
    for run in ("a", "b"):
        pm.execute_notebook(str(notebook_path("05_ablation_fusion")), str(tmp_path / f"05{run}.ipynb"),
                            kernel_name="python3", parameters={**params, "out_dir": str(tmp_path / run)},
                            progress_bar=False)
        counts.append(len(list(evals.glob("*.csv"))))
    assert sorted(p.name for p in zoo.ZOO_DIR.rglob("*")) == before
    assert counts[0] >= 4 and counts[1] == counts[0]  # four models' evaluations, read back by the second run
    a, b = (json.loads((tmp_path / r / "metrics.json").read_text()) for r in ("a", "b"))
    models = {label: [m["model"] for m in ms] for label, ms in a["models"].items()}
    assert models == {"avg": ["avg", "avg-seed1"], "adaptive": ["split1", "split1-seed1"]}
    for ms in a["models"].values():
        for m in ms:
            e = zoo.entry(m["model"])
            assert (m["source"], m["sha256"], m["steps"]) == ("zoo", e["sha256"], e["steps"])
    assert {row["steps"] for row in a["table"]} == {str(zoo.entry("split1")["steps"])}
    assert a["table"] == b["table"]


def test_long_preset_trains_the_zoo_recipes_runs():
    """The long preset's notebook parameters give the zoo recipes' configs, so notebook 02/03 of
    the long preset and `python -m helpers.study.cli.zoo train` share (and resume) the same cache runs."""
    from dataclasses import asdict

    from helpers.study.parameters import configs_from
    from helpers.study.pipeline import _train_key
    from helpers.study.cli.runner import preset_parameters
    from helpers.study.protocols.variants import variant_config

    P = preset_parameters("long", "02_train")
    c = configs_from(P)
    data, cfg = c.data, c.train
    r = zoo.recipe("split1")
    assert _train_key(cfg) == _train_key(r.train)
    assert {k: v for k, v in asdict(data).items() if k not in ("workers", "cache_dir")} == \
        {k: v for k, v in asdict(r.data).items() if k not in ("workers", "cache_dir")}
    assert P["val_refs"] == r.val_refs and P["split"] == r.split
    # Notebook 03 trains the 12,000-step models the quick preset's 03 evaluates (zoo_steps: 12000).
    c3 = configs_from(preset_parameters("long", "03_evaluate"))
    assert _train_key(c3.train) == _train_key(zoo.recipe("split1-12k").train)
    assert _train_key(variant_config(c3.train, scales="global")) == _train_key(zoo.recipe("global-12k").train)


@pytest.mark.slow
def test_notebook_13_compares_two_zoo_budgets_on_the_same_queries_and_removes_them_without_pairs(tmp_path):
    """Notebook 13 (smoke data, split #1) evaluates split1 (4,000 steps) and split1-12k on the same unseen and seen
    queries; the budget claims pair them. A later run without pairs removes the comparison's files, so no stale file
    enters its claims."""
    import pandas as pd
    import papermill as pm

    from helpers.study.experiments import build_claims
    from helpers.study.parameters import notebook_path

    out = tmp_path / "13_budget"
    pm.execute_notebook(str(notebook_path("13_budget")), str(tmp_path / "a.ipynb"), kernel_name="python3",
                        parameters={"out_dir": str(out)}, progress_bar=False)
    pq = pd.read_csv(out / "per_query_budget.csv")
    short, long = (pq[pq["budget"] == b] for b in ("shorter", "longer"))
    assert set(short["steps"]) == {4000} and set(long["steps"]) == {12000}
    key = ["split", "part", "query_id"]
    assert sorted(map(tuple, short[key].values)) == sorted(map(tuple, long[key].values))
    ids = {c["id"]: c for c in build_claims(tmp_path)}
    assert {"longer_budget_unseen", "longer_budget_seen"} <= set(ids)
    assert "12000-step" in ids["longer_budget_unseen"]["claim"]
    pm.execute_notebook(str(notebook_path("13_budget")), str(tmp_path / "b.ipynb"), kernel_name="python3",
                        parameters={"out_dir": str(out), "budgets": []}, progress_bar=False)
    assert not (out / "per_query_budget.csv").exists() and not (out / "budget_splits.csv").exists()
    assert not any(c["id"].startswith("longer_budget") for c in build_claims(tmp_path))