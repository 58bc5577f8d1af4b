"""Several processes on one cache, killed builders, damaged entries, and the cache command.

The builds are real (render sets, feature files, training runs of tests/cache_worker.py) and
run in separate processes, as they would when two notebooks or runners share one cache.
"""

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from helpers.core.fileio import DamagedEntry
from helpers.core.locks import LockTimeout, entry_lock, is_locked
from helpers.study.cli import cache as cache_cli

pytestmark = pytest.mark.gl
WORKER = Path(__file__).with_name("cache_worker.py")
KINDS = ("render", "features", "train")
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


def _start(kind: str, cache: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(WORKER), kind, str(cache)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV)


def _result(p: subprocess.Popen, timeout: float = 600) -> str:
    out, err = p.communicate(timeout=timeout)
    assert p.returncode == 0, err[-4000:]
    return re.search(r"^result ([0-9a-f]{64})$", out, re.M).group(1)


def _leftovers(cache: Path) -> list[Path]:
    """Temporary files and owner records: none may remain once every builder has finished."""
    return [f for f in cache.rglob("*") if f.is_file() and f.name.endswith((".tmp", ".partial", ".owner"))]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Each kind built once by one process: its digest and duration. Features and training
    start from a cache that already holds the renders they need (kept as a template), so that
    the kill tests' random moments fall inside the build proper."""
    out = {}
    for kind in KINDS:
        root = tmp_path_factory.mktemp(f"single-{kind}")
        template = root / "renders-only"
        if kind != "render":
            _result(_start("render" if kind == "features" else "train-data", template))
        out[kind] = {"renders": template}
        cache = _fresh(out, kind, root / "cache")
        p = _start(kind, cache)
        p.stdout.readline()
        t0 = time.monotonic()
        out[kind].update(digest=_result(p), seconds=time.monotonic() - t0)
    return out


def _fresh(ref: dict, kind: str, dst: Path) -> Path:
    """An empty cache (render) or a copy of the kind's renders-only template."""
    if kind != "render":
        shutil.copytree(ref[kind]["renders"], dst)
    return dst


@pytest.mark.parametrize("kind", KINDS)
def test_three_processes_build_one_entry_at_once_and_agree(reference, tmp_path, kind):
    cache = _fresh(reference, kind, tmp_path / "cache")
    procs = [_start(kind, cache) for _ in range(3)]
    outs = [p.communicate(timeout=600) for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0], [e[-3000:] for _, e in outs]
    digests = [re.search(r"^result ([0-9a-f]{64})$", o, re.M).group(1) for o, _ in outs]
    assert digests == [reference[kind]["digest"]] * 3  # byte-identical to a single-process build
    assert sum(o.count("building") for o, _ in outs) == 1  # one built it, the others waited and loaded it
    assert _leftovers(cache) == []


@pytest.mark.parametrize("kind", KINDS)
def test_a_build_killed_at_a_random_moment_is_finished_by_a_rerun(reference, tmp_path, kind):
    import cache_worker

    rng = np.random.default_rng(7)
    for seed in range(10):
        cache = _fresh(reference, kind, tmp_path / f"cache{seed}")
        p = _start(kind, cache)
        assert p.stdout.readline().strip() == "ready"
        time.sleep(rng.uniform(0.0, reference[kind]["seconds"]))
        p.send_signal(signal.SIGKILL)
        p.communicate()
        assert cache_worker.build(kind, str(cache)) == reference[kind]["digest"], f"seed {seed}"  # rerun here
        assert _leftovers(cache) == [], f"seed {seed}"
        shutil.rmtree(cache)


def _finished(reference, kind: str, dst: Path) -> Path:
    cache = _fresh(reference, kind, dst)
    assert _result(_start(kind, cache)) == reference[kind]["digest"]
    return cache


