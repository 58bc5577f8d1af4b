"""Batch runner: execute the study's notebooks with a named preset via papermill.

    python -m helpers.study.cli.runner quick            # all notebooks, quick preset
    python -m helpers.study.cli.runner smoke --only 01_render 02_train

For each notebook it loads ``presets/<preset>/<notebook>.yaml`` (absent = the
notebook's own defaults, which are the smoke preset), refuses unknown or
mistyped parameters before anything runs, points ``out_dir`` at
``reports/<preset>/<notebook>``, executes the notebook into
``reports/<preset>/<notebook>.ipynb``, exports HTML beside it, and finally
builds ``reports/<preset>/REPORT.md``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import yaml

from ...core.fileio import atomic_write_json, atomic_write_text, stable_hash
from ...core.locks import entry_lock
from ...core.paths import REPO_ROOT, portable_obj
from ..parameters import NOTEBOOK_DIR, ParameterError, check_mapping, check_values, declared_parameters
from ..provenance import git_revision
from ..report import build_report

PRESET_DIR = REPO_ROOT / "presets"
PRESETS = ("smoke", "quick", "screens", "long", "paper", "real-lm")  # "standard" (180-step models) retired once the quick preset read the zoo
STATE_FILE = "runner_state.json"
COMMON = "common.yaml"  # parameters a preset's notebooks share
NOTEBOOK_LIST = "notebooks.yaml"  # the notebooks a preset runs, where not all (real-lm: those of real data)
HEARTBEAT_S = 30.0  # how often a running notebook's elapsed time is saved (lost on a kill: at most this much)


def notebooks() -> list[str]:
    """Notebook names in run order (file name order)."""
    return sorted(p.stem for p in NOTEBOOK_DIR.glob("[0-9][0-9]_*.ipynb"))


def preset_notebooks(preset: str) -> list[str]:
    """The notebooks ``preset`` runs, in run order: those its ``notebooks.yaml`` lists, else all."""
    f, names = PRESET_DIR / preset / NOTEBOOK_LIST, notebooks()
    if not f.exists():
        return names
    listed = yaml.safe_load(f.read_text())
    if not isinstance(listed, list) or not listed or not set(listed) <= set(names):
        raise ParameterError(f"{f}: expected a non-empty list of notebook names among {names}, got {listed!r}")
    return [n for n in names if n in listed]


def _read_preset_file(f: Path) -> dict:
    if not f.exists():
        return {}
    given = yaml.safe_load(f.read_text()) or {}
    if not isinstance(given, dict):
        raise ParameterError(f"{f}: expected a mapping of parameter names to values")
    return given


def preset_parameters(preset: str, notebook: str, reports: str = "reports") -> dict:
    """Validated parameters of ``notebook`` under ``preset`` (out_dir: ``<reports>/<preset>/<notebook>``).

    ``presets/<preset>/common.yaml`` holds what the preset's notebooks share (each notebook takes the
    names it declares); ``presets/<preset>/<notebook>.yaml`` then sets what differs for that notebook.
    A name in common.yaml that no notebook declares is an error naming the file."""
    if preset not in PRESETS:
        raise ParameterError(f"preset must be one of {PRESETS}, got {preset!r}")
    declared = declared_parameters(NOTEBOOK_DIR / f"{notebook}.ipynb")
    common_file, f = PRESET_DIR / preset / COMMON, PRESET_DIR / preset / f"{notebook}.yaml"
    common = _read_preset_file(common_file)
    known = {k for n in notebooks() for k in declared_parameters(NOTEBOOK_DIR / f"{n}.ipynb")}
    if set(common) - known:
        raise ParameterError(f"{common_file}: parameter(s) {sorted(set(common) - known)} are declared by no notebook")
    given = {**{k: v for k, v in common.items() if k in declared}, **_read_preset_file(f)}
    given.setdefault("out_dir", f"{reports}/{preset}/{notebook}")
    try:
        return check_mapping(notebook, declared, given)
    except ParameterError as e:
        where = f if f.exists() else common_file if common_file.exists() else f"preset {preset}"
        raise ParameterError(f"{where}: {e}") from None


def run_key(params: dict) -> str:
    """What makes a finished notebook reusable: its parameters and the code it ran, i.e. the
    git revision plus any uncommitted change to src/, notebooks/, presets/ or the manifest
    (reports/ is excluded: the runner itself writes there)."""
    diff = ""
    try:
        diff = subprocess.run(["git", "diff", "HEAD", "--", "src", "notebooks", "presets", "data_manifest.yaml"],
                              cwd=REPO_ROOT, capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        pass
    return stable_hash({"params": params, "commit": git_revision().get("commit"),
                        "diff": hashlib.sha256(diff.encode()).hexdigest()})


def _read_state(path: Path) -> dict:
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return d if isinstance(d, dict) else {}


def run(preset: str, only: list[str] | None = None, html: bool = True, report: bool = True,
        restart: bool = False, reports: str | Path | None = None) -> Path:
    """Run the notebooks of ``preset``; returns the report folder ``<reports>/<preset>``
    (``reports`` default: the repository's ``reports/``).

    A notebook that finished in an earlier call (same parameters, same code) is skipped,
    so an interrupted run resumes at the notebook it was in (``restart`` reruns all).
    Inside a notebook, finished training runs and encoded features are reused from the
    cache, so the interrupted notebook itself resumes from its last checkpoint. Two
    runners writing the same report folder take turns (its lock); runners with different
    report folders share the cache safely (every cache entry has its own lock)."""
    names = preset_notebooks(preset)
    if only is not None:
        if not only:
            raise ParameterError(f"--only: name at least one notebook; available: {names}")
        unknown = sorted(set(only) - set(names))
        if unknown:
            raise ParameterError(f"--only: unknown notebook(s) {unknown}; available: {names}")
        names = [n for n in names if n in only]
    root = Path(reports) if reports is not None else REPO_ROOT / "reports"
    params = {n: preset_parameters(preset, n, str(root) if reports is not None else "reports")
              for n in names}  # validate everything first
    for n in names:  # values too (not only names and types), before any notebook starts
        check_values(n, params[n])
    out = root / preset
    out.mkdir(parents=True, exist_ok=True)
    with entry_lock(out, f"report folder {out.name} (another runner of this preset)"):
        _run_notebooks(preset, names, params, out, html, restart)
        if report:
            build_report(preset, out.parent, preset_notebooks(preset))
    return out


def _run_notebooks(preset: str, names: list[str], params: dict, out: Path, html: bool, restart: bool) -> None:
    import papermill as pm

    state_path = out / STATE_FILE
    state = {} if restart else _read_state(state_path)
    # Timings of notebooks this call does not run (``--only``) stay: they time the outputs that stay.
    timings = {k: v for k, v in _read_state(out / "timings.json").items() if k in state or k not in names}
    for n in names:
        key = run_key(params[n])
        dst = out / f"{n}.ipynb"
        prev = state.get(n, {})
        if prev.get("key") == key and prev.get("done", True) and dst.exists():
            print(f"[runner] {preset}: {n} finished earlier with the same parameters and code "
                  f"({prev['seconds']:.0f} s); skipped (--restart reruns it)", flush=True)
            timings[n] = prev["seconds"]
            continue
        # Time spent in interrupted attempts of this same notebook counts towards its wall time,
        # so a run resumed after a kill reports what it really cost (not only the last attempt).
        earlier = float(prev.get("seconds", 0.0)) if prev.get("key") == key and not prev.get("done", True) else 0.0
        attempts = int(prev.get("attempts", 0)) + 1 if earlier else 1
        state[n] = {"key": key, "seconds": earlier, "done": False, "attempts": attempts}
        atomic_write_json(state_path, state)
        t0 = time.perf_counter()
        print(f"[runner] {preset}: {n}" + (f" (attempt {attempts}; {earlier:.0f} s spent earlier)" if earlier else ""),
              flush=True)
        os.environ["HELPERS_MADE_BY"] = f"{preset}/{n}"  # the kernel inherits it: cache entries name their maker
        try:
            with _Heartbeat(state_path, state, n, earlier, t0):
                try:
                    pm.execute_notebook(str(NOTEBOOK_DIR / f"{n}.ipynb"), str(dst), parameters=params[n],
                                        cwd=str(NOTEBOOK_DIR), progress_bar=True, kernel_name="python3",
                                        kernel_manager_class=_ipc_kernel_manager())
                finally:
                    portable_notebook(dst)  # also a failed run's notebook: it is what the user reads
                if html:
                    export_html(dst)
        finally:
            os.environ.pop("HELPERS_MADE_BY", None)
        timings[n] = earlier + time.perf_counter() - t0
        state[n] = {"key": key, "seconds": timings[n], "done": True, "attempts": attempts}
        atomic_write_json(out / "timings.json", timings)
        atomic_write_json(state_path, state)


def _ipc_kernel_manager() -> type:
    """A kernel manager whose kernels talk over local socket files (ZeroMQ ipc) instead of TCP
    ports: nothing listens on the network, and ipykernel's warning about unencrypted TCP has no
    cause. Each kernel's sockets live in a fresh private folder (mode 0700, removed at shutdown):
    jupyter_client's default, ``kernel-ipc-<n>`` in the working folder, would be shared by two
    runners started from the same place."""
    import shutil
    import tempfile

    from jupyter_client import AsyncKernelManager
    from traitlets import default

    class IPCKernelManager(AsyncKernelManager):
        @default("transport")
        def _transport_default(self) -> str:
            return "ipc"

        @default("ip")
        def _ip_default(self) -> str:
            self._ipc_dir = tempfile.mkdtemp(prefix="helpers-kernel-")
            return os.path.join(self._ipc_dir, "k")

        async def _async_cleanup_resources(self, restart: bool = False) -> None:
            await super()._async_cleanup_resources(restart=restart)
            if not restart and getattr(self, "_ipc_dir", None):
                shutil.rmtree(self._ipc_dir, ignore_errors=True)

    return IPCKernelManager


def portable_notebook(path: Path) -> None:
    """Rewrite executed notebook ``path`` with this machine's absolute paths named by their role
    (:func:`helpers.core.paths.portable`): in sources, outputs, tracebacks and papermill's metadata;
    base64 image data is left alone."""
    if not path.exists():
        return
    try:
        nb = json.loads(path.read_text(encoding="utf-8"))
    except ValueError:
        return  # not a notebook papermill finished writing; left as it is
    images = {}
    for c in nb.get("cells", []):
        for o in c.get("outputs", []):
            data = o.get("data", {})
            for mime in [m for m in data if m.startswith("image/") and m != "image/svg+xml"]:
                images[id(data), mime] = data.pop(mime)
    nb = _restore_images(portable_obj(nb), nb, images)
    atomic_write_text(path, json.dumps(nb, indent=1, ensure_ascii=False) + "\n")


def _restore_images(new: dict, old: dict, images: dict) -> dict:
    """Put the image payloads taken out of ``old``'s outputs back into the same outputs of ``new``."""
    for c_new, c_old in zip(new.get("cells", []), old.get("cells", [])):
        for o_new, o_old in zip(c_new.get("outputs", []), c_old.get("outputs", [])):
            for (key, mime), payload in images.items():
                if key == id(o_old.get("data")):
                    o_new.setdefault("data", {})[mime] = payload
    return new


class _Heartbeat:
    """Saves a running notebook's elapsed seconds into the runner state every HEARTBEAT_S."""

    def __init__(self, path: Path, state: dict, name: str, earlier: float, t0: float) -> None:
        self.path, self.state, self.name, self.earlier, self.t0 = path, state, name, earlier, t0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, name="runner-heartbeat", daemon=True)

    def _save(self) -> None:
        self.state[self.name]["seconds"] = self.earlier + time.perf_counter() - self.t0
        atomic_write_json(self.path, self.state)

    def _loop(self) -> None:
        while not self.stop.wait(HEARTBEAT_S):
            self._save()

    def __enter__(self) -> "_Heartbeat":
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(timeout=10)
        self._save()  # also when the notebook failed: a rerun then counts this attempt's time


def export_html(nb_path: Path) -> Path:
    """Executed notebook -> HTML beside it."""
    import nbformat
    from nbconvert import HTMLExporter

    body, _ = HTMLExporter().from_notebook_node(nbformat.read(str(nb_path), as_version=4))
    dst = nb_path.with_suffix(".html")
    dst.write_text(body, encoding="utf-8")
    return dst


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m helpers.study.cli.runner", description=__doc__.split("\n\n")[0])
    ap.add_argument("preset", choices=PRESETS)
    ap.add_argument("--only", nargs="*", help="notebook names to run (default: all)")
    ap.add_argument("--no-html", action="store_true")
    ap.add_argument("--no-report", action="store_true")
    ap.add_argument("--restart", action="store_true",
                    help="rerun every notebook (default: skip those finished earlier with the same parameters and code)")
    ap.add_argument("--reports", default=None,
                    help="report root: writes <reports>/<preset>/ (default: the repository's reports/)")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    try:
        out = run(a.preset, a.only, html=not a.no_html, report=not a.no_report, restart=a.restart,
                  reports=a.reports)
    except ParameterError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"[runner] done in {time.perf_counter() - t0:.0f} s; report: {out / 'REPORT.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
