"""Learning curves behind the quick preset's training recipe (issue: a recipe that learns in the quick budget).

Trains split #1's model on the default (`linemod`) benchmark under a few recipes and records, per epoch,
the training loss, seconds and the validation accuracy on held-out views of SEEN objects (never the unseen
test objects: the recipe is chosen on these curves only). Writes ``benchmarks/results/recipe_curves.json``.

    .venv/bin/python benchmarks/recipe_curves.py                 # every recipe (about 12 min each on 2 cores)
    .venv/bin/python benchmarks/recipe_curves.py --only cosine_1e-3

Runs are cached like the study's (``$HELPERS_CACHE_DIR``/runs): an interrupted run resumes, a finished
one is read back, so re-running only re-collects the curves.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

#: name -> TrainConfig overrides (every recipe: batch 16, 6 x 50 steps unless said otherwise).
RECIPES = {
    "cosine_3e-4": {"lr": 3e-4, "lr_schedule": "cosine", "warmup_steps": 20, "epochs": 8, "val_every": 1},
    "cosine_1e-3": {"lr": 1e-3, "lr_schedule": "cosine", "warmup_steps": 30},
    "cosine_1e-3_clean150": {"lr": 1e-3, "lr_schedule": "cosine", "warmup_steps": 30, "clean_steps": 150},
}
DATA = dict(n_references=512, n_train_queries=160, n_val_queries=24, n_test_queries=100)
VAL_REFS = 256


def run(name: str, overrides: dict) -> dict:
    from helpers.core.configs import AugmentConfig, DataConfig, ModelConfig, TrainConfig
    from helpers.study.pipeline import prepare_data, train_or_load

    data = prepare_data(DataConfig(**DATA))
    base = {"epochs": 6, "steps_per_epoch": 50, "batch_size": 16, "val_every": 2, "progress": True,
            "model": ModelConfig(image_size=64), "augment": AugmentConfig()}
    cfg = TrainConfig(**{**base, **overrides})
    _, run_dir, info = train_or_load(1, cfg, data, val_refs_per_object=VAL_REFS)
    hist = info["history"]["history"]
    return {"overrides": overrides, "run": Path(run_dir).name, "val_refs_per_object": VAL_REFS,
            "curve": [{"step": h["global_step"], "train_loss": h["train_loss"], "seconds": h["seconds"],
                       "val_class_acc": None if not h["val"] else 100 * h["val"]["class_acc"],
                       "val_rot_acc": None if not h["val"] else 100 * h["val"]["rot_acc"]} for h in hist]}


def collect(run_dir: Path) -> dict:
    """The curve of an existing run folder (``history.json`` and the config in ``last.pt``), finished or not."""
    import torch

    hist = json.loads((run_dir / "history.json").read_text())["history"]
    cfg = torch.load(run_dir / "last.pt", map_location="cpu", weights_only=True)["config"]
    keys = ("lr", "lr_schedule", "warmup_steps", "clean_steps", "epochs", "steps_per_epoch", "batch_size",
            "random_ref", "val_every")
    return {"config": {k: cfg.get(k) for k in keys}, "run": run_dir.name, "finished": (run_dir / "done.json").exists(),
            "curve": [{"step": h["global_step"], "train_loss": h["train_loss"], "seconds": h["seconds"],
                       "val_class_acc": None if not h["val"] else 100 * h["val"]["class_acc"],
                       "val_rot_acc": None if not h["val"] else 100 * h["val"]["rot_acc"]} for h in hist]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=sorted(RECIPES), help="recipes to run (default: all)")
    ap.add_argument("--collect", nargs="+", metavar="NAME=RUN_DIR",
                    help="read the curves of existing run folders instead of training")
    ap.add_argument("--note", default="", help="free text stored beside collected curves")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "recipe_curves.json"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    results = json.loads(out.read_text()) if out.exists() else {}
    if args.collect:
        for item in args.collect:
            name, _, path = item.partition("=")
            results[name] = {**collect(Path(path)), "note": args.note}
    else:
        for name in args.only or RECIPES:
            results[name] = run(name, RECIPES[name])
    from helpers.core.paths import portable_obj

    out.write_text(json.dumps(portable_obj(results), indent=1) + "\n")
    print(json.dumps({k: v["curve"][-1] for k, v in results.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
