"""Views of the extra objects (issue #44, screen e; :mod:`helpers.data.extra_objects`): what a recipe with extra
training objects trains on, and the extra meshes kept out of training that decide whether they pay."""

from __future__ import annotations

from dataclasses import replace

from ..core.configs import ExtraConfig
from ..core.views import ObjectViews
from ..data.datasets import ViewSetSpec, render_sets
from ..data.extra_objects import ExtraObjects, load_extras, with_extras
from ..data.render import query_style
from .pipeline import StudyData

#: Seed offset of the validation extras' query views (the benchmark's screening views use +5; the references keep
#: the data seed, so every object's references share their rotations).
VALIDATION_SEED_OFFSET = 6


def add_extra_objects(data: StudyData, extra: ExtraConfig, extras: ExtraObjects | None = None) -> StudyData:
    """``data`` with the first ``extra.n`` training extras added (a copy; ``extra.n == 0``: ``data`` itself): their
    references, real-like training queries (the benchmark's style and context, training photos) and clean views
    for the curriculum, rendered (or loaded from the cache). They are training objects only: no validation or
    test views (:meth:`StudyData.training_objects`)."""
    if extra.n == 0:
        return data
    extras = extras or load_extras(manifest=data.manifest)
    names = extras.first(extra.n)
    m = with_extras(data.manifest, extras, names)
    cfg, rc = data.cfg, data.cfg.render_config()
    style = query_style(cfg.query_style, context=cfg.train_context)
    plan = []
    for n in names:
        plan += [("refs", n, ViewSetSpec(n, "reference", extra.n_references, cfg.seed, rc)),
                 ("train_q", n, ViewSetSpec(n, "query", extra.n_train_queries, cfg.seed, rc, style, "train")),
                 ("clean_q", n, ViewSetSpec(n, "reference", extra.n_train_queries, cfg.seed + 1000, rc))]
    sets = render_sets([p[2] for p in plan], cache=cfg.cache_dir or None, workers=cfg.workers, manifest=m)
    out = replace(data, manifest=m, refs=dict(data.refs), train_q=dict(data.train_q), clean_q=dict(data.clean_q),
                  extra=list(names))
    for (kind, n, _), vs in zip(plan, sets):
        getattr(out, kind)[n] = vs
    return out


def validation_extras(data: StudyData, n_objects: int, n_references: int, n_queries: int,
                      extras: ExtraObjects | None = None) -> tuple[StudyData, dict[str, ObjectViews]]:
    """The unseen-object validation set of the extras screen: the first ``n_objects`` validation extras (never
    trained on), each with ``n_references`` references and ``n_queries`` real-like views (the benchmark's query
    style, TRAINING photos: test photos stay the test's) at seed ``data.cfg.seed +`` :data:`VALIDATION_SEED_OFFSET`.

    Returns (a StudyData whose manifest declares them, with their references; name -> query views)."""
    extras = extras or load_extras(manifest=data.manifest)
    if not 1 <= n_objects <= len(extras.validation):
        raise ValueError(f"n_objects: expected 1..{len(extras.validation)} (validation extras in {extras.path}), "
                         f"got {n_objects}")
    names = list(extras.validation[:n_objects])
    m = with_extras(data.manifest, extras, names)
    cfg, rc = data.cfg, data.cfg.render_config()
    seed = cfg.seed + VALIDATION_SEED_OFFSET
    specs = [ViewSetSpec(n, "reference", n_references, cfg.seed, rc) for n in names]
    specs += [ViewSetSpec(n, "query", n_queries, seed, rc, query_style(cfg.query_style), "train") for n in names]
    sets = render_sets(specs, cache=cfg.cache_dir or None, workers=cfg.workers, manifest=m)
    val = StudyData(cfg, m, refs=dict(zip(names, sets[:len(names)])))
    return val, dict(zip(names, sets[len(names):]))
