"""The explorer notebook in a real browser: JupyterLab served headless, driven by Playwright in Debian's Chromium.

Opens a copy of ``notebooks/10_explore.ipynb`` (a copy, so JupyterLab's autosave never writes outputs into the
committed notebook), runs all cells from the Run menu as a reader would, reads the verdict line and the figure
the page shows, moves the query slider with the keyboard, and checks that the page then shows another query
and another figure. Everything is bounded in time and stopped afterwards. Skipped, saying why, only where
Chromium or Playwright is not installed (``scripts/setup.sh`` installs both). With ``HELPERS_SCREENSHOT=<png>``
the final page is also saved there (``reports/quick/explorer.png`` is made that way).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from labserver import running_lab

from helpers.study.parameters import NOTEBOOK_DIR

RUN_TIMEOUT_MS = 600_000  # the whole smoke notebook on a busy 2-core machine, renders included
STEP_TIMEOUT_MS = 120_000  # one slider move: one query's scores and figure
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _chromium() -> str:
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        pytest.skip("Debian's chromium is not installed (scripts/setup.sh installs it with apt)")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        pytest.skip("playwright is not installed in the venv (environment.lock pins it)")
    return path


def _explorer_copy(folder: Path) -> Path:
    """The explorer notebook with its out_dir pointing into ``folder``."""
    nb = json.loads((NOTEBOOK_DIR / "10_explore.ipynb").read_text())
    src = "".join(nb["cells"][1]["source"])
    new = src.replace('out_dir = "reports/smoke/10_explore"', f'out_dir = "{folder / "out"}"')
    assert new != src, "the explorer's parameters cell no longer sets out_dir = \"reports/smoke/10_explore\""
    nb["cells"][1]["source"] = new
    path = folder / "10_explore.ipynb"
    path.write_text(json.dumps(nb))
    return path


def _shown(page) -> tuple[str, str]:
    """(verdict line, figure image source) as the page displays them."""
    return page.inner_text(".explore-summary"), page.get_attribute("img.explore-figure", "src") or ""


@pytest.mark.slow
def test_explorer_runs_and_follows_the_query_slider(tmp_path):
    chromium = _chromium()
    from playwright.sync_api import sync_playwright

    root = tmp_path / "lab"
    root.mkdir()
    _explorer_copy(root)
    with running_lab(root, tmp_path) as (base, token), sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, headless=True, args=CHROMIUM_FLAGS)
        print(f"chromium {browser.version} driven by playwright")
        page = None
        try:
            page = browser.new_page(viewport={"width": 1500, "height": 1100})
            page.goto(f"{base}/lab/tree/10_explore.ipynb?token={token}", timeout=STEP_TIMEOUT_MS)
            page.wait_for_selector(".jp-Notebook .jp-Cell", timeout=STEP_TIMEOUT_MS)
            # The kernel is connected and idle once the status bar says so (the notebook's own indicator
            # reads "idle" before a kernel exists).
            page.get_by_text("Python 3 (ipykernel) | Idle").wait_for(timeout=STEP_TIMEOUT_MS)
            page.get_by_role("menuitem", name="Run", exact=True).click()
            page.get_by_role("menuitem", name="Run All Cells", exact=True).click()
            page.wait_for_function(
                "() => { const s = document.querySelector('.explore-summary');"
                " const i = document.querySelector('img.explore-figure');"
                " return s && s.innerText.includes('top-1') && i && (i.getAttribute('src') || '').length > 0 }",
                timeout=RUN_TIMEOUT_MS)
            # The last cells (the upload panel renders its references) run after the query panel appears;
            # the slider's change would queue behind them, so wait until the notebook has finished.
            page.wait_for_selector(".byo-run", timeout=RUN_TIMEOUT_MS)
            page.get_by_text("Python 3 (ipykernel) | Idle").wait_for(timeout=RUN_TIMEOUT_MS)
            before = _shown(page)
            assert "query" in before[0] and "#0" in before[0], before[0]
            page.locator(".explore-query .noUi-handle").first.focus()
            page.keyboard.press("ArrowRight")
            page.wait_for_function(
                "(old) => { const s = document.querySelector('.explore-summary');"
                " return s && s.innerText.includes('top-1') && s.innerText !== old }",
                arg=before[0], timeout=STEP_TIMEOUT_MS)
            page.wait_for_function(
                "(old) => (document.querySelector('img.explore-figure').getAttribute('src') || '') !== old",
                arg=before[1], timeout=STEP_TIMEOUT_MS)
            after = _shown(page)
            assert "#1" in after[0] and after[0] != before[0], (before[0], after[0])
            assert after[1] and after[1] != before[1]
            assert page.inner_text(".explore-query .widget-readout").strip() == "1"
            page.locator("img.explore-figure").scroll_into_view_if_needed()
            shot = page.screenshot(path=str(tmp_path / "explorer.png"))
            assert len(shot) > 10_000
            if os.environ.get("HELPERS_SCREENSHOT"):
                Path(os.environ["HELPERS_SCREENSHOT"]).write_bytes(shot)
        except Exception:
            if page is not None:
                _diagnose(page, tmp_path)
            raise
        finally:
            browser.close()


def _diagnose(page, folder: Path) -> None:
    """On a failure: a screenshot and the notebook's error outputs, named in the test's output."""
    try:
        page.screenshot(path=str(folder / "failure.png"), full_page=True)
        errs = [e.inner_text()[-1500:] for e in
                page.query_selector_all(".jp-OutputArea-output[data-mime-type='application/vnd.jupyter.stderr']")]
        print(f"browser test failed; screenshot {folder / 'failure.png'}; error outputs: {errs}")
    except Exception as e:  # the page may be gone; the original failure is what matters
        print(f"browser test failed; no diagnosis ({e})")
