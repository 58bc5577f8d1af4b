"""See, check and clean the cache: ``python -m helpers.study.cli.cache list | verify | prune``.

The cache (``$HELPERS_CACHE_DIR``, default ``<repo>/cache``) holds five kinds of entries:

========  ==========================================  ===========================================
kind      where                                       finished when / checked against
========  ==========================================  ===========================================
render    ``renders/<object>/<kind>-<key>/``          meta.json exists / its sha256 of 3 arrays
features  ``features/<model>/<refset>.f16`` + ``.json``  sidecar complete / its sha256
run       ``runs/split<k>-<key>/``                    done.json exists / its sha256 of 2 checkpoints
byo       ``byo/<mesh>-<key>/``                       meta.json exists / its sha256 of 2 arrays
kernel    ``ext/fusion_<key>/``                       built by torch (listed, not checked)
========  ==========================================  ===========================================

``verify`` exits 1 and names every damaged entry. ``prune`` removes damaged entries and the
temporary files of dead processes (each entry is taken under its lock first, so a build in
progress is never touched); ``--unfinished`` also removes interrupted renders, feature files and
trainings (which would otherwise resume where they stopped), ``--unused-days N`` finished entries
not used for N days; ``--dry-run`` only lists what would go.
Damaged render sets, feature files and reference sets are also rebuilt automatically when a run
needs them; a damaged training run is an error until pruned (retraining can take hours).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from ...core.fileio import DamagedEntry, read_json
from ...core.locks import try_entry_lock
from ...core.paths import cache_dir
from ...data.datasets import check_set
from ...search.features import FeatureCache
from ..byo import check_refs
from ..pipeline import check_run

KINDS = ("render", "features", "run", "byo", "kernel")
TEMP_SUFFIXES = (".tmp",)  # a feature file's ".partial" is its resumable progress, not a temporary


@dataclass
class Entry:
    """One cache entry: ``path`` is its folder (features: the .f16 path), ``files`` all it owns."""

    kind: str
    path: Path
    files: list[Path] = field(default_factory=list)
    finished: bool = True
    stamp: Path | None = None  # file whose modification time is the entry's last use
    made_by: str | None = None

    def size(self) -> int:
        return sum(f.stat().st_size for f in self.files if f.is_file())

    def last_use(self) -> float:
        probe = self.stamp if self.stamp is not None and self.stamp.exists() else self.path
        return probe.stat().st_mtime if probe.exists() else 0.0

    def temporaries(self) -> list[Path]:
        return [f for f in self.files if f.name.endswith(TEMP_SUFFIXES)]


def _tree(d: Path) -> list[Path]:
    return [f for f in d.rglob("*") if f.is_file()] if d.is_dir() else []


def _meta(p: Path) -> dict:
    try:
        d = read_json(p)
    except (OSError, ValueError):
        return {}
    return d if isinstance(d, dict) else {}


def entries(root: Path) -> Iterator[Entry]:
    """Every entry under cache root ``root``, kind by kind."""
    for d in sorted((root / "renders").glob("*/*-*")):
        if d.is_dir():
            yield Entry("render", d, _tree(d), (d / "meta.json").exists(), d / "meta.json",
                        _meta(d / "meta.json").get("made_by"))
    for side in sorted((root / "features").glob("*/*.json")):
        final = side.with_suffix(".f16")
        meta = _meta(side)
        files = [f for f in (final, side, side.with_name(f".{final.name}.partial")) if f.exists()]
        files += list(side.parent.glob(f".{side.name}.*.tmp"))  # a killed writer's sidecar temporaries
        yield Entry("features", final, files, bool(meta.get("complete")) and final.exists(), side, meta.get("made_by"))
    for d in sorted((root / "runs").glob("*")):
        if d.is_dir():
            yield Entry("run", d, _tree(d), (d / "done.json").exists(), d / "done.json", _meta(d / "done.json").get("made_by"))
    for d in sorted((root / "byo").glob("*")):
        if d.is_dir():
            yield Entry("byo", d, _tree(d), (d / "meta.json").exists(), d / "meta.json", _meta(d / "meta.json").get("made_by"))
    for d in sorted((root / "ext").glob("*")):
        if d.is_dir():
            yield Entry("kernel", d, _tree(d))


def damage(e: Entry) -> str | None:
    """Why finished entry ``e`` is damaged (None: intact or not checkable)."""
    if not e.finished:
        return None
    try:
        if e.kind == "render":
            check_set(e.path, backfill=False)
        elif e.kind == "features":
            FeatureCache(e.path.parent.parent).load(e.path.parent.name, e.path.stem, mark_used=False)
        elif e.kind == "run":
            check_run(e.path, backfill=False)
        elif e.kind == "byo":
            check_refs(e.path)
    except (DamagedEntry, ValueError, OSError, KeyError, TypeError, AttributeError) as err:
        return str(err)  # DamagedEntry names the file; the others mean an unreadable record
    return None


def _name(e: Entry, root: Path) -> str:
    return str(e.path.relative_to(root))


def _remove(e: Entry) -> None:
    # The lock file stays: a process may be waiting on it, and it is empty.
    if e.kind == "features":
        for f in e.files:
            f.unlink(missing_ok=True)
    else:
        shutil.rmtree(e.path, ignore_errors=True)


def _why_remove(e: Entry, now: float, unused_days: float | None, unfinished: bool) -> str | None:
    idle = now - e.last_use()  # read first: checking a feature file must not count as a use
    why = damage(e)
    if why is None and not e.finished and unfinished:
        why = "unfinished, no live builder (resumable work removed: --unfinished)"
    if why is None and e.finished and unused_days is not None and idle > unused_days * 86400:
        why = f"unused for {idle / 86400:.1f} days"
    return why


def prune(root: Path, unused_days: float | None = None, unfinished: bool = False,
          dry_run: bool = False) -> list[tuple[str, str]]:
    """Remove damaged entries and temporary files that no live process is building or writing;
    with ``unfinished`` also unfinished entries of dead processes (interrupted renders, feature
    files and trainings, which would otherwise resume), with ``unused_days`` finished entries
    unused for that long. Returns [(entry or file, reason)] of what was (``dry_run``: would be)
    removed."""
    out = []
    now = time.time()
    for e in entries(root):
        if e.kind == "kernel":
            continue
        with try_entry_lock(e.path, f"{e.kind} {_name(e, root)}") as free:
            if not free:
                continue  # a live process is building or using it
            why = _why_remove(e, now, unused_days, unfinished)
            if why is not None:
                out.append((_name(e, root), why))
                if not dry_run:
                    _remove(e)
                continue
            for t in e.temporaries():  # left by a killed writer (none is alive: we hold the lock)
                out.append((str(t.relative_to(root)), "temporary file of a dead process"))
                if not dry_run:
                    t.unlink(missing_ok=True)
    return out


def _fmt_row(e: Entry, root: Path) -> dict:
    state = "finished" if e.finished else "unfinished"
    return {"kind": e.kind, "entry": _name(e, root), "state": state, "MB": round(e.size() / 2**20, 1),
            "last_use": time.strftime("%Y-%m-%d %H:%M", time.localtime(e.last_use())),
            "made_by": e.made_by or "-"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m helpers.study.cli.cache", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", default=None, help="cache root (default: $HELPERS_CACHE_DIR or <repo>/cache)")
    sub = ap.add_subparsers(dest="cmd", required=True)
    ls = sub.add_parser("list", help="entries, kinds, sizes, last use, what made them")
    ls.add_argument("--json", action="store_true")
    sub.add_parser("verify", help="check every checksum; exit 1 naming each damaged entry")
    pr = sub.add_parser("prune", help="remove damaged entries and temporary files of dead processes")
    pr.add_argument("--unused-days", type=float, default=None, help="also finished entries unused for N days")
    pr.add_argument("--unfinished", action="store_true",
                    help="also unfinished entries of dead processes (their work would otherwise resume)")
    pr.add_argument("--dry-run", action="store_true")
    a = ap.parse_args(argv)
    root = cache_dir(a.cache)
    if not root.is_dir():
        print(f"error: cache folder {root} does not exist", file=sys.stderr)
        return 2
    if a.cmd == "list":
        rows = [_fmt_row(e, root) for e in entries(root)]
        if a.json:
            print(json.dumps(rows, indent=1))
        else:
            for r in rows:
                print(f"{r['kind']:8s} {r['state']:10s} {r['MB']:9.1f} MB  {r['last_use']}  {r['made_by']:24s} {r['entry']}")
            print(f"{len(rows)} entries, {sum(r['MB'] for r in rows):.1f} MB in {root}")
        return 0
    if a.cmd == "verify":
        bad = [(e, why) for e in entries(root) if (why := damage(e)) is not None]
        for e, why in bad:
            print(f"damaged {e.kind} {_name(e, root)}: {why}")
        print(f"{len(bad)} damaged entries in {root}" if bad else f"all entries intact in {root}")
        return 1 if bad else 0
    removed = prune(root, a.unused_days, a.unfinished, a.dry_run)
    for name, why in removed:
        print(f"{'would remove' if a.dry_run else 'removed'} {name}: {why}")
    print(f"{len(removed)} {'to remove' if a.dry_run else 'removed'} in {root}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
