"""Full, read-only or unusable output locations; non-image queries; same seed -> same metrics."""

from __future__ import annotations

import errno
import json
import os

import numpy as np
import pytest
import torch

from helpers.core import fileio
from helpers.core.views import ObjectViews
from helpers.search.features import FeatureCache
from helpers.study.byo import load_query_image


def _enospc(*_a, **_k):
    raise OSError(errno.ENOSPC, "No space left on device")


def test_full_disk_keeps_old_file_and_names_path(tmp_path, monkeypatch):
    target = tmp_path / "metrics.json"
    fileio.atomic_write_json(target, {"v": 1})
    monkeypatch.setattr(fileio.os, "fsync", _enospc)
    with pytest.raises(OSError, match="no space left") as ei:
        fileio.atomic_write_json(target, {"v": 2})
    assert ei.value.errno == errno.ENOSPC and str(target) in str(ei.value) and "bytes free" in str(ei.value)
    assert json.loads(target.read_text()) == {"v": 1}  # the previous result survives
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]  # no temporary file left


def test_read_only_file_system_is_named(tmp_path, monkeypatch):
    def erofs(*_a, **_k):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(fileio.tempfile, "mkstemp", erofs)
    with pytest.raises(OSError, match="read-only") as ei:
        fileio.atomic_write_text(tmp_path / "REPORT.md", "x")
    assert str(tmp_path / "REPORT.md") in str(ei.value)


def test_output_directory_that_cannot_exist(tmp_path):
    blocker = tmp_path / "reports"
    blocker.write_text("a file where a folder should be")
    with pytest.raises(OSError, match="cannot create output directory .*reports"):
        fileio.atomic_write_text(blocker / "quick" / "REPORT.md", "x")


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root may write anywhere")
def test_read_only_directory(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(PermissionError, match="not writable"):
            fileio.atomic_write_text(ro / "x.txt", "x")
    finally:
        ro.chmod(0o755)


class _TinyEncoder:
    def encode(self, x):
        return x.mean(dim=(2, 3))[:, :, None].repeat(1, 1, 4)


def test_feature_cache_full_disk_fails_before_mapping(tmp_path, monkeypatch):
    """A sparse memmap on a full disk dies with SIGBUS; the cache reserves the bytes first."""
    views = ObjectViews("duck", np.zeros((6, 8, 8, 3), np.uint8), np.tile(np.eye(3), (6, 1, 1)), kind="reference")
    monkeypatch.setattr(fileio.os, "posix_fallocate", _enospc, raising=False)
    cache = FeatureCache(tmp_path / "features")
    with pytest.raises(OSError, match="no space left") as ei:
        cache.get_or_build(_TinyEncoder(), "m", views, "refs", batch=4, progress=False)
    assert ".refs.f16.partial" in str(ei.value) and "bytes needed" in str(ei.value)
    monkeypatch.undo()
    out = cache.get_or_build(_TinyEncoder(), "m", views, "refs", batch=4, progress=False)  # space again: works
    assert out.shape == (6, 3, 4)


def test_preallocate_reserves_blocks(tmp_path):
    p = fileio.preallocate(tmp_path / "f.bin", 1 << 20)
    assert p.stat().st_size == 1 << 20
    assert os.stat(p).st_blocks * 512 >= 1 << 20  # really allocated, not a sparse hole


def test_non_image_query_is_refused_with_its_name(tmp_path):
    bad = tmp_path / "query.png"
    bad.write_text("this is not a PNG")
    with pytest.raises(ValueError, match=r"query\.png is not a readable image"):
        load_query_image(bad, 64)
    with pytest.raises(FileNotFoundError, match="missing.jpg"):
        load_query_image(tmp_path / "missing.jpg", 64)
    empty = tmp_path / "empty.jpg"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match="empty.jpg"):
        load_query_image(empty, 64)


def test_checkpoint_write_on_full_disk_keeps_last_checkpoint(tmp_path, monkeypatch):
    from helpers.training.train import _atomic_torch_save

    path = tmp_path / "last.pt"
    _atomic_torch_save({"epoch": 3}, path)
    monkeypatch.setattr(fileio.os, "fsync", _enospc)
    with pytest.raises(OSError, match="last.pt: no space left"):
        _atomic_torch_save({"epoch": 4}, path)
    monkeypatch.undo()
    assert torch.load(path, weights_only=True) == {"epoch": 3}  # resume still starts from epoch 3


@pytest.mark.gl
def test_smoke_preset_is_deterministic(tmp_path):
    """Two runs of notebook 02 (smoke preset) from empty caches give identical metrics (CPU, same seed)."""
    import papermill as pm

    from helpers.study.parameters import notebook_path

    runs = []
    for k in range(2):
        out = tmp_path / f"out{k}"
        pm.execute_notebook(str(notebook_path("02_train")), str(tmp_path / f"02_{k}.ipynb"), kernel_name="python3",
                            progress_bar=False, parameters={"device": "cpu", "workers": 0, "out_dir": str(out),
                                                            "cache_dir": str(tmp_path / f"cache{k}")})
        hist = json.loads((out / "history.json").read_text())
        for h in hist["history"]:
            for t in ("seconds", "images_per_s", "cpu_share"):  # timings: they vary run to run
                h.pop(t)
        table = (out / "unseen_per_object.csv").read_text()
        m = json.loads((out / "train_metrics.json").read_text())
        m = {k2: v for k2, v in m.items() if k2 not in ("run_dir", "checkpoint", "train_seconds",
                                                          "train_images_per_s")}
        m["unseen_test"].pop("s_per_query")
        runs.append((m, hist, table))
    assert runs[0] == runs[1]
    assert runs[0][1]["history"] and all(np.isfinite(h["train_loss"]) for h in runs[0][1]["history"])
