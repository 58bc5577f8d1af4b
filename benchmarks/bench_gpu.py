#!/usr/bin/env python
"""One-shot GPU benchmark: training, encoding, fusion and retrieval at the paper's 128 px setting.

Two modes (run from the repository root):

1. ``--make-data DIR`` (on a machine that can render, i.e. here, on the CPU)::

       HELPERS_CACHE_DIR=/tmp/gpubench_cache PYTHONPATH=src \
           .venv/bin/python benchmarks/bench_gpu.py --make-data .gpudata

   renders a small set of the paper preset's data (128 px crops from 160 px
   renders, LineMOD-style queries with 1.5x context) for the seen objects of
   split 1 and writes ``DIR/gpu_data.npz``: references, training queries (with
   masks) and validation queries per object. Rendering needs trimesh/pyrender;
   nothing else in this file does.

2. default (GPU) mode::

       PYTHONPATH=src python3 benchmarks/bench_gpu.py --data .gpudata [--out PATH]

   loads the npz and measures, each section under its own time cap and all of
   them under ``--budget-s`` (default 420 s; a watchdog writes the JSON and
   exits if a section overruns): ``train`` (``helpers.training.train.train`` on the
   real data, paper config), ``train_step`` (bare ``helpers.training.train.train_step``
   on random images), ``encode`` (``model.encode`` at batch 256),
   ``retrieval`` (fast vs greedy search over 13 x 10,000 synthetic float16
   references held on the GPU) and ``fusion`` (``model.score`` pair rates,
   with the block-size constants of ``helpers.net.model`` as a what-if).
   The JSON is rewritten after every section. ``--device cpu --tiny`` is a
   small CPU dry run of the same flow.

The sections live in two sibling modules: ``gpu_sections.py`` (the shared
clock, timing loop and npz loader, and ``train``, ``train_step``, ``encode``,
``fusion``) and ``gpu_retrieval.py`` (``retrieval`` and its torch-backed
bank); this file is the CLI, ``--make-data``, the budget watchdog and the JSON.
See ``benchmarks/README_gpu_section.md`` for the JSON keys. Only the standard
library and numpy are imported at module level (in all three files).
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import types
from pathlib import Path
from typing import Any, Callable

import numpy as np

# The section modules are siblings of this file; put its folder on the path however it is run.
_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)

# Importing gpu_sections (here or through gpu_retrieval) starts the run's clock, T_START.
from gpu_retrieval import bench_retrieval  # noqa: E402
from gpu_sections import (  # noqa: E402
    NPZ_NAME,
    T_START,
    Ctx,
    _log,
    bench_encode,
    bench_fusion,
    bench_train,
    bench_train_step,
    load_data,
    release_cuda,
)

REPO = Path(__file__).resolve().parents[1]
SCHEMA_VERSION = 1
PRESET, PRESET_NOTEBOOK = "paper", "02_train"

# Paper setting of the retrieval benchmark (as benchmarks/bench.py).
PAPER_OBJECTS = 13
PAPER_REFS = 10_000
PAPER_K_AC = 1024
PAPER_FPS_K = 256

# Counts of --make-data (small: the npz travels with the working tree).
MAKE_DATA_COUNTS = {"n_references": 64, "n_train_queries": 32, "n_val_queries": 8, "n_test_queries": 1}
MAX_NPZ_BYTES = 40_000_000

SECTIONS = ("train", "train_step", "encode", "retrieval", "fusion")
# Seconds per section (each also limited by what is left of the total budget).
DEFAULT_CAPS = {"train": 120.0, "train_step": 35.0, "encode": 25.0, "retrieval": 170.0, "fusion": 30.0}
WATCHDOG_GRACE_S = 15.0  # the watchdog fires this long after the budget

MEASURED_MODULES = ("net/model.py", "training/train.py", "search/retrieval.py", "training/losses.py",
                    "training/augment.py", "core/rotations.py", "core/views.py")


def _git_revision() -> dict:
    out: dict[str, Any] = {"revision": None, "dirty": None}
    try:
        r = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        if r.returncode == 0:
            out["revision"] = r.stdout.strip()
            d = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10)
            out["dirty"] = bool(d.stdout.strip()) if d.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        pass
    return out


def _sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def source_hashes() -> dict:
    """sha256 of the measured helpers modules and of this script and its two section modules
    (the tree may differ from the commit)."""
    out = {m: _sha256(REPO / "src" / "helpers" / m) for m in MEASURED_MODULES}
    for name in ("bench_gpu.py", "gpu_sections.py", "gpu_retrieval.py"):
        out[f"benchmarks/{name}"] = _sha256(Path(_HERE) / name)
    return out


# =========================================================================== environment shims

def block_modules(names: list[str]) -> None:
    """Make ``import name`` fail (to simulate the GPU machine in a dry run)."""
    for n in names:
        if n:
            sys.modules[n] = None  # type: ignore[assignment]


def ensure_render_helpers_importable() -> dict:
    """Let ``helpers.data.render`` import without trimesh, so the in-plane augmentation works.

    ``helpers.training.augment.box_crop`` (the in-plane rotation, p = 0.5 per query)
    imports ``crop_affine``/``silhouette_box`` from ``helpers.data.render``, which
    imports ``helpers.data.meshes``, which imports ``trimesh`` at module level (it is
    used only inside functions there). Where trimesh is missing a placeholder
    module is registered; any attribute access on it raises AttributeError
    (what ``hasattr``/``inspect`` expect of a module), so nothing that really
    needs trimesh can run by accident.
    """
    try:
        import trimesh  # noqa: F401
        return {"trimesh": "real"}
    except ImportError:
        pass

    stub = types.ModuleType("trimesh")

    def __getattr__(name: str):  # noqa: N807
        raise AttributeError(f"trimesh is not installed (bench_gpu placeholder module; trimesh.{name} requested)")

    stub.__getattr__ = __getattr__  # type: ignore[attr-defined]
    stub.__bench_gpu_stub__ = True  # type: ignore[attr-defined]
    sys.modules["trimesh"] = stub
    return {"trimesh": "placeholder module (not installed): helpers.data.render imports, mesh functions raise"}


# =========================================================================== --make-data (CPU, renders)

def paper_parameters() -> tuple[dict, str]:
    """The paper preset's parameters of notebook 02_train (declared defaults + presets/paper yaml)."""
    from helpers.study.cli.runner import preset_parameters

    src = f"helpers.study.cli.runner.preset_parameters({PRESET!r}, {PRESET_NOTEBOOK!r})"
    return dict(preset_parameters(PRESET, PRESET_NOTEBOOK)), src


