"""The fusion kernel's build can never hang a run (stale locks, live builders, time limit)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time

import pytest

from helpers.net import fusion_kernel


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait(timeout=60)
    return p.pid


def _write_lock(where, pid: int) -> None:
    (where / "helpers_build.lock").write_text(json.dumps({"pid": pid, "host": socket.gethostname(),
                                                          "started": time.time()}))


def test_stale_lock_of_dead_process_is_cleared(tmp_path):
    _write_lock(tmp_path, _dead_pid())
    (tmp_path / "lock").write_text("")  # torch's own baton, left by the interrupted build
    t0 = time.monotonic()
    with pytest.warns(RuntimeWarning, match="stale build lock"):
        assert fusion_kernel.acquire_build_lock(tmp_path, timeout=30)
    assert time.monotonic() - t0 < 5
    assert not (tmp_path / "lock").exists()
    assert json.loads((tmp_path / "helpers_build.lock").read_text())["pid"] == os.getpid()
    fusion_kernel.release_build_lock(tmp_path)
    assert not (tmp_path / "helpers_build.lock").exists()


def test_live_builder_is_waited_for_with_messages_then_given_up(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        _write_lock(tmp_path, holder.pid)
        t0 = time.monotonic()
        with pytest.warns(RuntimeWarning, match=f"process {holder.pid}"):
            got = fusion_kernel.acquire_build_lock(tmp_path, timeout=1.5, poll=0.1, report_every=0.3)
        assert got is False
        assert 1.4 < time.monotonic() - t0 < 10
        assert (tmp_path / "helpers_build.lock").exists()  # a live build's lock is left alone
    finally:
        holder.kill()
        holder.wait(timeout=30)


def _run_get(env: dict, timeout: float = 240) -> subprocess.CompletedProcess:
    code = ("import warnings, time; warnings.simplefilter('always'); from helpers.net import fusion_kernel as f; "
            "t=time.monotonic(); m=f.get(); print('MODULE', m is not None, round(time.monotonic()-t, 1)); "
            "print('REASON', f.status()['reason'])")
    return subprocess.run([sys.executable, "-c", code], env={**os.environ, **env}, capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.skipif(fusion_kernel.get() is None, reason="no C++ toolchain: the kernel cannot build here")
def test_leftover_locks_from_a_killed_run_do_not_block_a_fresh_run(tmp_path):
    # A copy of the built extension, as a run interrupted during the build leaves it: both locks present.
    built = fusion_kernel.build_dir()
    ext = tmp_path / "ext"
    shutil.copytree(built, ext / built.name)
    _write_lock(ext / built.name, _dead_pid())
    (ext / built.name / "lock").write_text("")
    r = _run_get({"HELPERS_EXT_DIR": str(ext)})
    assert "MODULE True" in r.stdout, r.stdout + r.stderr
    assert "stale build lock" in r.stderr


def test_build_waiting_on_a_live_lock_falls_back_to_eager_after_the_limit(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        ext = tmp_path / "ext"
        env = {"HELPERS_EXT_DIR": str(ext), "HELPERS_KERNEL_BUILD_TIMEOUT": "3"}
        # The build folder name does not depend on HELPERS_EXT_DIR's value, only on the source and machine.
        where = ext / fusion_kernel.build_dir().name
        where.mkdir(parents=True)
        _write_lock(where, holder.pid)
        t0 = time.monotonic()
        r = _run_get(env, timeout=120)
        assert time.monotonic() - t0 < 90
        assert "MODULE False" in r.stdout, r.stdout + r.stderr
        assert "TimeoutError" in r.stdout and f"process {holder.pid}" in r.stdout
        assert "eager" in r.stderr
    finally:
        holder.kill()
        holder.wait(timeout=30)


def test_bad_timeout_value_is_named(monkeypatch):
    monkeypatch.setenv("HELPERS_KERNEL_BUILD_TIMEOUT", "soon")
    with pytest.raises(ValueError, match="HELPERS_KERNEL_BUILD_TIMEOUT"):
        fusion_kernel._timeout()
