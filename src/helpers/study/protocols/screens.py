"""Training-regime screens: zoo models trained with one change of the recipe against the current recipe.

Each arm is a list of zoo models (one per training seed) trained from a recipe of ``presets/long/zoo.yaml``
that changes one thing of the current recipe (its ``baseline`` models, same split, same steps). The screens
are decided on held-out views of the split's SEEN objects, rendered here with their own seed
(:data:`SCREEN_SEED_OFFSET`) and never used in training or model selection; the split's unseen test accuracy is
reported afterwards and never used to choose.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from ...core.configs import LATER_DEFAULTS, ExtraConfig
from ...core.views import ObjectViews
from ...data.datasets import ViewSetSpec, render_sets
from ...data.render import query_style
from ...evaluation.stats import claim, seed_spread
from ..pipeline import StudyData
from .variants import Trained, per_query, seed_accuracies
from ..zoo import named_model

#: The screening views' seed is the data seed plus this (validation +1, test +2, occluded +3 are taken).
SCREEN_SEED_OFFSET = 5
#: The label of the current recipe's models.
CURRENT = "current"
#: Recipe fields that are bookkeeping, not part of what an arm changes.
_BOOKKEEPING = {"seed", "device", "progress", "num_threads", "val_batch_size", "precision", "val_every"}


def screen_models(baseline: list[str], arms: list[list[str]], split: int, image_size: int,
                  device: str = "auto") -> dict[str, list[Trained]]:
    """label -> the zoo models of each seed: :data:`CURRENT` for ``baseline``, then each ``[label, model, ...]``
    of ``arms``. ValueError when a model is trained on another split or for another number of steps."""
    out: dict[str, list[Trained]] = {}
    for label, names in [(CURRENT, baseline)] + [(a[0], a[1:]) for a in arms]:
        out[label] = []
        for name in names:
            model, path, info = named_model(name, image_size, device)
            out[label].append(Trained(model, path, {"seed": info["zoo_entry"]["train"]["seed"], **info}))
    for label, ts in out.items():
        for t in ts:
            if t.info["split"] != split:
                raise ValueError(f"arms: {label}'s zoo model {t.info['zoo']} is trained on split {t.info['split']}, "
                                 f"the screens compare split {split}'s models")
    steps = {t.info["zoo"]: int(t.info["zoo_entry"]["steps"]) for ts in out.values() for t in ts}
    if len(set(steps.values())) > 1:
        raise ValueError(f"arms: a screen compares equal budgets, got steps {steps}")
    return out


def changes(trained: dict[str, list[Trained]]) -> dict[str, str]:
    """label -> what its recipe changes from the current one ("symmetry_aware: False -> True"), read from the zoo
    entries' data and training configurations (the first seed of each)."""
    def flat(e: dict) -> dict[str, Any]:
        d = {f"data.{k}": v for k, v in e["data"].items() if k != "seed"}
        # extra objects (entries without the key have none): every field shown at its default unless it changed
        d.update({f"extra.{k}": v for k, v in {**asdict(ExtraConfig()), **(e.get("extra") or {})}.items()
                  if k not in ("objects_file", "objects_sha256")})
        for k, v in e["train"].items():
            if k in _BOOKKEEPING:
                continue
            if isinstance(v, dict):
                d.update({f"{k}.{kk}": vv for kk, vv in v.items()})
            else:
                d[k] = v
        return {**LATER_DEFAULTS, **d}  # entries written before a field existed were trained at its default

    base = flat(trained[CURRENT][0].info["zoo_entry"])
    out = {}
    for label, ts in trained.items():
        mine = flat(ts[0].info["zoo_entry"])
        diff = [f"{k}: {base.get(k)} -> {mine.get(k)}" for k in sorted(set(base) | set(mine))
                if base.get(k) != mine.get(k)]
        out[label] = "; ".join(diff) if diff else ("the current recipe" if label == CURRENT else "no change")
    return out


def screening_views(data: StudyData, objects: list[str], n: int,
                    offset: int = SCREEN_SEED_OFFSET) -> dict[str, ObjectViews]:
    """``n`` held-out real-like views of each of ``objects`` (training backgrounds, the benchmark's query style),
    rendered (or loaded from the cache) with seed ``data.cfg.seed + offset``: views no model trained or was
    selected on."""
    cfg = data.cfg
    style = query_style(cfg.query_style)
    specs = [ViewSetSpec(o, "query", n, cfg.seed + offset, cfg.render_config(), style, "train") for o in objects]
    sets = render_sets(specs, cache=cfg.cache_dir or None, workers=cfg.workers, manifest=data.manifest)
    return dict(zip(objects, sets))


def screen_trend(results: dict[str, list[dict]]) -> dict[str, dict]:
    """``<arm>_beats_current`` -> the paired claim of each arm against :data:`CURRENT` (seeds matched, the verdict
    with the largest seed-to-seed range of any label: :func:`helpers.evaluation.stats.claim`)."""
    pq = per_query(results)
    spread = seed_spread(seed_accuracies(results))
    return {f"{label}_beats_{CURRENT}": claim(pq, CURRENT, label, spread) for label in results if label != CURRENT}