def make_data(out_dir: Path, counts: dict, split: int | None = None) -> Path:
    os.environ.setdefault("LP_NUM_THREADS", "1")  # llvmpipe threads: keep the CPU use small
    import torch

    torch.set_num_threads(1)
    from helpers.core.configs import DataConfig
    from helpers.study.pipeline import prepare_data

    P, source = paper_parameters()
    split = int(P["split"] if split is None else split)
    cache = os.environ.get("HELPERS_CACHE_DIR") or str(Path(tempfile.gettempdir()) / "gpubench_cache")
    if Path(cache).resolve().is_relative_to(REPO):
        raise SystemExit(f"--make-data: cache dir {cache} is inside the repository; set HELPERS_CACHE_DIR elsewhere")
    cfg = DataConfig(image_size=P["image_size"], render_size=P["render_size"], query_style=P["query_style"],
                     train_context=P["train_context"], seed=P["seed"], workers=0, cache_dir=cache, **counts)
    from helpers.data.manifest import load_manifest

    m = load_manifest()
    seen = m.seen_objects(split)
    _log(f"rendering split-{split} seen objects {seen} with {cfg} (cache {cache})")
    t0 = time.perf_counter()
    data = prepare_data(cfg, objects=seen, occluded=False, manifest=m)
    render_s = time.perf_counter() - t0
    _log(f"rendered/loaded in {render_s:.0f} s")

    arrays: dict[str, np.ndarray] = {"names": np.array(seen)}
    sets = {"ref": data.refs, "train": data.train_q, "val": data.val_q}
    if P.get("clean_steps", 0):
        sets["clean"] = data.clean_q
    keys = {}
    for n in seen:
        for kind, d in sets.items():
            v = d[n]
            arrays[f"{kind}_images__{n}"] = np.ascontiguousarray(v.images)
            arrays[f"{kind}_rotations__{n}"] = np.asarray(v.rotations, np.float32)
            if v.masks is not None:
                arrays[f"{kind}_masks__{n}"] = np.asarray(v.masks, bool)
            keys[f"{kind}/{n}"] = v.meta.get("key")
        sym = data.refs[n].symmetries
        if sym is not None:
            arrays[f"symmetries__{n}"] = np.asarray(sym, np.float32)
    kinds = {k: d[seen[0]].kind for k, d in sets.items()}
    meta = {"schema": SCHEMA_VERSION, "preset": PRESET, "preset_notebook": PRESET_NOTEBOOK,
            "preset_parameters": P, "preset_source": source, "split": split, "seen_objects": seen,
            "data_config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in cfg.__dict__.items()},
            "counts": counts, "kinds": kinds, "render_keys": keys, "render_s": render_s,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "git": _git_revision(),
            "shapes": {k: list(v.shape) for k, v in arrays.items()}}
    arrays["meta_json"] = np.array(json.dumps(meta, default=str))
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / NPZ_NAME
    tmp = out_dir / (NPZ_NAME + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)
    size = path.stat().st_size
    _log(f"wrote {path}: {size / 1e6:.1f} MB ({size} bytes)")
    if size > MAX_NPZ_BYTES:
        _log(f"WARNING: {path} is larger than {MAX_NPZ_BYTES / 1e6:.0f} MB; rerun with smaller counts")
    print(f"NPZ_BYTES {size}", flush=True)
    return path


