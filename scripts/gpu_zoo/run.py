"""Train zoo recipes side by side on a lent GPU machine, stop them at a deadline, pack what comes back.

Run by ``scripts/gpu_zoo/device.sh`` on that machine (after ``scripts/gpu_zoo/bundle.py`` here)::

    python3 scripts/gpu_zoo/run.py --deadline 470 split1-12k split2-12k split3-12k global-12k

1. renders every view the recipes need once, with many processes (a subprocess: this process never
   holds a GL context, so the trainers it starts are never forked from one);
2. starts one ``python -m helpers.study.cli.zoo train NAME --publish`` per recipe (one GPU, shared);
3. at ``--deadline`` seconds after ``$GPU_ZOO_T0`` (the script's start otherwise) stops those still
   running (SIGTERM, then SIGKILL): their epoch checkpoints stay;
4. packs into ``$OUT``: ``NAME.zoo.tgz`` (models/NAME.* and its zoo.yaml entry) for a published model,
   else ``NAME.ckpt.tgz`` (``zoo snapshot``: models/checkpoints/NAME.last.pt, resumable anywhere), in the
   order given, while the device tool's limits allow (8 files, 16 MiB each, 64 MiB in all); ``log.txt``.
Nothing here is needed for the study: it only makes the GPU lease train the zoo faster.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
FILE_LIMIT, TOTAL_LIMIT, MAX_FILES = 16 * 2**20, 64 * 2**20, 8
LOGS = Path("/tmp/gpu_zoo_logs")
T0 = float(os.environ.get("GPU_ZOO_T0", time.time()))


def log(msg: str, out: Path) -> None:
    line = f"[{time.time() - T0:6.0f} s] {msg}"
    print(line, flush=True)
    with open(out / "log.txt", "a") as f:
        f.write(line + "\n")


def render(names: list[str], recipes: str, workers: int) -> None:
    """Render (into the cache) every view set the recipes train on."""
    sys.path.insert(0, str(REPO / "src"))
    from dataclasses import replace

    from helpers.study import zoo

    for name in names:
        r = zoo.recipe(name, path=recipes)
        zoo.recipe_data(replace(r, data=replace(r.data, workers=workers)))  # extra objects too


def train_all(names: list[str], recipes: str, deadline: float, threads: int, out: Path) -> dict[str, int | None]:
    """One trainer process per recipe; returns each one's exit code (None: stopped at the deadline)."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "PYTHONUNBUFFERED": "1"}
    procs = {}
    for n in names:
        f = open(LOGS / f"train-{n}.log", "w")  # outside $OUT: only the tail travels, in log.txt
        procs[n] = (subprocess.Popen([sys.executable, "-m", "helpers.study.cli.zoo", "train", n, "--publish",
                                      "--recipes", recipes], cwd=REPO, env=env, stdout=f, stderr=subprocess.STDOUT,
                                     start_new_session=True), f)
    codes: dict[str, int | None] = {}
    while len(codes) < len(procs) and time.time() - T0 < deadline:
        for n, (p, _) in procs.items():
            if n not in codes and p.poll() is not None:
                codes[n] = p.returncode
                log(f"{n}: exited {p.returncode}", out)
        time.sleep(2)
    for n, (p, f) in procs.items():
        if n not in codes:
            log(f"{n}: deadline, stopping", out)
            os.killpg(p.pid, signal.SIGTERM)
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
            codes[n] = None
        f.close()
        tail = (LOGS / f"train-{n}.log").read_text(errors="replace").replace("\r", "\n").splitlines()
        log(f"{n}: last lines:\n    " + "\n    ".join([t for t in tail if t.strip()][-6:]), out)
    return codes


