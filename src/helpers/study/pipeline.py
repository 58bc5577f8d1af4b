"""The study's shared plumbing: data of a preset, train-or-load, evaluate.

Every notebook goes through here so the same preset parameters always give
the same rendered sets, the same trained models (content-hashed run folders
under ``<cache>/runs``) and the same cached reference features.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.configs import LATER_DEFAULTS, DataConfig, SearchConfig
from ..core.device import resolve_device
from ..core.fileio import DamagedEntry, atomic_write_json, check_sha256, read_json, sha256_file, stable_hash, touch
from ..core.locks import entry_lock, made_by, settle
from ..core.paths import cache_dir
from ..core.views import ObjectViews
from ..data.datasets import ViewSetSpec, render_sets
from ..data.gl import gl_platform
from ..data.linemod_bop import LMO_OBJECT_IDS, bop_manifest, object_id, partition_views
from ..data.linemod_real import bop_folders, real_views, spread
from ..data.manifest import Manifest, load_manifest
from ..data.render import query_style
from ..evaluation.metrics import Record, per_query_table, summarise_queries
from ..search.features import FeatureCache, encode_batch, encode_views, model_fingerprint
from ..search.fps import farthest_point_sampling
from ..search.retrieval import ReferenceBank, model_scorer, search_all
from ..training.distributed import distributed_world
from ..training.train import load_model, train


@dataclass
class StudyData:
    """All view sets of a preset, by object name."""

    cfg: DataConfig
    manifest: Manifest
    refs: dict[str, ObjectViews] = field(default_factory=dict)
    train_q: dict[str, ObjectViews] = field(default_factory=dict)
    val_q: dict[str, ObjectViews] = field(default_factory=dict)
    test_q: dict[str, ObjectViews] = field(default_factory=dict)
    occluded_q: dict[str, ObjectViews] = field(default_factory=dict)
    clean_q: dict[str, ObjectViews] = field(default_factory=dict)
    #: Real data only: a SEEN object's test views (its every tenth view), where ``test_q`` holds all its views
    #: (what it is tested on where it is unseen). Rendered benchmark: empty, ``test_q`` serves both.
    seen_test_q: dict[str, ObjectViews] = field(default_factory=dict)
    #: Extra training objects (issue #44, screen e; :func:`helpers.study.extra_data.add_extra_objects`): trained on
    #: beside the split's seen objects, never validated or tested on. Empty: none.
    extra: list[str] = field(default_factory=list)

    def key(self, name: str, kind: str = "refs") -> str:
        return getattr(self, kind)[name].meta["key"]

    def seen_test(self, name: str) -> ObjectViews:
        """The test views of ``name`` where a model trained on it is tested (see :attr:`seen_test_q`)."""
        return self.seen_test_q.get(name, self.test_q[name])

    def training_objects(self, split: int) -> list[str]:
        """What a model of ``split`` trains on: the split's seen benchmark objects, then the extra objects."""
        return self.manifest.seen_objects(split) + list(self.extra)


def prepare_data(cfg: DataConfig, objects: list[str] | None = None, occluded: bool = True,
                 manifest: Manifest | None = None, test: bool = True, bop_root: str = "",
                 training: bool = True) -> StudyData:
    """Render (or load) references and queries of ``objects`` (default: all).

    ``test=False`` skips the test and occluded queries (what training alone needs); ``training=False`` skips the
    training, validation and clean views (what evaluating a trained model alone needs; rendered benchmark only).
    ``bop_root``: real LineMOD and LineMOD-O instead of the rendered benchmark (:func:`prepare_real_data`).

    Training and validation queries are rendered only for benchmark (``train``
    role) objects; test and occluded queries use the test background photos.
    """
    if bop_root:
        if not training:
            raise ValueError("prepare_data(training=False): the rendered benchmark only (real data are split "
                             "into training and test views together)")
        return prepare_real_data(cfg, bop_root, objects, occluded, test)
    m = manifest or load_manifest()
    names = objects or m.object_names()
    bench = set(m.object_names("train"))
    rc = cfg.render_config()
    plain = query_style(cfg.query_style)
    train = query_style(cfg.query_style, context=cfg.train_context)
    occ = query_style(cfg.query_style, occlusion=1.0, occlusion_fraction=tuple(cfg.occlusion_fraction))
    plan: list[tuple[str, str, ViewSetSpec]] = []
    for n in names:
        plan.append(("refs", n, ViewSetSpec(n, "reference", cfg.n_references, cfg.seed, rc)))
        if n in bench and training:
            plan.append(("train_q", n, ViewSetSpec(n, "query", cfg.n_train_queries, cfg.seed, rc, train, "train")))
            plan.append(("val_q", n, ViewSetSpec(n, "query", cfg.n_val_queries, cfg.seed + 1, rc, plain, "train")))
            # Clean (reference-style) views at other rotations, for the clean-to-real-like curriculum.
            plan.append(("clean_q", n, ViewSetSpec(n, "reference", cfg.n_train_queries, cfg.seed + 1000, rc)))
        if not test:
            continue
        plan.append(("test_q", n, ViewSetSpec(n, "query", cfg.n_test_queries, cfg.seed + 2, rc, plain, "test")))
        if occluded:
            plan.append(("occluded_q", n, ViewSetSpec(n, "query", cfg.n_test_queries, cfg.seed + 3, rc, occ, "test")))
    sets = render_sets([p[2] for p in plan], cache=cfg.cache_dir or None, workers=cfg.workers, manifest=m)
    data = StudyData(cfg, m)
    for (kind, n, _), vs in zip(plan, sets):
        getattr(data, kind)[n] = vs
    return data