# =========================================================================== run

def device_info(ctx: Ctx) -> dict:
    import torch

    info: dict[str, Any] = {"torch": torch.__version__, "cuda_runtime": torch.version.cuda,
                            "cudnn": torch.backends.cudnn.version() if torch.backends.cudnn.is_available() else None,
                            "python": sys.version.split()[0], "numpy": np.__version__, "platform": platform.platform(),
                            "cpu_count": os.cpu_count(), "torch_threads": torch.get_num_threads(),
                            "device": ctx.device, "cuda_available": torch.cuda.is_available()}
    if ctx.cuda:
        p = torch.cuda.get_device_properties(0)
        info.update({"name": torch.cuda.get_device_name(0), "capability": list(torch.cuda.get_device_capability(0)),
                     "total_memory_bytes": p.total_memory, "multiprocessors": p.multi_processor_count,
                     "tf32_matmul": torch.backends.cuda.matmul.allow_tf32,
                     "tf32_cudnn": torch.backends.cudnn.allow_tf32,
                     "cudnn_benchmark": torch.backends.cudnn.benchmark})
        try:
            r = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total,power.limit,clocks.max.sm",
                                "--format=csv,noheader"], capture_output=True, text=True, timeout=15)
            info["nvidia_smi"] = r.stdout.strip() if r.returncode == 0 else None
        except (OSError, subprocess.SubprocessError):
            info["nvidia_smi"] = None
    else:
        info["name"] = platform.processor() or "cpu"
    return info


def write_json(path: Path, obj: dict) -> None:
    try:
        from helpers.core.fileio import atomic_write_json
        from helpers.core.paths import portable_obj

        atomic_write_json(path, portable_obj(obj))
        return
    except ImportError:
        pass

    def default(o):
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, (np.integer, np.floating, np.bool_)):
            return o.item()
        return str(o)

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, sort_keys=True, default=default) + "\n")
    os.replace(tmp, path)


def summarise(res: dict) -> dict:
    s: dict[str, Any] = {"device_name": res.get("device", {}).get("name"), "total_s": res.get("total_s")}
    tr = res.get("train") or {}
    s.update({"train_steps_done": tr.get("steps_done"), "train_cut_short": tr.get("cut_short"),
              "train_images_per_s": tr.get("images_per_s"),
              "train_images_per_s_in_loop": tr.get("images_per_s_in_loop"),
              "train_loss_first_epoch": tr.get("loss_first_epoch"), "train_loss_last_epoch": tr.get("loss_last_epoch")})
    for b, v in ((res.get("train_step") or {}).get("by_batch") or {}).items():
        s[f"train_step_images_per_s_b{b}"] = v.get("images_per_s")
    en = res.get("encode") or {}
    if en.get("batch"):
        s[f"encode_refs_per_s_b{en['batch']}"] = en.get("refs_per_s")
    rt = res.get("retrieval") or {}
    s.update({"retrieval_bank": f"{rt.get('n_objects')}x{rt.get('R')}" if rt.get("R") else None,
              "fast_s_per_query": (rt.get("fast") or {}).get("s_per_query_median"),
              "fast_comparisons_per_query": (rt.get("fast") or {}).get("comparisons_per_query_median"),
              "fast_batched_s_per_query": (rt.get("fast_batched") or {}).get("s_per_query_mean"),
              "greedy_s_per_query": (rt.get("greedy") or {}).get("s_per_query_median"),
              "greedy_extrapolated": bool((rt.get("greedy") or {}).get("extrapolated_to_all_objects")),
              "speedup_greedy_over_fast": rt.get("speedup_greedy_over_fast"),
              "comparison_ratio_greedy_over_fast": rt.get("comparison_ratio_greedy_over_fast")})
    for name, v in ((res.get("fusion") or {}).get("variants") or {}).items():
        for key, m in v.items():
            s[f"fusion_{name}_{key}_pair_scores_per_s"] = m.get("pair_scores_per_s")
    s["sections_cut_short"] = [k for k in SECTIONS if isinstance(res.get(k), dict) and res[k].get("cut_short")]
    s["sections_failed"] = sorted(res.get("errors", {}))
    return s


