"""The model zoo: trained weights committed under ``models/`` with their provenance.

Recipes live in ``presets/long/zoo.yaml`` (shared data and training settings, per-model
overrides). Training a recipe goes through :func:`helpers.study.pipeline.train_or_load`, so it uses the
same content-hashed run folder (``<cache>/runs/...``) as notebook 02 and resumes after an
interruption; a run that did not finish in one session resumes from the checkpoint committed
under ``models/checkpoints/`` by :func:`snapshot`. :func:`publish` writes ``models/<name>.pt``
(float16 weights), ``models/<name>.history.json``, ``models/<name>.check.npz`` (a few seen-object
validation views, references and their scores, for the reproduction test) and the model's entry
in ``models/zoo.yaml``. :func:`load` checks the sha256 before it loads.
"""

from __future__ import annotations

import io
import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from ..core.configs import LATER_DEFAULTS, DataConfig, ExtraConfig, ModelConfig, TrainConfig
from ..core.device import resolve_device
from ..core.fileio import atomic_write_bytes, atomic_write_json, atomic_write_text, read_json, sha256_file
from ..core.paths import REPO_ROOT
from ..core.precision import describe
from ..data.extra_objects import EXTRA_FILE
from ..data.manifest import load_manifest
from ..net.model import OrientationNet, images_to_tensor
from ..training.train import read_checkpoint
from ..training.validation import plot_history, validate
from .extra_data import add_extra_objects
from .pipeline import check_run, prepare_data, run_folder, run_lock, train_or_load, val_refs_subset
from .provenance import device_info, git_revision, package_versions

ZOO_DIR = REPO_ROOT / "models"
RECIPES = REPO_ROOT / "presets" / "long" / "zoo.yaml"
#: Views per seen object kept in ``<name>.check.npz``: queries and references.
CHECK_QUERIES, CHECK_REFS = 2, 12


@dataclass(frozen=True)
class Recipe:
    """How one zoo model is trained: its data, training configuration, split (0 = all objects) and the extra
    training objects beside the split's seen ones (issue #44, screen e; ``extra.n == 0``: none)."""

    name: str
    split: int
    data: DataConfig
    train: TrainConfig
    val_refs: int
    extra: ExtraConfig = ExtraConfig()
    #: The recipe changes the shared data or adds extra objects (a screen's arm): notebooks name its model,
    #: :func:`find` never picks it for a training configuration (it would match on the network and training alone).
    by_name_only: bool = False


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
            by_name_only = "data" in over or bool((over.get("extra") or {}).get("n"))
            split = int(over.pop("split"))
            if split not in (0, 1, 2, 3):
                raise ValueError(f"split: expected 0 (all objects), 1, 2 or 3, got {split}")
            data = DataConfig(**{**spec["data"], **over.pop("data", {}), "cache_dir": cache_dir})
            model = ModelConfig.from_dict(_merge({"image_size": data.image_size}, over.pop("model", {})))
            train = _merge(spec["train"], over.pop("train", {}))
            extra = ExtraConfig(**over.pop("extra", {}))
            if over:
                raise ValueError(f"unknown keys {sorted(over)}")
            tcfg = TrainConfig.from_dict({**train, "model": model.to_dict(), "device": device})
            if extra.n and tcfg.symmetry_aware:  # the training extras carry no symmetry declarations
                raise ValueError("extra objects with symmetry_aware training: the extras' symmetries are not declared")
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{path}: model {name!r}: {e}") from None
        out[name] = Recipe(name, split, data, tcfg, int(spec.get("val_refs", 256)), extra, by_name_only)
    return out


def recipe(name: str, **kw: Any) -> Recipe:
    rs = recipes(**kw)
    if name not in rs:
        raise ValueError(f"zoo: no recipe {name!r} in {kw.get('path', RECIPES)}; known: {sorted(rs)}")
    return rs[name]


# ----------------------------------------------------------------------------- training

