import numpy as np
import pytest

import helpers.data.datasets as ds
from helpers.core.configs import QueryStyle, RenderConfig
from helpers.data.datasets import ViewSetSpec, render_sets

pytestmark = pytest.mark.gl
RC = RenderConfig(size=32, render_size=64)


def test_render_cache_and_shared_rotations(tmp_path, manifest):
    specs = [ViewSetSpec("duck", "reference", 6, 0, RC), ViewSetSpec("bunny", "reference", 6, 0, RC),
             ViewSetSpec("duck", "query", 5, 0, RC, QueryStyle(occlusion=0.5), "test")]
    a = render_sets(specs, cache=tmp_path, workers=0, progress=False)
    assert a[0].images.shape == (6, 32, 32, 3) and a[2].images.shape == (5, 32, 32, 3)
    # Same reference rotations for every object (the method relies on it).
    np.testing.assert_array_equal(a[0].rotations, a[1].rotations)
    assert not np.allclose(a[2].rotations[:5], a[0].rotations[:5])
    b = render_sets(specs, cache=tmp_path, workers=0, progress=False)  # from cache
    np.testing.assert_array_equal(a[2].images, b[2].images)
    # A different parameter gives a different cache entry.
    other = ViewSetSpec("duck", "reference", 6, 1, RC)
    assert other.key(manifest) != specs[0].key(manifest)


def test_interrupted_render_resumes_without_redoing_work(tmp_path, monkeypatch, manifest):
    monkeypatch.setattr(ds, "CHUNK", 3)
    spec = ViewSetSpec("mug", "query", 8, 2, RC, QueryStyle())
    full = render_sets([spec], cache=tmp_path / "full", workers=0, progress=False)[0]
    # Simulate a run killed after its first chunk.
    d = ds.set_dir(spec, manifest, tmp_path / "part")
    d.mkdir(parents=True)
    ds._render_chunk(spec, str(d), 0)
    (d / ".chunk_00001.npz.999.tmp").write_bytes(b"half-written")  # a torn write is ignored
    done_before = (d / "chunk_00000.npz").stat().st_mtime_ns
    calls = []
    real = ds._render_chunk
    monkeypatch.setattr(ds, "_render_chunk", lambda s, o, c: calls.append(c) or real(s, o, c))
    resumed = render_sets([spec], cache=tmp_path / "part", workers=0, progress=False, keep_chunks=True)[0]
    assert calls == [1, 2]
    assert (d / "chunk_00000.npz").stat().st_mtime_ns == done_before
    np.testing.assert_array_equal(full.images, resumed.images)
    np.testing.assert_array_equal(full.rotations, resumed.rotations)


def test_parallel_workers_equal_serial(tmp_path):
    spec = ViewSetSpec("cereal", "query", 4, 3, RC, QueryStyle())
    serial = render_sets([spec], cache=tmp_path / "a", workers=0, progress=False)[0]
    par = render_sets([spec], cache=tmp_path / "b", workers=2, progress=False)[0]
    np.testing.assert_array_equal(serial.images, par.images)


def test_bad_specs(tmp_path):
    with pytest.raises(ValueError, match="kind"):
        ViewSetSpec("duck", "photo", 3)
    with pytest.raises(ValueError, match="n must be"):
        ViewSetSpec("duck", "reference", 0)
    with pytest.raises(KeyError, match="not_an_object"):
        render_sets([ViewSetSpec("not_an_object", "reference", 2, 0, RC)], cache=tmp_path, workers=0)


def test_unusable_cache_dir_gives_clear_error(tmp_path):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file where a folder should be")
    with pytest.raises(OSError, match="cannot create render cache folder .*blocker"):
        render_sets([ViewSetSpec("duck", "reference", 2, 0, RC)], cache=blocker, workers=0)


def test_readonly_cache_dir_gives_clear_error(tmp_path):
    import os

    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("running as a user that ignores permissions")
        with pytest.raises(OSError, match="ro"):
            render_sets([ViewSetSpec("duck", "reference", 2, 0, RC)], cache=ro, workers=0)
    finally:
        os.chmod(ro, 0o700)
