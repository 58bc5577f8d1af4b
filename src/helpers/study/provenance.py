"""Provenance of a run: parameters, seed, git revision, package versions, device."""

from __future__ import annotations

import datetime as _dt
import importlib.metadata as md
import json
import os
import platform
import subprocess
from pathlib import Path
from typing import Any

from ..core.device import resolve_device
from ..core.fileio import atomic_write_json
from ..core.paths import REPO_ROOT, portable_obj
from ..core.precision import native_bf16
from ..net import fusion_kernel

PACKAGES = ("helpers", "torch", "numpy", "scipy", "trimesh", "pyrender-maintained", "PyOpenGL", "opencv-python-headless",
            "scikit-image", "pandas", "matplotlib", "papermill", "pybullet", "robosuite", "pyvista")


def git_revision(repo: Path = REPO_ROOT) -> dict[str, Any]:
    """{"commit": sha or None, "dirty": bool or None}.

    ``$HELPERS_GIT_REVISION`` (JSON ``{"commit": ..., "dirty": ...}``, written by
    ``scripts/gpu_zoo/bundle.py``) overrides git, recorded with ``"via": "HELPERS_GIT_REVISION"``: the copy
    of the tree sent to a lent GPU machine carries a ``.git`` of another commit than the checkout's."""
    if os.environ.get("HELPERS_GIT_REVISION"):
        try:
            rev = json.loads(os.environ["HELPERS_GIT_REVISION"])
            return {"commit": rev.get("commit"), "dirty": rev.get("dirty"), "via": "HELPERS_GIT_REVISION"}
        except (ValueError, AttributeError):
            return {"commit": None, "dirty": None}
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True, timeout=10)
        # reports/ is excluded: the runner itself rewrites the committed reports while it runs.
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".", ":!reports"],
                               cwd=repo, capture_output=True, text=True, timeout=10)
        if sha.returncode != 0:
            return {"commit": None, "dirty": None}
        return {"commit": sha.stdout.strip(), "dirty": bool(dirty.stdout.strip())}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


def package_versions(names: tuple[str, ...] = PACKAGES) -> dict[str, str | None]:
    out = {}
    for n in names:
        try:
            out[n] = md.version(n)
        except md.PackageNotFoundError:
            out[n] = None
    return out


def device_info(device: str = "auto") -> dict[str, Any]:
    import torch

    d = resolve_device(device)

    info = {"requested": device, "resolved": str(d), "torch_threads": torch.get_num_threads(),
            "cpu_count": os.cpu_count(), "cpu": platform.processor() or platform.machine(),
            # what TrainConfig(precision="auto") trains with here (helpers.core.precision)
            "native_bf16": native_bf16(d), "auto_precision": "bf16" if native_bf16(d) else "fp32"}
    if d.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(d)
    else:
        # Which CPU fusion implementation scores pairs in this run (timings depend on it).
        fusion_kernel.get()
        info["fusion_kernel"] = fusion_kernel.status()
    return info


def run_record(name: str, params: dict[str, Any], seed: int | None = None, device: str = "auto",
               extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything needed to say how a result was produced (this machine's paths named by their
    role: :func:`helpers.core.paths.portable`)."""
    return portable_obj({
        "name": name,
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "parameters": params,
        "seed": seed if seed is not None else params.get("seed"),
        "git": git_revision(),
        "packages": package_versions(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "device": device_info(device),
        "gl_platform": os.environ.get("PYOPENGL_PLATFORM"),
        **(extra or {}),
    })


def start_run(name: str, params: dict[str, Any], out_dir: str | os.PathLike, device: str = "auto") -> Path:
    """Create ``out_dir`` and write ``out_dir/run.json``; returns the folder.

    Relative ``out_dir`` is taken from the repository root so notebooks run
    from any working directory write to the same place.
    """
    out = Path(out_dir)
    if not out.is_absolute():
        out = REPO_ROOT / out
    atomic_write_json(out / "run.json", run_record(name, params, device=device))
    return out