def _checkpoint_path(name: str, zoo_dir: Path = ZOO_DIR) -> Path:
    return zoo_dir / "checkpoints" / f"{name}.last.pt"


def _best_path(checkpoint: Path) -> Path:
    """``<name>.best.pt`` beside committed checkpoint ``<name>.last.pt``: the weights of its best epoch so far."""
    return checkpoint.with_name(checkpoint.name.replace(".last.pt", ".best.pt"))


def _machine(device: str) -> dict:
    """Where a model trains: torch's device summary, the CPU model and its bf16 support."""
    model = next((ln.split(":", 1)[1].strip() for ln in _cpuinfo_lines() if ln.startswith("model name")), None)
    info = device_info(device)
    kernel = info.pop("fusion_kernel", None)  # its build folder is a machine path: keep the verdict only
    info["fusion_kernel"] = None if kernel is None else bool(kernel.get("available"))
    return {**info, "cpu_model": model, **describe(resolve_device(device))}


def _cpuinfo_lines() -> list[str]:
    try:
        return Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return []


def train_recipe(r: Recipe, zoo_dir: Path = ZOO_DIR) -> tuple[OrientationNet, Path, dict, Any]:
    """Train (or resume, or load the finished run of) recipe ``r``; returns
    (model, run folder, info of :func:`train_or_load`, StudyData)."""
    data = recipe_data(r)
    run = run_folder(r.split, r.train, data, r.val_refs)
    committed = _checkpoint_path(r.name, zoo_dir)
    with run_lock(run):  # held through training (train_or_load takes it again)
        # Resume from the committed checkpoint when this cache has none, or an older one (another machine went on).
        if committed.exists() and not (run / "done.json").exists() and _step(committed) > _step(run / "last.pt"):
            run.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(committed, run / "last.pt")
            if _best_path(committed).exists():  # the best epoch so far may predate the checkpoint
                shutil.copyfile(_best_path(committed), run / "best.pt")
            if committed.with_suffix(".provenance.json").exists():
                shutil.copyfile(committed.with_suffix(".provenance.json"), run / "provenance.json")
        if not (run / "done.json").exists():
            _record_session(r, run)
        model, run, info = train_or_load(r.split, r.train, data, val_refs_per_object=r.val_refs)
    return model, run, info, data


def _step(checkpoint: Path) -> int:
    """The optimiser steps a last.pt has taken (-1: no such file)."""
    return int(read_checkpoint(checkpoint)["global_step"]) if checkpoint.exists() else -1


def recipe_data(r: Recipe) -> Any:
    """The StudyData recipe ``r`` trains on: the split's seen objects (references, training, validation and clean
    views), plus its extra objects."""
    data = prepare_data(r.data, objects=load_manifest().seen_objects(r.split), occluded=False, test=False)
    return add_extra_objects(data, r.extra)


def _record_session(r: Recipe, run: Path) -> None:
    """One provenance record per training session (a resumed run may continue on another machine)."""
    run.mkdir(parents=True, exist_ok=True)
    prov = run / "provenance.json"
    sessions = _sessions(read_json(prov)) if prov.exists() else []
    step = read_checkpoint(run / "last.pt")["global_step"] \
        if (run / "last.pt").exists() else 0
    sessions.append({"git": git_revision(), "device": _machine(r.train.device), "from_step": int(step),
                     "precision": r.train.resolved().precision,
                     "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
    atomic_write_json(prov, {"recipe": r.name, "sessions": sessions})


def _sessions(prov: dict) -> list[dict]:
    """Training sessions of a provenance record (the first format held one session's git only)."""
    if "sessions" in prov:
        return list(prov["sessions"])
    return [{"git": prov.get("git"), "device": prov.get("device"), "from_step": 0}]


# ----------------------------------------------------------------------------- publishing

def _torch_bytes(obj: Any) -> bytes:
    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


def _half(state: dict) -> dict:
    """Floating tensors to float16 (the zoo's storage precision); others unchanged."""
    return {k: v.half() if v.is_floating_point() else v for k, v in state.items()}


def _build(ck: dict, device: str | torch.device = "cpu") -> OrientationNet:
    """A float32 eval-mode network from a checkpoint dict (float16 weights are upcast)."""
    model = OrientationNet(ModelConfig.from_dict(ck["model_config"]))
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in ck["model"].items()})
    return model.to(device).eval()


