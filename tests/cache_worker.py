"""One process building one kind of cache entry, for the concurrency and kill tests.

    python tests/cache_worker.py render|features|train|train-data CACHE_DIR

Prints ``ready`` once its imports are done (the tests time their kills from it), then builds
(or loads) the entry and prints ``result <digest>``: the sha256 of the entry's content (render
set: its three arrays; features: the .f16 file; training run: the weights of best.pt and
last.pt, which, unlike the checkpoint files, hold no wall-clock timings).
"""

from __future__ import annotations

import hashlib
import sys
from dataclasses import replace

import numpy as np
import torch

from helpers.core.configs import DataConfig, ModelConfig, RenderConfig, TrainConfig
from helpers.data.datasets import ViewSetSpec, render_sets
from helpers.data.manifest import load_manifest
from helpers.net.model import OrientationNet
from helpers.search.features import FeatureCache
from helpers.study.pipeline import prepare_data, train_or_load
from helpers.training.train import read_checkpoint

RC = RenderConfig(size=64, render_size=64)
SET = ViewSetSpec("duck", "reference", 300, 0, RC)  # 3 chunks
DATA = DataConfig(image_size=64, render_size=64, n_references=8, n_train_queries=4, n_val_queries=2,
                  n_test_queries=1, workers=0)
TRAIN = TrainConfig(epochs=4, steps_per_epoch=3, batch_size=2, lr=1e-3, warmup_steps=1, clean_steps=1,
                    val_every=1, seed=0, precision="fp32", progress=False, device="cpu",
                    model=ModelConfig(image_size=64))


def _digest(arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def build(kind: str, cache: str) -> str:
    """Build (or load) the entry of ``kind`` in cache root ``cache``; its content digest."""
    if kind == "render":
        v = render_sets([SET], cache=cache, workers=0, progress=False)[0]
        return _digest([v.images, v.masks, v.rotations])
    if kind == "features":
        v = render_sets([SET], cache=cache, workers=0, progress=False)[0]
        torch.manual_seed(0)
        model = OrientationNet(ModelConfig(image_size=64)).eval()
        f = FeatureCache(f"{cache}/features").get_or_build(model, "tiny", v, "duck-300", batch=4, progress=False)
        return _digest([f])
    if kind in ("train", "train-data"):
        data = prepare_data(replace(DATA, cache_dir=cache), objects=load_manifest().seen_objects(1),
                            occluded=False, test=False)
        if kind == "train-data":
            return _digest([data.refs[n].images for n in sorted(data.refs)])
        _, run, _ = train_or_load(1, TRAIN, data, val_refs_per_object=6)
        return _digest([t.numpy() for f in ("best.pt", "last.pt")
                        for _, t in sorted(read_checkpoint(run / f)["model"].items())])
    raise SystemExit(f"unknown kind {kind!r}: expected render, features, train or train-data")


def _report_builds() -> None:
    """Print "building" whenever this process does the work of an entry (not when it loads one)."""
    import helpers.data.datasets as ds
    import helpers.search.features as ft
    import helpers.study.pipeline as st

    def wrap(owner, name):
        inner = getattr(owner, name)

        def f(*a, **k):
            print("building", flush=True)
            return inner(*a, **k)

        setattr(owner, name, f)

    wrap(ds, "_render_chunks")
    wrap(ft.FeatureCache, "_build")
    wrap(st, "_train_run")


def main() -> None:
    torch.set_num_threads(1)  # same arithmetic in every process: results comparable byte for byte
    kind, cache = sys.argv[1], sys.argv[2]
    _report_builds()
    print("ready", flush=True)
    print("result", build(kind, cache), flush=True)


if __name__ == "__main__":
    main()
