"""The model zoo: trained weights committed under ``models/`` with their provenance.

Recipes live in ``presets/long/zoo.yaml`` (shared data and training settings, per-model
overrides). Training a recipe goes through :func:`helpers.study.train_or_load`, so it uses the
same content-hashed run folder (``<cache>/runs/...``) as notebook 02 and resumes after an
interruption; a run that did not finish in one session resumes from the checkpoint committed
under ``models/checkpoints/`` by :func:`snapshot`. :func:`publish` writes ``models/<name>.pt``
(float16 weights), ``models/<name>.history.json``, ``models/<name>.check.npz`` (a few seen-object
validation views, references and their scores, for the reproduction test) and the model's entry
in ``models/zoo.yaml``. :func:`load` checks the sha256 before it loads.
"""

from __future__ import annotations

import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from .fileio import atomic_write_bytes, atomic_write_text, read_json, sha256_file
from .model import ModelConfig, OrientationNet
from .paths import REPO_ROOT
from .study import DataConfig, prepare_data, run_folder, train_or_load
from .train import TrainConfig

ZOO_DIR = REPO_ROOT / "models"
RECIPES = REPO_ROOT / "presets" / "long" / "zoo.yaml"
#: Views per seen object kept in ``<name>.check.npz``: queries and references.
CHECK_QUERIES, CHECK_REFS = 2, 12


@dataclass(frozen=True)
class Recipe:
    """How one zoo model is trained: its data, training configuration and split (0 = all objects)."""

    name: str
    split: int
    data: DataConfig
    train: TrainConfig
    val_refs: int


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out.get(k, {}), v) if isinstance(v, dict) else v
    return out


def recipes(path: str | Path = RECIPES, cache_dir: str = "", device: str = "auto") -> dict[str, Recipe]:
    """Every recipe of ``path`` by name (ValueError naming the file and model on a bad entry)."""
    spec = yaml.safe_load(Path(path).read_text())
    out = {}
    for name, over in (spec.get("models") or {}).items():
        try:
            over = dict(over or {})
            split = int(over.pop("split"))
            if split not in (0, 1, 2, 3):
                raise ValueError(f"split: expected 0 (all objects), 1, 2 or 3, got {split}")
            data = DataConfig(**{**spec["data"], **over.pop("data", {}), "cache_dir": cache_dir})
            model = ModelConfig.from_dict(_merge({"image_size": data.image_size}, over.pop("model", {})))
            train = _merge(spec["train"], over.pop("train", {}))
            if over:
                raise ValueError(f"unknown keys {sorted(over)}")
            tcfg = TrainConfig.from_dict({**train, "model": model.to_dict(), "device": device})
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{path}: model {name!r}: {e}") from None
        out[name] = Recipe(name, split, data, tcfg, int(spec.get("val_refs", 256)))
    return out


def recipe(name: str, **kw: Any) -> Recipe:
    rs = recipes(**kw)
    if name not in rs:
        raise ValueError(f"zoo: no recipe {name!r} in {RECIPES}; known: {sorted(rs)}")
    return rs[name]


# ----------------------------------------------------------------------------- training

def _checkpoint_path(name: str, zoo_dir: Path = ZOO_DIR) -> Path:
    return zoo_dir / "checkpoints" / f"{name}.last.pt"


def train_recipe(r: Recipe, zoo_dir: Path = ZOO_DIR) -> tuple[OrientationNet, Path, dict, Any]:
    """Train (or resume, or load the finished run of) recipe ``r``; returns
    (model, run folder, info of :func:`train_or_load`, StudyData)."""
    from .runinfo import git_revision

    from .manifest import load_manifest

    data = prepare_data(r.data, objects=load_manifest().seen_objects(r.split), occluded=False, test=False)
    run = run_folder(r.split, r.train, data, r.val_refs)
    committed = _checkpoint_path(r.name, zoo_dir)
    if not (run / "last.pt").exists() and committed.exists():  # resume from the committed checkpoint
        run.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(committed, run / "last.pt")
    prov = run / "provenance.json"
    if not prov.exists():
        run.mkdir(parents=True, exist_ok=True)
        from .fileio import atomic_write_json

        atomic_write_json(prov, {"git": git_revision(), "recipe": r.name})
    model, run, info = train_or_load(r.split, r.train, data, val_refs_per_object=r.val_refs)
    return model, run, info, data


# ----------------------------------------------------------------------------- command line

def main(argv: list[str] | None = None) -> int:
    """``python -m helpers.zoo train NAME [NAME ...] [--publish]`` | ``snapshot NAME`` | ``list`` | ``verify``."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m helpers.zoo", description=main.__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train", help="train (or resume) zoo recipes; --publish writes models/<name>.*")
    t.add_argument("names", nargs="+")
    t.add_argument("--publish", action="store_true")
    t.add_argument("--device", default="auto")
    s = sub.add_parser("snapshot", help="commit-ready copy of an unfinished run's last.pt")
    s.add_argument("names", nargs="+")
    sub.add_parser("list", help="the zoo's models and their validation numbers")
    sub.add_parser("verify", help="check every committed model file against its sha256")
    a = ap.parse_args(argv)
    if a.cmd == "train":
        for name in a.names:
            r = recipe(name, device=a.device)
            model, run, info, data = train_recipe(r)
            print(f"{name}: trained in {run}")
            if a.publish:
                print(f"{name}: published {publish(r, run, data)}")
    elif a.cmd == "snapshot":
        for name in a.names:
            print(snapshot(recipe(name)))
    elif a.cmd == "list":
        for name, e in entries().items():
            print(f"{name:14s} split {e['split']} steps {e['steps']} val {e['val']}")
    elif a.cmd == "verify":
        bad = verify()
        for b in bad:
            print(b)
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