def _check_views(r: Recipe, data: Any) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(query images, reference images, names of the query objects) kept for the reproduction test:
    the first CHECK_QUERIES validation views and CHECK_REFS validation references of every seen object."""
    seen = data.manifest.seen_objects(r.split)
    q = np.concatenate([data.val_q[n].images[:CHECK_QUERIES] for n in seen])
    refs = np.concatenate([val_refs_subset(data.refs[n], r.val_refs).images[:CHECK_REFS] for n in seen])
    return q, refs, [n for n in seen for _ in range(min(CHECK_QUERIES, len(data.val_q[n])))]


def check_scores(model: OrientationNet, queries: np.ndarray, refs: np.ndarray) -> np.ndarray:
    """(Q, R) float32 scores of ``queries`` (Q,S,S,3) against ``refs`` (R,S,S,3), uint8 images, on CPU
    in float32: what ``<name>.check.npz`` records and the zoo test recomputes."""
    with torch.inference_mode():
        fq = model.encode(images_to_tensor(queries))
        fr = model.encode(images_to_tensor(refs))
        return model.score(fq, fr).float().numpy()


#: An epoch counts as quiet when its CPU share is at least this fraction of the run's highest.
QUIET_SHARE = 0.9


def quiet_speed(history: list[dict], fallback: float = float("nan")) -> dict[str, Any]:
    """The training speed a zoo entry records: the median images/s over the run's quiet epochs,
    those whose ``cpu_share`` is at least :data:`QUIET_SHARE` of the run's highest (epochs that
    shared the cores or were paused would understate the machine). Histories written before
    ``cpu_share`` existed: the median over all their epochs; none with a speed: ``fallback``.

    Returns {"train_images_per_s", "train_speed_epochs" (how many epochs it is the median of),
    "train_speed_rule"}."""
    eps = [h for h in history if h.get("images_per_s")]
    shares = [h["cpu_share"] for h in eps if h.get("cpu_share") is not None]
    if shares and len(shares) == len(eps):
        top = max(shares)
        quiet = [h["images_per_s"] for h in eps if h["cpu_share"] >= QUIET_SHARE * top]
        rule = f"median over epochs with cpu_share >= {QUIET_SHARE} x the run's highest ({top:.2f})"
    else:
        quiet = [h["images_per_s"] for h in eps]
        rule = f"median over all epochs (cpu_share recorded for {len(shares)} of {len(eps)})"
    if not quiet:
        return {"train_images_per_s": float(fallback), "train_speed_epochs": 0,
                "train_speed_rule": "no per-epoch speeds: the training call's own figure"}
    return {"train_images_per_s": float(np.median(quiet)), "train_speed_epochs": len(quiet), "train_speed_rule": rule}


def publish(r: Recipe, run: Path, data: Any, zoo_dir: Path = ZOO_DIR) -> Path:
    """Write ``<name>.pt`` (float16 weights of the run's best.pt), its history, check views and
    its entry in ``zoo.yaml``; returns the weight file. The validation numbers are recomputed with
    the published weights (float32 on CPU) beside those the training recorded."""
    run = Path(run)
    check_run(run)
    best, last = read_checkpoint(run / "best.pt"), read_checkpoint(run / "last.pt")
    done = read_json(run / "done.json")
    sessions = _sessions(read_json(run / "provenance.json"))
    for sess in sessions:  # runs started before provenance recorded the machine: the publishing one
        if not sess.get("device"):
            sess["device"] = {**_machine("cpu"), "recorded_at": "publish"}
    cfg = best["config"]
    out = {"model": _half(best["model"]), "model_config": best["model_config"], "config": cfg,
           "epoch": best["epoch"], "val": best["val"], "recipe": r.name}
    zoo_dir.mkdir(parents=True, exist_ok=True)
    wfile = zoo_dir / f"{r.name}.pt"
    atomic_write_bytes(wfile, _torch_bytes(out))
    model = _build(out)
    seen = data.manifest.seen_objects(r.split)
    val = validate(model, {n: val_refs_subset(data.refs[n], r.val_refs) for n in seen},
                   {n: data.val_q[n] for n in seen}, "cpu")
    q, refs, qnames = _check_views(r, data)
    buf = io.BytesIO()
    np.savez_compressed(buf, queries=q, refs=refs, scores=check_scores(model, q, refs), query_objects=np.array(qnames))
    atomic_write_bytes(zoo_dir / f"{r.name}.check.npz", buf.getvalue())
    hist = read_json(run / "history.json")
    atomic_write_text(zoo_dir / f"{r.name}.history.json", json.dumps(hist, indent=1))
    plot_history(hist.get("history", []), zoo_dir / f"{r.name}.curve.png")
    steps_per_epoch = last["global_step"] // max(1, last["epoch"])
    data_cfg = {k: v for k, v in asdict(r.data).items() if k not in ("cache_dir", "workers")}
    entry = {
        "file": wfile.name, "sha256": sha256_file(wfile), "bytes": wfile.stat().st_size, "dtype": "float16",
        "history": f"{r.name}.history.json", "curve": f"{r.name}.curve.png", "check": f"{r.name}.check.npz",
        "split": r.split, "seen_objects": seen, "data": data_cfg, "val_refs_per_object": r.val_refs,
        # the extras are the first n of the file's training order: its name and sha256 say which
        **({"extra": {**asdict(r.extra), "objects_file": EXTRA_FILE.name, "objects_sha256": sha256_file(EXTRA_FILE)}}
           if r.extra.n else {}),
        **({"by_name_only": True} if r.by_name_only else {}),
        "train": {k: v for k, v in cfg.items() if k not in ("device", "progress", "num_threads")},
        "steps": int(last["global_step"]), "best_epoch": int(best["epoch"]),
        "best_step": int(best["epoch"]) * steps_per_epoch, "seed": int(cfg["seed"]),
        # every precision the epochs used (a run resumed on a CPU without native bf16 goes on in fp32)
        "precision": "+".join(sorted({h.get("precision", cfg["precision"]) for h in hist.get("history", [])}))
        or cfg["precision"],
        "git": sessions[0]["git"], "device": sessions[0]["device"], "sessions": sessions, "packages": package_versions(("torch", "numpy")),
        **quiet_speed(hist.get("history", []), float(done.get("train_images_per_s", float("nan")))),
        "train_seconds": float(sum(h.get("seconds", 0.0) for h in hist.get("history", []))),
        "val_recorded": {k: float(v) for k, v in (best["val"] or {}).items() if k != "per_object"},
        "val": {k: float(v) for k, v in val.items() if k != "per_object"},
    }
    _write_entry(r.name, entry, zoo_dir)
    return wfile


def _write_entry(name: str, entry: dict, zoo_dir: Path) -> None:
    """Add or replace ``name`` in zoo.yaml, one writer at a time (filelock, 10 min limit)."""
    from filelock import FileLock

    path = zoo_dir / "zoo.yaml"
    with FileLock(str(path) + ".lock", timeout=600):
        zoo = entries(zoo_dir) if path.exists() else {}
        zoo[name] = entry
        head = "# The model zoo: written by `python -m helpers.study.cli.zoo train NAME --publish` (helpers.study.zoo.publish).\n"
        atomic_write_text(path, head + yaml.dump({"models": dict(sorted(zoo.items()))}, Dumper=_PlainDumper,
                                                 sort_keys=False))


def refresh_speeds(zoo_dir: Path = ZOO_DIR) -> dict[str, float]:
    """Rewrite every zoo.yaml entry's training speed with :func:`quiet_speed` from its committed history
    (entries published before the rule kept the mean of their last training call). Returns name ->
    images/s now recorded."""
    out = {}
    for name, e in entries(zoo_dir).items():
        hist = read_json(Path(zoo_dir) / e["history"]).get("history", [])
        speed = quiet_speed(hist, e.get("train_images_per_s", float("nan")))
        new = {}
        for k, v in e.items():  # the speed fields stay together, where train_images_per_s was
            if k in ("train_speed_epochs", "train_speed_rule"):
                continue
            new.update(speed if k == "train_images_per_s" else {k: v})
        _write_entry(name, new, Path(zoo_dir))
        out[name] = speed["train_images_per_s"]
    return out


class _PlainDumper(yaml.SafeDumper):
    """Writes repeated values out in full (no &id001 anchors: zoo.yaml is read by people too)."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def snapshot(r: Recipe, zoo_dir: Path = ZOO_DIR) -> Path:
    """Copy the run's last.pt (optimizer and RNG state included) to ``models/checkpoints/<name>.last.pt``, and its
    best.pt to ``<name>.best.pt``, so that an unfinished training resumes from them in a later session or on another
    machine. ValueError when the committed checkpoint is further along than this run (it is never replaced by an
    older one)."""
    data = recipe_data(r)
    src = run_folder(r.split, r.train, data, r.val_refs) / "last.pt"
    if not src.exists():
        raise FileNotFoundError(f"zoo snapshot {r.name}: no {src} (has its training started?)")
    dst = _checkpoint_path(r.name, zoo_dir)
    if _step(dst) > _step(src):
        raise ValueError(f"zoo snapshot {r.name}: {dst} is at step {_step(dst)}, further than this run's {src} "
                         f"(step {_step(src)}); resume from it with zoo train {r.name} instead of replacing it")
    dst.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(dst, src.read_bytes())
    # The best epoch's weights travel too: when no later epoch beats it, the resumed run has no other best.pt.
    if (src.parent / "best.pt").exists():
        atomic_write_bytes(_best_path(dst), (src.parent / "best.pt").read_bytes())
    if (src.parent / "provenance.json").exists():  # the sessions so far travel with the checkpoint
        atomic_write_bytes(dst.with_suffix(".provenance.json"), (src.parent / "provenance.json").read_bytes())
    return dst


# ----------------------------------------------------------------------------- loading

def entries(zoo_dir: Path = ZOO_DIR) -> dict[str, dict]:
    """Every model of ``zoo.yaml`` by name."""
    path = Path(zoo_dir) / "zoo.yaml"
    if not path.exists():
        raise FileNotFoundError(f"zoo: {path} does not exist (no model published yet)")
    return dict((yaml.safe_load(path.read_text()) or {}).get("models") or {})


def entry(name: str, zoo_dir: Path = ZOO_DIR) -> dict:
    zoo = entries(zoo_dir)
    if name not in zoo:
        raise ValueError(f"zoo: no model {name!r} in {Path(zoo_dir) / 'zoo.yaml'}; available: {sorted(zoo)}")
    return zoo[name]


def progress(path: str | Path = RECIPES, zoo_dir: Path = ZOO_DIR) -> list[dict]:
    """Where each recipe of ``path`` stands in the committed zoo, in the recipes' order: one dict
    {"name", "state" ("published" | "checkpoint": a committed unfinished run | "untrained"),
    "steps" (done), "budget" (epochs x steps_per_epoch; None for one pass per epoch), "val" (the published
    seen-object validation), "train_seconds", "precision", "images_per_s" (published: as recorded)}."""
    published = entries(zoo_dir) if (Path(zoo_dir) / "zoo.yaml").exists() else {}
    out = []
    for name, r in recipes(path, device="cpu").items():
        # steps_per_epoch 0/None means one pass over the training queries: no fixed count here
        budget = r.train.epochs * r.train.steps_per_epoch if r.train.steps_per_epoch else None
        row = {"name": name, "budget": budget, "steps": 0, "val": None, "state": "untrained", "train_seconds": None,
               "precision": None, "images_per_s": None}
        ck = _checkpoint_path(name, Path(zoo_dir))
        if name in published:
            e = published[name]
            row.update(state="published", steps=int(e["steps"]), val=e.get("val"), train_seconds=e.get("train_seconds"),
                       precision=e.get("precision"), images_per_s=e.get("train_images_per_s"))
        elif ck.exists():
            row.update(state="checkpoint", steps=int(read_checkpoint(ck, "cpu")["global_step"]))
        out.append(row)
    return out


def verify(zoo_dir: Path = ZOO_DIR) -> list[str]:
    """Problems with the committed files (missing, or sha256 differing from zoo.yaml); [] if none."""
    bad = []
    for name, e in entries(zoo_dir).items():
        f = Path(zoo_dir) / e["file"]
        if not f.exists():
            bad.append(f"{name}: {f} is missing")
        elif sha256_file(f) != e["sha256"]:
            bad.append(f"{name}: {f} does not match its sha256 in zoo.yaml (damaged or replaced)")
    return bad


def load(name: str, device: str | torch.device = "auto", zoo_dir: Path = ZOO_DIR) -> tuple[OrientationNet, dict]:
    """The zoo model ``name`` in eval mode (float32 on ``device``) and its zoo.yaml entry, after
    checking the weight file's sha256."""
    e = entry(name, zoo_dir)
    f = Path(zoo_dir) / e["file"]
    if not f.exists():
        raise FileNotFoundError(f"zoo: {f} (model {name!r}) is missing")
    if sha256_file(f) != e["sha256"]:
        raise ValueError(f"zoo: {f} does not match the sha256 recorded in zoo.yaml for {name!r}: damaged "
                         "or replaced; restore it with `git checkout -- models/` or retrain it with "
                         f"`python -m helpers.study.cli.zoo train {name} --publish`")
    ck = torch.load(f, map_location="cpu", weights_only=True)
    return _build(ck, resolve_device(device)), e


# ----------------------------------------------------------------------------- notebooks

MODEL_SOURCES = ("train", "zoo")
# TrainConfig fields that make an ablation variant (besides the architecture): a zoo model stands
# in for a requested variant only when these and its model config are the same.
_VARIANT_FIELDS = ("seed", "weighted_loss", "occlusion", "random_ref", "symmetry_aware")


def find(split: int, train_cfg: TrainConfig, zoo_dir: Path = ZOO_DIR, steps: int = 0) -> str:
    """Name of the zoo model trained on ``split`` with ``train_cfg``'s architecture and variant
    switches (seed, loss, occlusion, random reference, symmetry-aware training, augmentation), never one of a
    screen's models that changed the data (``by_name_only``); the budget is the zoo's, not ``train_cfg``'s:
    ``steps`` optimiser steps, or (0) the shortest budget the zoo has for it (4,000 steps; every ablation
    variant has that one). ValueError listing what the zoo has when none matches."""
    want = ModelConfig.from_dict(train_cfg.model.to_dict()).to_dict()
    zoo = entries(zoo_dir)
    found = {name: int(e["steps"]) for name, e in zoo.items()
             if e["split"] == split and not e.get("by_name_only")
             and ModelConfig.from_dict(e["train"]["model"]).to_dict() == want
             and all(e["train"].get(f, LATER_DEFAULTS.get(f)) == getattr(train_cfg, f) for f in _VARIANT_FIELDS)
             and e["train"].get("augment", train_cfg.augment.to_dict()) == train_cfg.augment.to_dict()}
    if found and steps:
        for name, n in found.items():
            if n == steps:
                return name
        raise ValueError(f"models='zoo', zoo_steps={steps}: the zoo's models for split {split} and this variant "
                         f"have {sorted(set(found.values()))} steps ({sorted(found)})")
    if found:
        return min(found, key=found.get)  # ties: the first in zoo.yaml
    raise ValueError(f"models='zoo': no zoo model for split {split} with model {want} and "
                     f"{ {f: getattr(train_cfg, f) for f in _VARIANT_FIELDS} }; the zoo has "
                     f"{ {n: (e['split'], e['train']['model'].get('fusion'), e['seed']) for n, e in zoo.items()} }. "
                     "Train it (`python -m helpers.study.cli.zoo train NAME --publish`) or use models='train'")


def model_for(split: int, train_cfg: TrainConfig, data: Any, val_refs: int, models: str = "train",
              zoo_dir: Path = ZOO_DIR, zoo_steps: int = 0) -> tuple[OrientationNet, Path, dict]:
    """What a notebook evaluates: ``models="train"`` trains (or loads from the cache) with
    ``train_cfg`` (:func:`helpers.study.pipeline.train_or_load`); ``models="zoo"`` loads the committed zoo
    model of :func:`find`. Returns (model in eval mode, run folder or weight file, info with
    ``history``). ``zoo_steps``: the zoo budget to load (:func:`find`; 0: the shortest)."""
    if models not in MODEL_SOURCES:
        raise ValueError(f"models: expected one of {MODEL_SOURCES}, got {models!r}")
    if models == "train":
        return train_or_load(split, train_cfg, data, val_refs_per_object=val_refs)
    name = find(split, train_cfg, zoo_dir, steps=zoo_steps)
    return named_model(name, data.cfg.image_size, train_cfg.device, zoo_dir)


def named_model(name: str, image_size: int, device: str = "auto", zoo_dir: Path = ZOO_DIR
                ) -> tuple[OrientationNet, Path, dict]:
    """The zoo model ``name`` for ``image_size`` px crops (ValueError otherwise), as :func:`model_for` returns it:
    (model in eval mode, its weight file, info with ``history``, ``zoo``, ``split`` and ``zoo_entry``)."""
    model, e = load(name, device=device, zoo_dir=zoo_dir)
    if e["data"]["image_size"] != image_size:
        raise ValueError(f"models='zoo': {name} takes {e['data']['image_size']} px crops, the data are "
                         f"{image_size} px")
    history = read_json(Path(zoo_dir) / e["history"])
    return model, Path(zoo_dir) / e["file"], {"history": history, "zoo": name, "split": int(e["split"]),
                                              "train_images_per_s": e["train_images_per_s"], "zoo_entry": e}


def zoo_curve(split: int, train_cfg: TrainConfig, zoo_dir: Path = ZOO_DIR) -> tuple[str, np.ndarray, np.ndarray] | None:
    """(label, optimiser steps, validation Rota. Acc. %) of the zoo model matching ``split`` and
    ``train_cfg`` (see :func:`find`), to draw beside a notebook's own run; None when the zoo has none."""
    try:
        name = find(split, train_cfg, zoo_dir)
    except (FileNotFoundError, ValueError):
        return None
    e = entry(name, zoo_dir)
    hist = read_json(Path(zoo_dir) / e["history"]).get("history", [])
    pts = [(h["global_step"], 100 * h["val"]["rot_acc"]) for h in hist if h.get("val")]
    label = (f"zoo {name} ({e['data']['n_train_queries']} queries/object; val: {e['data']['n_val_queries']} views x "
             f"{e['val_refs_per_object']} refs/object)")
    return label, np.array([p[0] for p in pts]), np.array([p[1] for p in pts])
