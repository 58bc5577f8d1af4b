"""Training-regime screens: zoo models trained with one change of the recipe against the current recipe.

Each arm is a list of zoo models (one per training seed) trained from a recipe of ``presets/long/zoo.yaml``
that changes one thing of the current recipe (its ``baseline`` models, same split, same steps). The screens
are decided on held-out views of the split's SEEN objects, rendered here with their own seed
(:data:`SCREEN_SEED_OFFSET`) and never used in training or model selection; the split's unseen test accuracy is
reported afterwards and never used to choose.
"""

from __future__ import annotations

from dataclasses import asdict, replace
from typing import Any

import numpy as np

from ...core.configs import LATER_DEFAULTS, ExtraConfig
from ...core.views import ObjectViews
from ...data.datasets import ViewSetSpec, render_sets
from ...data.render import query_style
from ...evaluation.stats import claim, seed_spread
from ..pipeline import StudyData, prepare_data
from .variants import Trained, evaluate_queries, per_query, seed_accuracies
from ..zoo import entry, named_model

#: The screening views' seed is the data seed plus this (validation +1, test +2, occluded +3 are taken).
SCREEN_SEED_OFFSET = 5
#: The label of the current recipe's models.
CURRENT = "current"
#: Recipe fields that are bookkeeping, not part of what an arm changes.
_BOOKKEEPING = {"seed", "device", "progress", "num_threads", "val_batch_size", "precision", "val_every"}


def screen_models(baseline: list[str], arms: list[list[str]], split: int,
                  device: str = "auto") -> dict[str, list[Trained]]:
    """label -> the zoo models of each seed: :data:`CURRENT` for ``baseline``, then each ``[label, model, ...]``
    of ``arms``, each at the input side it was trained at (screen c compares sides: :func:`model_sizes`).
    ValueError when a model is trained on another split or for another number of steps, or when one arm's seeds
    differ in input side."""
    out: dict[str, list[Trained]] = {}
    for label, names in [(CURRENT, baseline)] + [(a[0], a[1:]) for a in arms]:
        out[label] = []
        for name in names:
            model, path, info = named_model(name, int(entry(name)["data"]["image_size"]), device)
            out[label].append(Trained(model, path, {"seed": info["zoo_entry"]["train"]["seed"], **info}))
    for label, ts in out.items():
        for t in ts:
            if t.info["split"] != split:
                raise ValueError(f"arms: {label}'s zoo model {t.info['zoo']} is trained on split {t.info['split']}, "
                                 f"the screens compare split {split}'s models")
    steps = {t.info["zoo"]: int(t.info["zoo_entry"]["steps"]) for ts in out.values() for t in ts}
    if len(set(steps.values())) > 1:
        raise ValueError(f"arms: a screen compares equal budgets, got steps {steps}")
    model_sizes(out)
    return out


def model_sizes(trained: dict[str, list[Trained]]) -> dict[str, int]:
    """label -> the input side (px) of its models. ValueError when the seeds of one label differ."""
    out = {}
    for label, ts in trained.items():
        sides = {int(t.info["zoo_entry"]["data"]["image_size"]) for t in ts}
        if len(sides) != 1:
            raise ValueError(f"arms: {label}'s models take different input sides {sorted(sides)} px; "
                             f"one arm is one recipe")
        out[label] = sides.pop()
    return out


def render_sides(trained: dict[str, list[Trained]]) -> dict[int, int]:
    """input side (px) -> the internal render side (px) its models' recipes rendered their views at. ValueError
    when two models of one input side were trained on views of different render sides."""
    out: dict[int, int] = {}
    for label, ts in trained.items():
        for t in ts:
            d = t.info["zoo_entry"]["data"]
            side, render = int(d["image_size"]), int(d["render_size"])
            if out.setdefault(side, render) != render:
                raise ValueError(f"arms: {t.info['zoo']} ({label}) renders {side} px crops from {render} px, another "
                                 f"model of that side from {out[side]} px; one side, one set of views")
    return out


def data_at_sizes(data: StudyData, sides: dict[int, int], objects: list[str] | None = None,
                  test: bool = True) -> dict[int, StudyData]:
    """input side (px) -> the study's data at that side: ``data`` itself at its own side; at another side ``s``
    the SAME views (rotations, scenes and every random draw: each view has its own generator, seeded by the view)
    rendered at ``s`` from ``sides[s]`` px internal renders (:func:`render_sides`: as the models of that side were
    trained), references and (``test``) test queries of ``objects`` only (default: the benchmark's objects;
    ``test=False`` where no test query is scored, as a screen without its afterwards part). A model is scored at
    the side it was trained at, on the views every other model sees. Rendered benchmark only."""
    cfg = data.cfg
    if data.seen_test_q and set(sides) - {cfg.image_size}:
        raise ValueError(f"sides {sorted(sides)} px: real photographs are cropped at {cfg.image_size} px only; "
                         f"scoring a model at another side needs the rendered benchmark")
    objects = objects or data.manifest.object_names("train")
    out = {cfg.image_size: data}
    for s, render in sorted(sides.items()):
        if s != cfg.image_size:
            c = replace(cfg, image_size=int(s), render_size=int(render))
            out[s] = prepare_data(c, objects, occluded=False, manifest=data.manifest, training=False, test=test)
    return dict(sorted(out.items()))


def evaluate_at_sizes(trained: dict[str, list[Trained]], datas: dict[int, StudyData],
                      queries: dict[int, dict[str, ObjectViews]], bench: list[str],
                      device: str = "auto") -> dict[str, list[dict]]:
    """:func:`helpers.study.protocols.variants.evaluate_queries` of every label at its models' side, among the
    references of ``bench`` in ``datas[side]``, on ``queries[side]`` (object -> views). ValueError when the
    views of two sides differ in number or rotation: the comparison is paired only over the same views."""
    sides = sorted(queries)
    for s in sides[1:]:
        for n, v in queries[sides[0]].items():
            w = queries[s].get(n)
            if w is None or len(w) != len(v) or not np.allclose(w.rotations, v.rotations, atol=1e-5):
                raise ValueError(f"views of {n!r} at {s} px are not those at {sides[0]} px; "
                                 f"a paired screen needs the same views at every side")
    out: dict[str, list[dict]] = {}
    for label, side in model_sizes(trained).items():
        out.update(evaluate_queries({label: trained[label]}, datas[side], queries[side], bench, device=device))
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