def study_manifest(bop_root: str = "") -> Manifest:
    """The objects a study runs on: the rendered benchmark's manifest, or (``bop_root``) real LineMOD's 13 objects
    with the symmetries its ``models_info.json`` declares (:func:`helpers.data.linemod_bop.bop_manifest`)."""
    return bop_manifest(bop_folders(bop_root)["lm"], "lm") if bop_root else load_manifest()


def prepare_real_data(cfg: DataConfig, bop_root: str, objects: list[str] | None = None, occluded: bool = True,
                      test: bool = True) -> StudyData:
    """The paper's real data: LineMOD (``<bop_root>/lm``) and LineMOD-O (``<bop_root>/lmo``) in BOP format.

    Objects, splits and symmetries: :func:`helpers.data.linemod_bop.bop_manifest` (the 13 objects, role
    ``train``, no held-out objects). References: ``cfg.n_references`` renders of each object's mesh, as for the
    rendered benchmark (the clean views of the curriculum too). Queries: real crops (:mod:`helpers.data.linemod_real`),
    one object's views separated by :func:`helpers.data.linemod_bop.partition_views`: ``test_q`` = ALL views
    (an unseen object is tested on all of them), ``seen_test_q`` = every tenth view (the paper's 10 % seen test
    split), ``val_q`` = ``cfg.n_val_queries`` others (model selection), ``train_q`` = the rest, with context.
    ``n_train_queries`` and ``n_test_queries`` cap the training and test views per object (spread evenly over
    the sorted views); ``occluded_q``: LineMOD-O's views of its eight objects (capped like the test views; none
    without ``<bop_root>/lmo``).
    """
    folders = bop_folders(bop_root)
    m = bop_manifest(folders["lm"], "lm")
    names = objects or m.object_names()
    rc = cfg.render_config()
    plan = [("refs", n, ViewSetSpec(n, "reference", cfg.n_references, cfg.seed, rc)) for n in names]
    plan += [("clean_q", n, ViewSetSpec(n, "reference", cfg.n_train_queries, cfg.seed + 1000, rc)) for n in names]
    sets = render_sets([p[2] for p in plan], cache=cfg.cache_dir or None, workers=cfg.workers, manifest=m)
    data = StudyData(cfg, m)
    for (kind, n, _), vs in zip(plan, sets):
        getattr(data, kind)[n] = vs
    cache = cfg.cache_dir or None
    for n in names:
        views = real_views(folders["lm"], "lm", n, cfg.image_size, 1.0, cache)
        part = partition_views(len(views), cfg.n_val_queries)
        wide = real_views(folders["lm"], "lm", n, cfg.image_size, cfg.train_context, cache)
        data.train_q[n] = _views_at(wide, part["train"][spread(len(part["train"]), cfg.n_train_queries)])
        data.val_q[n] = _views_at(views, part["val"])
        if test:
            data.test_q[n] = _views_at(views, spread(len(views), cfg.n_test_queries))
            data.seen_test_q[n] = _views_at(views, part["test"][spread(len(part["test"]), cfg.n_test_queries)])
        if test and occluded and "lmo" in folders and object_id(n) in LMO_OBJECT_IDS:
            occ = real_views(folders["lmo"], "lmo", n, cfg.image_size, 1.0, cache)
            data.occluded_q[n] = _views_at(occ, spread(len(occ), cfg.n_test_queries))
    return data


