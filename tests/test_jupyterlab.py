"""JupyterLab works as a user would use it: served headless, lists the study, runs cells in the venv's kernel.

Starts ``jupyter lab`` on 127.0.0.1 (free port, token), waits for it (bounded), checks ``/lab`` and the
contents API, starts a kernel and runs notebook 02's parameters and validation cells through it over the
kernel websocket, then shuts everything down, also when an assertion fails.
"""

from __future__ import annotations

import json
import sys
import time
import urllib.request
import uuid
from pathlib import Path

import pytest
from labserver import get as _get
from labserver import running_lab

from helpers.core.paths import REPO_ROOT
from helpers.study.parameters import NOTEBOOK_DIR

CELL_TIMEOUT_S = 180


def _request(method: str, url: str, body: dict | None = None) -> dict:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method, headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=30) as r:
        raw = r.read()
    return json.loads(raw) if raw else {}


@pytest.fixture
def lab(tmp_path):
    """A running JupyterLab server on the repository: yields (base URL, token); always stopped afterwards."""
    with running_lab(REPO_ROOT, tmp_path) as served:
        yield served


def _execute(ws, session: str, code: str) -> list[dict]:
    """Run ``code`` on the kernel behind websocket ``ws``; returns its iopub messages (raises on error)."""
    msg_id = uuid.uuid4().hex
    ws.send(json.dumps({"header": {"msg_id": msg_id, "username": "test", "session": session, "msg_type":
                                   "execute_request", "version": "5.3"}, "parent_header": {}, "metadata": {},
                        "content": {"code": code, "silent": False, "store_history": False, "user_expressions": {},
                                    "allow_stdin": False, "stop_on_error": True}, "channel": "shell"}))
    out, reply = [], None
    deadline = time.monotonic() + CELL_TIMEOUT_S
    while reply is None or not any(m["msg_type"] == "status" and m["content"]["execution_state"] == "idle"
                                   for m in out):
        if time.monotonic() > deadline:
            raise TimeoutError(f"the kernel did not finish a cell within {CELL_TIMEOUT_S} s")
        m = json.loads(ws.recv())
        if m.get("parent_header", {}).get("msg_id") != msg_id:
            continue
        if m["channel"] == "shell":
            reply = m
        else:
            out.append(m)
    if reply["content"]["status"] != "ok":
        raise AssertionError(f"cell failed: {reply['content'].get('ename')}: {reply['content'].get('evalue')}")
    return out


@pytest.mark.slow
def test_jupyterlab_serves_the_study_and_runs_its_cells(lab, tmp_path):
    import websocket

    base, token = lab
    status, page = _get(f"{base}/lab?token={token}")
    assert status == 200 and b"JupyterLab" in page
    listing = _request("GET", f"{base}/api/contents/notebooks?token={token}")
    names = {c["name"] for c in listing["content"]}
    study = {p.name for p in NOTEBOOK_DIR.glob("[0-9][0-9]_*.ipynb")}
    assert "10_explore.ipynb" in study and study <= names

    kernel = _request("POST", f"{base}/api/kernels?token={token}", {"name": "python3"})
    ws = websocket.create_connection(f"ws://127.0.0.1:{base.rsplit(':', 1)[1]}/api/kernels/{kernel['id']}/channels"
                                     f"?token={token}", timeout=CELL_TIMEOUT_S)
    try:
        session = uuid.uuid4().hex
        # The kernel is the venv's interpreter: the one the study's notebooks use.
        msgs = _execute(ws, session, "import sys; print(sys.executable)")
        printed = "".join(m["content"].get("text", "") for m in msgs if m["msg_type"] == "stream")
        assert Path(printed.strip()).resolve() == Path(sys.executable).resolve()
        nb = json.loads((NOTEBOOK_DIR / "02_train.ipynb").read_text())
        code = [c for c in nb["cells"] if c["cell_type"] == "code"]
        params, check = "".join(code[0]["source"]), "".join(code[1]["source"])
        _execute(ws, session, f"import os; os.chdir({str(NOTEBOOK_DIR)!r})")
        _execute(ws, session, params)
        _execute(ws, session, f"out_dir = {str(tmp_path / 'out')!r}")  # as papermill would inject it
        _execute(ws, session, check)
        msgs = _execute(ws, session, "print(P['split'], P['lr_schedule'], OUT.name)")
        printed = "".join(m["content"].get("text", "") for m in msgs if m["msg_type"] == "stream")
        assert printed.split() == ["1", "step", "out"]
        assert (tmp_path / "out" / "run.json").exists()
    finally:
        ws.close()
        _request("DELETE", f"{base}/api/kernels/{kernel['id']}?token={token}")