def run_gpu(args: argparse.Namespace) -> int:
    out_path = Path(args.out) if args.out else (Path(os.environ["OUT"]) / "bench_gpu.json" if os.environ.get("OUT")
                                                else REPO / "benchmarks" / "results" / "bench_gpu.json")
    res: dict[str, Any] = {"schema": SCHEMA_VERSION, "script": "benchmarks/bench_gpu.py", "argv": sys.argv[1:],
                           "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "git": _git_revision(),
                           "measured_sources": source_hashes(), "budget_s": args.budget_s, "errors": {},
                           "section_caps_s": {}, "in_progress": None}
    lock = threading.Lock()

    def flush(final: bool = False) -> None:
        with lock:
            res["total_s"] = time.perf_counter() - T_START
            for _ in range(3):
                try:
                    snap = copy.deepcopy(res)
                    break
                except RuntimeError:  # dict changed during copy (watchdog vs main thread)
                    time.sleep(0.05)
            else:
                snap = dict(res)
            snap["summary"] = summarise(snap)
            snap["complete"] = final
            write_json(out_path, snap)

    def watchdog() -> None:
        res["watchdog_fired"] = True
        sec = res.get("in_progress")
        if sec:
            res.setdefault(sec, {})
            if isinstance(res[sec], dict):
                res[sec]["cut_short"] = True
                res[sec]["killed_by_watchdog"] = True
        try:
            flush()
        finally:
            print(f"[bench_gpu] watchdog: budget {args.budget_s} s exceeded during {sec!r}; wrote {out_path}",
                  flush=True)
            os._exit(3)

    timer = threading.Timer(max(1.0, args.budget_s + args.watchdog_grace_s - (time.perf_counter() - T_START)),
                            watchdog)
    timer.daemon = True
    timer.start()

    import torch

    block_modules([m for m in args.block_modules.split(",") if m])
    res["shims"] = ensure_render_helpers_importable()

    ctx = Ctx(args)
    if not ctx.cuda:
        torch.set_num_threads(args.threads)
    elif not torch.cuda.is_available():
        res["errors"]["setup"] = "device cuda requested but torch.cuda.is_available() is False"
        flush(True)
        print(f"error: {res['errors']['setup']}", file=sys.stderr)
        return 2
    res["device"] = device_info(ctx)
    _log(f"device: {res['device'].get('name')}; torch {torch.__version__}, CUDA {torch.version.cuda}")
    data = load_data(Path(args.data))
    meta = data["meta"]
    try:
        P, psrc = paper_parameters()
    except Exception as e:  # noqa: BLE001 - fall back to the parameters stored with the data
        P, psrc = dict(meta["preset_parameters"]), f"stored in the npz (runtime read failed: {e!r})"
    size = int(meta["data_config"]["image_size"])
    res["data"] = {"path": data["path"], "bytes": data["bytes"], "objects": data["names"], "split": meta.get("split"),
                   "data_config": meta["data_config"], "counts": meta.get("counts"), "created": meta.get("created"),
                   "data_git": meta.get("git"),
                   "shapes": {k: v for k, v in meta.get("shapes", {}).items() if data["names"][0] in k}}
    res["preset"] = {"name": PRESET, "notebook": PRESET_NOTEBOOK, "source": psrc, "parameters": P}
    res["config"] = {k: v for k, v in vars(args).items()}
    caps = dict(DEFAULT_CAPS)
    for item in filter(None, args.caps.split(",")):
        k, v = item.split("=")
        caps[k.strip()] = float(v)
    sections = [s for s in args.sections.split(",") if s]
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        raise SystemExit(f"--sections: unknown {sorted(unknown)}; known {SECTIONS}")
    flush()
    fns: dict[str, Callable[[float, dict], dict]] = {
        "train": lambda cap, live: bench_train(ctx, data, P, cap, live),
        "train_step": lambda cap, live: bench_train_step(ctx, P, cap, size, live),
        "encode": lambda cap, live: bench_encode(ctx, data, cap, size, live),
        "retrieval": lambda cap, live: bench_retrieval(ctx, cap, size, live),
        "fusion": lambda cap, live: bench_fusion(ctx, cap, size, live),
    }
    for name in SECTIONS:
        if name not in sections:
            continue
        cap = min(caps[name], ctx.left())
        res["section_caps_s"][name] = cap
        if cap < 3:
            res[name] = {"skipped": "no time left in the budget", "cut_short": True}
            _log(f"{name}: skipped (no time left)")
            continue
        _log(f"=== {name} (cap {cap:.0f} s)")
        live: dict[str, Any] = {}
        with lock:
            res[name] = live  # filled in place, so the watchdog can write what a section got done
            res["in_progress"] = name
        t0 = time.perf_counter()
        try:
            fns[name](cap, live)
        except Exception as e:  # noqa: BLE001 - record and go on with the next section
            live.update({"error": f"{type(e).__name__}: {e}", "cut_short": True})
            res["errors"][name] = traceback.format_exc()
            _log(f"{name}: FAILED {type(e).__name__}: {e}")
            release_cuda()
        live["section_wall_s"] = time.perf_counter() - t0
        with lock:
            res["in_progress"] = None
        flush()
    timer.cancel()
    res["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    flush(True)
    summary = summarise({**res, "total_s": time.perf_counter() - T_START})
    _log(f"wrote {out_path}")
    print(json.dumps(summary, indent=1, default=str), flush=True)
    return 0 if not res["errors"] else 1


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--make-data", metavar="DIR", help="render the small data set into DIR/gpu_data.npz and exit")
    ap.add_argument("--data", default=str(REPO / ".gpudata"), help="folder (or file) of gpu_data.npz")
    ap.add_argument("--out", help="JSON path (default $OUT/bench_gpu.json, else benchmarks/results/bench_gpu.json)")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--tiny", action="store_true", help="tiny counts for a CPU dry run (128 px kept)")
    ap.add_argument("--budget-s", type=float, default=420.0, help="total wall-clock budget")
    ap.add_argument("--caps", default="", help="per-section caps, e.g. train=100,retrieval=150")
    ap.add_argument("--sections", default=",".join(SECTIONS))
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads with --device cpu")
    ap.add_argument("--train-steps", type=int, default=300)
    ap.add_argument("--epoch-steps", type=int, default=50)
    ap.add_argument("--train-step-batches", default="16,64")
    ap.add_argument("--train-step-repeats", type=int, default=20)
    ap.add_argument("--train-step-warmup", type=int, default=5)
    ap.add_argument("--encode-batch", type=int, default=256)
    ap.add_argument("--encode-repeats", type=int, default=20)
    ap.add_argument("--encode-warmup", type=int, default=3)
    ap.add_argument("--retr-objects", type=int, default=PAPER_OBJECTS)
    ap.add_argument("--retr-refs", type=int, default=PAPER_REFS)
    ap.add_argument("--k-ac", type=int, default=PAPER_K_AC)
    ap.add_argument("--fps-k", type=int, default=PAPER_FPS_K)
    ap.add_argument("--fast-queries", type=int, default=10)
    ap.add_argument("--greedy-queries", type=int, default=3)
    ap.add_argument("--batch-queries", type=int, default=16, help="queries of the batched fast search (0: skip)")
    ap.add_argument("--gpu-margin-gb", type=float, default=8.0, help="device memory left free besides the bank")
    ap.add_argument("--fusion-refs-q1", type=int, default=4096)
    ap.add_argument("--fusion-refs-q16", type=int, default=1024)
    ap.add_argument("--fusion-repeats", type=int, default=5)
    ap.add_argument("--watchdog-grace-s", type=float, default=WATCHDOG_GRACE_S, help=argparse.SUPPRESS)
    ap.add_argument("--block-modules", default="", help=argparse.SUPPRESS)  # dry run: simulate missing packages
    a = ap.parse_args(argv)
    if a.tiny:  # smaller defaults; flags given explicitly still win
        ap.set_defaults(train_steps=4, epoch_steps=2, train_step_batches="4", train_step_repeats=2,
                        train_step_warmup=1, encode_batch=16, encode_repeats=2, encode_warmup=1,
                        retr_objects=2, retr_refs=50, k_ac=16, fps_k=8, fast_queries=2, greedy_queries=2,
                        batch_queries=2, fusion_refs_q1=64, fusion_refs_q16=32, fusion_repeats=2)
        a = ap.parse_args(argv)
    return a


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.make_data:
        make_data(Path(args.make_data), MAKE_DATA_COUNTS)
        return 0
    return run_gpu(args)


if __name__ == "__main__":
    sys.exit(main())