def _views_at(views: ObjectViews, idx: np.ndarray) -> ObjectViews:
    """``views.subset(idx)`` keyed by the selection too (training run folders hash the keys of their sets)."""
    out = views.subset(idx)
    out.meta["key"] = f"{views.meta['key']}-{stable_hash([int(i) for i in idx], 8)}"
    out.meta["instances"] = [views.meta["instances"][int(i)] for i in idx]
    return out


def first(views: ObjectViews, k: int) -> ObjectViews:
    """The first ``k`` views (0 = all): a smaller, still random, sample of a rendered query set. Real views come
    sorted by scene and image (neighbours nearly alike), so ``k`` of them are taken spread evenly instead."""
    if not k or k >= len(views):
        return views
    return _views_at(views, spread(len(views), k)) if views.meta.get("sorted_views") else views.subset(np.arange(k))


def cap_test_queries(data: StudyData, k: int) -> StudyData:
    """``data`` with only the first ``k`` test queries per object (0: all; real data: of the seen objects' test
    views too); the other sets are shared. The first k of a rendered set are themselves a random sample (rotations and
    backgrounds are drawn independently per query), so a notebook can evaluate fewer queries
    than notebook 01 rendered for the ablations."""
    if not k:
        return data
    return replace(data, test_q={n: first(v, k) for n, v in data.test_q.items()},
                   seen_test_q={n: first(v, k) for n, v in data.seen_test_q.items()})


# ------------------------------------------------------------------ training

def val_refs_subset(refs: ObjectViews, n: int) -> ObjectViews:
    """A spread-out subset of references for cheap validation retrieval."""
    if len(refs) <= n:
        return refs
    return refs.subset(np.sort(farthest_point_sampling(refs.rotations.astype(np.float64), n)))


def train_or_load(split: int, train_cfg: Any, data: StudyData, val_refs_per_object: int = 256
                  ) -> tuple[torch.nn.Module, Path, dict]:
    """Train on the seen objects of LineMOD-like ``split``, or load the finished run.

    The run folder ``<cache>/runs/<hash>`` is keyed by the model and training
    configs, the split and the render keys of every set used, so a finished
    run is reused by any notebook that asks for the same thing, and an
    interrupted one resumes from its last checkpoint. One process trains a run at
    a time (its lock); another that asks for it waits and then loads it. A finished
    run's ``done.json`` records the sha256 of ``best.pt`` and ``last.pt``, checked here.

    Returns:
        (model in eval mode on its device, run folder, history dict).

    Raises:
        DamagedEntry: a checkpoint of the finished run does not match its checksum
            (the message names the file and how to recover).
    """
    seen = data.training_objects(split)
    missing = [n for n in seen if n not in data.train_q]
    if missing:
        raise ValueError(f"train_or_load: no training queries rendered for {missing}; prepare_data with them")
    run = run_folder(split, train_cfg, data, val_refs_per_object)
    rank, world = distributed_world()
    if world > 1:
        _train_run_together(split, train_cfg, data, val_refs_per_object, run, seen, rank, world)
    elif not _finished_run(run):
        with run_lock(run):
            if not _finished_run(run):  # another process may have finished it while we waited
                _train_run(split, train_cfg, data, val_refs_per_object, run, seen, world)
    settle(run)
    info = check_run(run)
    touch(run / "done.json")  # its modification time is the run's last use
    model, _ = load_model(run / "best.pt", device=getattr(train_cfg, "device", "auto"))
    model.eval()
    history = read_json(run / "history.json") if (run / "history.json").exists() else {}
    return model, run, {"history": history, **info}


def run_lock(run: Path):
    """The lock of training run folder ``run`` (one process trains it at a time)."""
    return entry_lock(run, f"training run {run.name}")


def _finished_run(run: Path) -> bool:
    return (run / "done.json").exists()


def check_run(run: Path, backfill: bool = True) -> dict:
    """done.json of finished run ``run`` after checking best.pt and last.pt against its sha256
    sums. A run finished before checksums were recorded gets them now (``backfill``) or is
    not checked."""
    done = run / "done.json"
    info = read_json(done)
    if "sha256" not in info:
        if not backfill:
            return info
        try:
            with run_lock(run):
                info = read_json(done)
                info.setdefault("sha256", {f: sha256_file(run / f) for f in ("best.pt", "last.pt")})
                atomic_write_json(done, info)
        except OSError:
            return info  # a read-only cache: the run stays unchecked
    sums = info["sha256"]
    if not isinstance(sums, dict):
        raise DamagedEntry(f"{done}: malformed checksums; delete {run} (the next run retrains it)")
    for f in ("best.pt", "last.pt"):
        check_sha256(run / f, sums.get(f, ""), done,
                     f"remove the run with `python -m helpers.study.cli.cache prune` (or delete {run}); the next run retrains it")
    return info