def _truncate(path: Path) -> None:
    with open(path, "r+b") as f:
        f.truncate(path.stat().st_size // 2)


def test_damaged_render_set_and_feature_file_are_rebuilt(reference, tmp_path):
    import cache_worker

    cache = _finished(reference, "features", tmp_path / "cache")
    _truncate(next(cache.glob("features/*/*.f16")))
    with pytest.warns(RuntimeWarning, match=r"\.f16: size .* rebuilding it"):
        assert cache_worker.build("features", str(cache)) == reference["features"]["digest"]
    images = next(cache.glob("renders/duck/reference-*/images.npy"))
    _truncate(images)
    with pytest.warns(RuntimeWarning, match=r"images\.npy: content does not match the sha256 .* re-rendering"):
        assert cache_worker.build("render", str(cache)) == reference["render"]["digest"]


def test_damaged_checkpoint_is_named_then_verify_finds_it_and_prune_removes_it(reference, tmp_path, capsys):
    import cache_worker

    cache = _finished(reference, "train", tmp_path / "cache")
    assert cache_cli.main(["--cache", str(cache), "verify"]) == 0
    best = next(cache.glob("runs/split1-*/best.pt"))
    _truncate(best)
    with pytest.raises(DamagedEntry, match=r"best\.pt: content does not match .*helpers\.study\.cli\.cache prune"):
        cache_worker.build("train", str(cache))
    capsys.readouterr()
    assert cache_cli.main(["--cache", str(cache), "verify"]) == 1
    out = capsys.readouterr().out
    assert f"damaged run {best.parent.relative_to(cache)}" in out and "best.pt" in out
    assert cache_cli.main(["--cache", str(cache), "prune", "--dry-run"]) == 0
    assert best.exists()
    assert cache_cli.main(["--cache", str(cache), "prune"]) == 0
    assert not best.parent.exists()
    assert cache_cli.main(["--cache", str(cache), "verify"]) == 0
    assert cache_worker.build("train", str(cache)) == reference["train"]["digest"]  # retrained, same weights
    assert cache_cli.main(["--cache", str(cache), "list"]) == 0
    listing = capsys.readouterr().out
    assert "run      finished" in listing and "render   finished" in listing


def test_prune_leaves_what_a_live_process_builds_and_removes_unfinished_and_stale(tmp_path, capsys):
    from helpers.core.fileio import atomic_save_npy, atomic_write_json, sha256_file

    cache = tmp_path / "cache"
    live, dead = cache / "renders" / "duck" / "reference-live", cache / "renders" / "duck" / "reference-dead"
    for d in (live, dead):
        d.mkdir(parents=True)
        (d / "chunk_00000.npz").write_bytes(b"x")
    old = cache / "byo" / "mesh-old"  # a finished, intact entry last used 10 days ago, with a stray temporary
    atomic_save_npy(old / "images.npy", np.zeros((2, 4, 4, 3), np.uint8))
    atomic_save_npy(old / "rotations.npy", np.tile(np.eye(3, dtype=np.float32), (2, 1, 1)))
    atomic_write_json(old / "meta.json", {"sha256": {f: sha256_file(old / f) for f in ("images.npy", "rotations.npy")}})
    (old / ".images.npy.x1.tmp").write_bytes(b"half")
    ten_days_ago = time.time() - 10 * 86400
    os.utime(old / "meta.json", (ten_days_ago, ten_days_ago))
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from helpers.core.locks import entry_lock\n"
                               f"with entry_lock({str(live)!r}, 'test'):\n print('held', flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, text=True, env=ENV)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert is_locked(live) and not is_locked(dead)
        assert cache_cli.main(["--cache", str(cache), "prune"]) == 0  # resumable work and used entries stay
        assert live.exists() and dead.exists() and (old / "meta.json").exists()
        assert not (old / ".images.npy.x1.tmp").exists()
        assert "temporary file of a dead process" in capsys.readouterr().out
        assert cache_cli.main(["--cache", str(cache), "prune", "--unfinished", "--unused-days", "5"]) == 0
        assert live.exists() and not dead.exists() and not old.exists()
        out = capsys.readouterr().out
        assert "reference-dead: unfinished, no live builder" in out and "mesh-old: unused for 10.0 days" in out
    finally:
        holder.kill()
        holder.communicate()


def test_waiting_for_a_live_builder_says_so_and_has_a_limit(tmp_path, capsys):
    entry = tmp_path / "entry"
    holder = subprocess.Popen([sys.executable, "-c", "import time; from helpers.core.locks import entry_lock\n"
                               f"with entry_lock({str(entry)!r}, 'test'):\n print('held', flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, text=True, env=ENV)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(LockTimeout, match=rf"my entry: waited \d+ s for process {holder.pid} on"):
            with entry_lock(entry, "my entry", timeout=1.0, report_every=0.3):
                pass
        assert f"my entry: waiting for process {holder.pid}" in capsys.readouterr().err
    finally:
        holder.kill()
        holder.communicate()
    # The killed holder's lock went with it; its owner record tells the next one what happened.
    with pytest.warns(RuntimeWarning, match=f"previous builder, process {holder.pid} .* died"):
        with entry_lock(entry, "my entry", timeout=5.0):
            assert is_locked(entry)
    assert not is_locked(entry)


@pytest.mark.slow
def test_two_smoke_runners_on_one_cache_both_succeed(tmp_path):
    """Two runners share one empty cache: renders (01), the training run both 02 and 03 read, reference
    features and per-query evaluations (03), the T-LESS-like set (09), and one report folder each.
    The other notebooks build no other kind of entry and nbval runs every notebook anyway, so they are
    left out to keep CI short."""
    env = {**ENV, "HELPERS_CACHE_DIR": str(tmp_path / "cache")}
    cmd = [sys.executable, "-m", "helpers.study.cli.runner", "smoke", "--no-html",
           "--only", "01_render", "02_train", "03_evaluate", "09_tless"]
    t0 = time.monotonic()
    procs = [subprocess.Popen(cmd + ["--reports", str(tmp_path / f"reports{k}")], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True) for k in range(2)]
    outs = [p.communicate(timeout=2400)[0] for p in procs]
    for p, out in zip(procs, outs):
        assert p.returncode == 0, out[-4000:]
    print(f"two concurrent smoke runs: {time.monotonic() - t0:.0f} s")
    for k in range(2):
        claims = tmp_path / f"reports{k}" / "smoke" / "claims.json"
        assert claims.exists()
        for f in (tmp_path / f"reports{k}").rglob("*"):
            if f.suffix in (".json", ".ipynb", ".md", ".csv"):
                assert str(tmp_path) not in f.read_text(errors="replace"), f"{f} holds a machine path"
    assert _leftovers(tmp_path / "cache") == []


# Absolute paths in committed results: any "/dir/..." at the start of a token, except the system
# interfaces that read the same on every Linux machine.
_ABS = re.compile(r"""(?:^|[\s"'(=:,\[])(/[A-Za-z_.][\w.+-]*/[\w.+-]+)""", re.M)
_SYSTEM = ("/proc/", "/sys/", "/dev/")


def test_no_committed_result_holds_a_machine_path():
    repo = Path(__file__).resolve().parents[1]
    files = subprocess.run(["git", "ls-files", "reports", "benchmarks/results"], cwd=repo, capture_output=True,
                           text=True, check=True).stdout.split()
    assert files
    found = []
    for f in files:
        try:
            text = (repo / f).read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue  # images
        found += [(f, m) for m in _ABS.findall(text) if not m.startswith(_SYSTEM)]
    assert found == [], found[:10]


def test_portable_names_paths_by_their_role(monkeypatch, tmp_path):
    from helpers.core.paths import REPO_ROOT, portable, portable_obj

    monkeypatch.setenv("HELPERS_CACHE_DIR", str(tmp_path / "c"))
    assert portable(tmp_path / "c" / "runs" / "x" / "best.pt") == "<cache>/runs/x/best.pt"
    assert portable(REPO_ROOT / "reports" / "quick") == "reports/quick"
    assert portable(f"{sys.prefix}/lib/site-packages/m.py") == "<venv>/lib/site-packages/m.py"
    other = portable(f"{REPO_ROOT}2/x")  # another folder that only starts alike: not the repository
    assert other.endswith(f"{REPO_ROOT.name}2/x") and not other.startswith(("2/", ".2"))
    assert portable_obj({"a": [str(tmp_path / "c")], "n": 3}) == {"a": ["<cache>"], "n": 3}
    assert _ABS.findall(portable(f"see {tmp_path}/out.png")) == []
    assert portable(f"\x1b[0;32m{REPO_ROOT}/src/x.py\x1b[0m") == "\x1b[0;32msrc/x.py\x1b[0m"  # a traceback's colours


def test_the_next_holder_removes_an_owner_record_half_written_by_a_killed_one(tmp_path):
    """A builder killed while writing its owner record leaves that write's temporary beside the lock;
    the next process to take the lock removes it (only a holder writes the record)."""
    from helpers.core.locks import lock_path

    entry = tmp_path / "entry"
    stray = lock_path(entry).with_name(f".{lock_path(entry).name}.owner.abc123.tmp")
    stray.write_text('{"pid": 1')
    other = tmp_path / ".other.lock.owner.abc123.tmp"  # another entry's: left alone
    other.write_text("{}")
    with entry_lock(entry, "my entry"):
        assert not stray.exists()
    assert other.exists() and _leftovers(tmp_path) == [other]


def test_settle_removes_the_record_of_a_builder_that_died_after_finishing(tmp_path):
    """A builder killed between finishing its entry and releasing the lock leaves its owner record; a
    later process that finds the entry finished (without locking it) removes it, unless a live one holds it."""
    from helpers.core.locks import lock_path, settle

    entry = tmp_path / "entry"
    owner = lock_path(entry).with_name(lock_path(entry).name + ".owner")
    owner.write_text('{"pid": 1}')
    settle(entry)
    assert not owner.exists() and _leftovers(tmp_path) == []
    settle(entry)  # nothing to do
    holder = subprocess.Popen([sys.executable, "-c", "import time; from helpers.core.locks import entry_lock\n"
                               f"with entry_lock({str(entry)!r}, 'test'):\n print('held', flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        settle(entry)  # a live builder's record stays
        assert owner.exists()
    finally:
        holder.kill()
        holder.wait()