def pack(names: list[str], recipes: str, out: Path) -> None:
    """Published models first, then checkpoints of unfinished ones, within the tool's limits."""
    sys.path.insert(0, str(REPO / "src"))
    from helpers.study.zoo import entries as zoo_entries

    zoo_dir = REPO / "models"
    entries = zoo_entries(zoo_dir) if (zoo_dir / "zoo.yaml").exists() else {}
    budget = {"bytes": 0, "files": 1}  # log.txt
    for name in names:
        if (zoo_dir / f"{name}.pt").exists() and name in entries:
            (zoo_dir / f"{name}.entry.yaml").write_text(yaml.safe_dump({name: entries[name]}, sort_keys=False))
            files, dst = sorted(zoo_dir.glob(f"{name}.*")), out / f"{name}.zoo.tgz"
        else:
            res = subprocess.run([sys.executable, "-m", "helpers.study.cli.zoo", "snapshot", name, "--recipes", recipes],
                                 cwd=REPO,
                                 capture_output=True, text=True)
            if res.returncode != 0:
                log(f"{name}: no checkpoint ({res.stderr.strip().splitlines()[-1:]})", out)
                continue
            files, dst = sorted((zoo_dir / "checkpoints").glob(f"{name}.*")), out / f"{name}.ckpt.tgz"
        with tarfile.open(dst, "w:gz") as tar:
            for p in files:
                tar.add(p, arcname=str(p.relative_to(REPO)))
        size, parts = dst.stat().st_size, fit(dst, budget)
        log(f"{name}: {dst.name} ({size / 2**20:.1f} MiB) " +
            (f"packed in {parts} file(s)" if parts else "does not fit what comes back; left out"), out)


def fit(dst: Path, budget: dict) -> int:
    """Keep ``dst`` in the files that come back if the budget (``{"bytes": used, "files": used}``) allows,
    split into parts of at most FILE_LIMIT bytes (``dst.name + ".partI"``; rejoin with ``cat``); else
    delete it. Returns the number of files kept (0: left out)."""
    size = dst.stat().st_size
    parts = -(-size // FILE_LIMIT)  # a checkpoint with Adam's state exceeds one file's limit
    if budget["bytes"] + size > TOTAL_LIMIT or budget["files"] + parts > MAX_FILES:
        dst.unlink()
        return 0
    if parts > 1:
        data = dst.read_bytes()
        dst.unlink()
        for i in range(parts):
            dst.with_name(f"{dst.name}.part{i}").write_bytes(data[i * FILE_LIMIT:(i + 1) * FILE_LIMIT])
    budget["bytes"] += size
    budget["files"] += parts
    return parts


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="+")
    ap.add_argument("--recipes", default=str(REPO / "presets" / "long" / "zoo.yaml"))
    ap.add_argument("--deadline", type=float, default=470.0, help="seconds after $GPU_ZOO_T0 to stop training")
    ap.add_argument("--render-workers", type=int, default=max(1, (os.cpu_count() or 2) - 2))
    ap.add_argument("--threads", type=int, default=0, help="CPU threads per trainer (default: cores / trainers)")
    ap.add_argument("--render-only", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.render_only:
        render(a.names, a.recipes, a.render_workers)
        return 0
    out = Path(os.environ.get("OUT") or "/tmp/gpu_zoo_out")
    out.mkdir(parents=True, exist_ok=True)
    LOGS.mkdir(parents=True, exist_ok=True)
    log(f"rendering the views of {a.names} with {a.render_workers} processes", out)
    res = subprocess.run([sys.executable, __file__, "--render-only", "--recipes", a.recipes,
                          "--render-workers", str(a.render_workers), *a.names], cwd=REPO)
    if res.returncode != 0:
        log(f"rendering failed ({res.returncode})", out)
        return 1
    threads = a.threads or max(1, (os.cpu_count() or 2) // len(a.names))
    log(f"training {a.names}, {threads} CPU threads each, until {a.deadline:.0f} s", out)
    codes = train_all(a.names, a.recipes, a.deadline, threads, out)
    pack(a.names, a.recipes, out)
    log(f"done: {codes}", out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