def _train_run_together(split: int, train_cfg: Any, data: StudyData, val_refs_per_object: int, run: Path,
                        seen: list[str], rank: int, world: int) -> None:
    """Data-parallel: process 0 takes the run's lock and decides whether it still needs training;
    every process learns that decision from it, so all of them train (or skip) together. (If
    another job holds the lock for longer than the process group's collective timeout, the other
    ranks' wait in the broadcast fails: do not launch a data-parallel run of a run in training.)"""
    import torch.distributed as dist

    decision = [None]
    if rank > 0:
        dist.broadcast_object_list(decision, src=0)
        if decision[0]:
            _train_run(split, train_cfg, data, val_refs_per_object, run, seen, world)
        return
    with run_lock(run):  # held until every process has passed the final barrier of _train_run
        decision[0] = not _finished_run(run)
        dist.broadcast_object_list(decision, src=0)
        if decision[0]:
            _train_run(split, train_cfg, data, val_refs_per_object, run, seen, world)


def _train_run(split: int, train_cfg: Any, data: StudyData, val_refs_per_object: int, run: Path,
               seen: list[str], world: int) -> None:
    curriculum = bool(getattr(train_cfg, "clean_steps", 0))
    if distributed_world()[0] == 0:
        for stray in run.glob(".*.tmp"):  # a killed writer's (this process holds the run's lock)
            stray.unlink(missing_ok=True)
    t0 = time.perf_counter()
    val = [n for n in seen if n not in data.extra]  # validation: the benchmark's seen objects only
    res = train(train_cfg, {n: data.refs[n] for n in seen}, {n: data.train_q[n] for n in seen},
                {n: val_refs_subset(data.refs[n], val_refs_per_object) for n in val},
                {n: data.val_q[n] for n in val}, run, resume=True,
                clean_queries={n: data.clean_q[n] for n in seen} if curriculum else None)
    rank, _ = distributed_world()
    if rank == 0:
        atomic_write_json(run / "done.json", {
            "split": split, "seen": val, **({"extra": len(data.extra)} if data.extra else {}),
            "seconds_this_session": time.perf_counter() - t0,
            "best": "best.pt", "train_images_per_s": res.train_images_per_s, "processes": world,
            "sha256": {f: sha256_file(run / f) for f in ("best.pt", "last.pt")}, "made_by": made_by(),
            "finished": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
    if world > 1:
        import torch.distributed as dist

        dist.barrier()


def run_folder(split: int, train_cfg: Any, data: StudyData, val_refs_per_object: int = 256) -> Path:
    """``<cache>/runs/split<k>-<hash>``: the run folder of :func:`train_or_load`, keyed by the
    training config (precision resolved), the split and the render keys of every set it uses."""
    if hasattr(train_cfg, "resolved"):  # "auto" precision keys the run by what it means on this machine
        train_cfg = train_cfg.resolved()
    seen, objs = data.manifest.seen_objects(split), data.training_objects(split)
    curriculum = bool(getattr(train_cfg, "clean_steps", 0))
    key = stable_hash({"split": split, "train": _train_key(train_cfg),
                       "refs": [data.key(n) for n in objs], "train_q": [data.key(n, "train_q") for n in objs],
                       "val_q": [data.key(n, "val_q") for n in seen], "val_refs": val_refs_per_object,
                       **({"clean_q": [data.key(n, "clean_q") for n in objs]} if curriculum else {})})
    return cache_dir(data.cfg.cache_dir or None) / "runs" / f"split{split}-{key}"


def _train_key(cfg: Any) -> dict:
    """The parts of a TrainConfig that change the trained weights (not device/progress)."""
    d = cfg.to_dict() if hasattr(cfg, "to_dict") else asdict(cfg)
    for k in ("device", "progress", "num_threads", "val_batch_size"):
        d.pop(k, None)
    for k, v in LATER_DEFAULTS.items():  # added later: at their default, earlier runs keep their folders
        if k in d and d[k] == v:
            d.pop(k)
    return d


# ------------------------------------------------------------------ evaluation

def reference_bank(model: Any, data: StudyData, objects: list[str], device: str = "auto", k_ac: int | None = None,
                   n_refs: int | None = None, batch: int | None = None, progress: bool = True) -> ReferenceBank:
    """Encode (once, cached as float16 memmaps) the references of ``objects``.

    ``n_refs`` keeps only the first n references (still Haar-uniform): taken from the
    full set's features when those are cached already, else only those n are encoded
    (cached under their own key), so a small ablation bank costs n, not all, encodings.
    ``k_ac``: anchors of fast retrieval to pick now (None: on first use).
    """
    dev = resolve_device(device)
    batch = batch or encode_batch(dev)
    fc = FeatureCache(cache_dir(data.cfg.cache_dir or None) / "features")
    mkey = model_fingerprint(model)
    feats = []
    for n in objects:
        views, key = data.refs[n], data.key(n)
        if n_refs is not None and n_refs < len(views) and fc.load(mkey, key) is None:
            views, key = views.subset(np.arange(n_refs)), f"{key}-first{n_refs}"
        feats.append(fc.get_or_build(model, mkey, views, key, batch=batch, device=dev, progress=progress))
    rot = data.refs[objects[0]].rotations
    for n in objects[1:]:
        if not np.array_equal(data.refs[n].rotations, rot):
            raise ValueError(f"reference rotations of {n!r} differ from {objects[0]!r}; render them with one seed")
    if n_refs is not None:
        feats = [f[:n_refs] for f in feats]
        rot = rot[:n_refs]
    return ReferenceBank(feats, rot, objects, k_ac=k_ac)


def encode_queries(model: Any, views: ObjectViews, device: str = "auto", batch: int | None = None) -> torch.Tensor:
    """(N, C, L) float32 features of query views."""
    dev = resolve_device(device)
    batch = batch or encode_batch(dev)
    parts = list(encode_views(model, views.images, batch=batch, device=dev))
    return torch.cat(parts) if parts else torch.zeros(0)


def evaluate(model: Any, bank: ReferenceBank, queries: dict[str, ObjectViews], search: SearchConfig,
             device: str = "auto", threshold_deg: float = 30.0) -> dict[str, Any]:
    """Retrieve every query of ``queries`` in ``bank`` with ``search`` and score the predictions.

    Seconds per query exclude query encoding.

    Returns:
        {"per_object": DataFrame, "means": dict, "per_query": DataFrame,
         "seconds_per_query": [...], "comparisons": [...], "records": [...]}.
    """
    dev = resolve_device(device)
    scorer = model_scorer(model, dev)
    records, secs, comps = [], [], []
    for name, views in queries.items():
        q = encode_queries(model, views, device)
        preds = search_all(q, bank, scorer, search, progress=False) if len(q) else []
        for i, pred in enumerate(preds):
            secs.append(pred.seconds)
            comps.append(pred.n_comparisons)
            records.append(Record(name, pred.obj_name, np.asarray(views.rotations[i], dtype=np.float64), pred.R_est,
                                  views.symmetries, f"{name}:{i}"))
    per_query = per_query_table(records, threshold_deg)
    per_object, means = summarise_queries(per_query)
    return {"per_object": per_object, "means": means, "per_query": per_query,
            "seconds_per_query": secs, "comparisons": comps, "records": records}


def split_of(manifest: Manifest) -> dict[str, str]:
    """Object -> "1"/"2"/"3"/"held-out"."""
    return {o.name: (str(o.split) if o.split else "held-out") for o in manifest.objects}


def summary_row(label: str, res: dict[str, Any]) -> dict[str, Any]:
    m = res["means"]
    return {"setting": label, "class_acc": m.get("class_acc"), "rot_acc": m.get("rot_acc"),
            "median_err_deg": m.get("median_err_deg"), "n_queries": int(res["per_object"]["n"].sum()),
            "s_per_query": float(np.median(res["seconds_per_query"])) if res["seconds_per_query"] else None}


def render_summary(data: StudyData, verify_seconds: float, render_seconds: float) -> dict[str, Any]:
    """What notebook 01 records about the rendered benchmark: config, objects, view counts, timings,
    GL backend, reference bytes (per object and scaled to 10,000 references) and every cache key."""
    cfg = data.cfg
    kinds = ("refs", "train_q", "val_q", "test_q", "occluded_q")
    sets = [vs for kind in kinds for vs in getattr(data, kind).values()]
    ref_bytes = sum(v.meta["bytes"] for v in data.refs.values())
    n_obj = len(data.refs)
    return {
        "data_config": asdict(cfg), "objects": list(data.refs), "views": sum(len(s) for s in sets),
        "verify_seconds": verify_seconds, "render_or_load_seconds": render_seconds,
        "gl_platform": gl_platform(),  # the headless GL backend renders used (probed if nothing rendered)
        "reference_bytes_per_object": ref_bytes / n_obj,
        "reference_bytes_per_10000_per_object": ref_bytes / n_obj / cfg.n_references * 10000,
        "cache_keys": {f"{kind}/{n}": vs.meta["key"] for kind in kinds for n, vs in getattr(data, kind).items()},
    }
