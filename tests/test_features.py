"""Reference feature cache with a tiny fake model."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from helpers.core.configs import ModelConfig
from helpers.core.fileio import source_digest
from helpers.core.views import ObjectViews
from helpers.search.features import FeatureCache, encode_views, model_fingerprint


class FakeModel(torch.nn.Module):
    """encode: 4x4 average pooling of each channel -> (B, 3, L) unit vectors per location."""

    def __init__(self, fail_after: int | None = None):
        super().__init__()
        self.w = torch.nn.Parameter(torch.ones(1))
        self.config = {"pool": 4}
        self.calls = 0
        self.fail_after = fail_after

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        self.calls += 1
        if self.fail_after is not None and self.calls > self.fail_after:
            raise KeyboardInterrupt("simulated interruption")
        f = torch.nn.functional.avg_pool2d(x, 4).flatten(2) * self.w + 0.01
        return f / f.norm(dim=1, keepdim=True)


def _views(n=10, s=16, seed=0) -> ObjectViews:
    rng = np.random.default_rng(seed)
    return ObjectViews("toy", rng.integers(0, 256, (n, s, s, 3), dtype=np.uint8),
                       np.tile(np.eye(3, dtype=np.float32), (n, 1, 1)))


def _reference(model, views) -> np.ndarray:
    return torch.cat(list(encode_views(model, views.images, batch=3))).numpy()


def test_encode_views_batches():
    v = _views(7)
    model = FakeModel()
    parts = list(encode_views(model, v.images, batch=3))
    assert [p.shape[0] for p in parts] == [3, 3, 1] and parts[0].shape[1:] == (3, 16)
    assert parts[0].dtype == torch.float32
    with pytest.raises(ValueError, match="uint8"):
        next(encode_views(model, v.images.astype(np.float32)))


def test_roundtrip_and_cached(tmp_path):
    v = _views(10)
    model = FakeModel()
    cache = FeatureCache(tmp_path)
    out = cache.get_or_build(model, "m1", v, "toyset", batch=4, progress=False)
    assert isinstance(out, np.memmap) and out.dtype == np.float16 and out.shape == (10, 3, 16)
    assert not out.flags.writeable
    np.testing.assert_allclose(out.astype(np.float32), _reference(FakeModel(), v), atol=1e-3)
    meta = json.loads((tmp_path / "m1" / "toyset.json").read_text())
    assert meta["complete"] and meta["done"] == 10 and meta["shape"] == [10, 3, 16]
    assert not list((tmp_path / "m1").glob(".*partial"))

    calls = model.calls
    again = cache.get_or_build(model, "m1", v, "toyset", batch=4, progress=False)
    assert model.calls == calls  # nothing re-encoded
    np.testing.assert_array_equal(again, out)
    # Same key, different views: refuse instead of returning wrong features.
    with pytest.raises(ValueError, match="different views"):
        cache.get_or_build(model, "m1", _views(10, seed=1), "toyset", progress=False)
    with pytest.raises(ValueError, match="refset_key"):
        cache.get_or_build(model, "m1", v, "../evil", progress=False)


def test_resume_after_interruption(tmp_path):
    v = _views(10)
    cache = FeatureCache(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        cache.get_or_build(FakeModel(fail_after=2), "m1", v, "toyset", batch=3, progress=False)
    final, side, tmp = cache.paths("m1", "toyset")
    assert not final.exists() and tmp.exists()
    meta = json.loads(side.read_text())
    assert meta["done"] == 6 and not meta["complete"]
    assert cache.load("m1", "toyset") is None

    model = FakeModel()
    out = cache.get_or_build(model, "m1", v, "toyset", batch=3, progress=False)
    assert model.calls == 2  # images 6..9 only: two batches of 3 and 1
    np.testing.assert_allclose(out.astype(np.float32), _reference(FakeModel(), v), atol=1e-3)
    assert final.exists() and not tmp.exists()


def test_fingerprint():
    a, b = FakeModel(), FakeModel()
    assert model_fingerprint(a) == model_fingerprint(b)
    with torch.no_grad():
        b.w.add_(1e-6)
    assert model_fingerprint(a) != model_fingerprint(b)
    c = FakeModel()
    c.config = {"pool": 2}
    assert model_fingerprint(a) != model_fingerprint(c)
    assert len(model_fingerprint(a)) == 16


def test_fingerprint_changes_with_the_encoding_code(tmp_path, monkeypatch):
    """Cached features of older encoding code are never read back: the key covers the encoder's source."""
    from helpers.net.model import OrientationNet
    from helpers.search import features
    net = {p.name for p in features.encoder_sources(OrientationNet(ModelConfig()))}
    # the model and its backbone, preprocessing, precision and this cache; not the scoring kernel nor torch's code
    assert {"model.py", "backbone.py", "local_norm.py", "precision.py", "features.py"} <= net
    assert "fusion_kernel.py" not in net and "module.py" not in net
    assert "test_features.py" in {p.name for p in features.encoder_sources(FakeModel())}
    src = tmp_path / "encoder.py"
    src.write_text("x = 1\n")
    monkeypatch.setattr(features, "encoder_sources", lambda model: [src])
    before = model_fingerprint(FakeModel())
    src.write_text("x = 2\n")
    assert model_fingerprint(FakeModel()) != before


def test_fingerprint_covers_the_runtime_precision_and_a_model_defined_in_a_notebook():
    """bf16 and float32 encodings of the same weights are different features; a class without a source file
    (a notebook's, ``python -c``) still gets a key."""
    from helpers.net.model import OrientationNet
    torch.manual_seed(0)
    m = OrientationNet(ModelConfig())
    fp32 = model_fingerprint(m)
    m.precision = "bf16"
    assert model_fingerprint(m) != fp32
    Notebook = type("Notebook", (FakeModel,), {"__module__": "__main__"})
    assert len(model_fingerprint(Notebook())) == 16


def test_source_digest_reads_what_files_say(tmp_path):
    """A folder counts by its .py and .cpp files; the digest changes with a file's bytes, not its mtime."""
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.py").write_text("a = 1\n")
    (tmp_path / "pkg" / "k.cpp").write_text("int k;\n")
    (tmp_path / "pkg" / "notes.txt").write_text("ignored\n")
    (tmp_path / "pkg" / ".#a.py").symlink_to(tmp_path / "gone")  # an editor's lock: hidden and dangling
    d = source_digest([tmp_path / "pkg"])
    (tmp_path / "pkg" / "notes.txt").write_text("changed\n")
    (tmp_path / "pkg" / "a.py").touch()
    assert source_digest([tmp_path / "pkg"]) == d and len(d) == 16
    (tmp_path / "pkg" / "k.cpp").write_text("int k2;\n")
    assert source_digest([tmp_path / "pkg"]) != d
    assert source_digest([tmp_path / "pkg" / "a.py"]) != source_digest([tmp_path / "pkg"])
