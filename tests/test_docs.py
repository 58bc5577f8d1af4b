"""The Markdown files name only paths that exist: a moved module or a retired report folder named as if it were
there is a stale instruction to a reader."""

import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: What a named path may be relative to: the Markdown file's folder, the repository, the package, a report.
BASES = (REPO, REPO / "src", REPO / "src" / "helpers", REPO / "reports" / "quick")
EXTENSIONS = (".py", ".md", ".yaml", ".yml", ".ipynb", ".png", ".json", ".csv", ".sh", ".cpp", ".toml", ".lock",
              ".pt", ".npz")
_TOKEN = re.compile(r"`([^`\s]+)`|\]\(([^)\s]+)\)")


def _markdown_files() -> list[Path]:
    out = subprocess.run(["git", "ls-files", "*.md"], cwd=REPO, capture_output=True, text=True, timeout=60).stdout
    # The generated reports (REPORT.md, tables) are checked by the tests of what the notebooks write.
    return [REPO / f for f in out.split() if not (f.startswith("reports/quick/") and f.count("/") > 2)
            and not f.endswith("REPORT.md")]


def _named_paths(line: str) -> list[str]:
    """Path-like tokens of a line (code spans and link targets with a folder and a known file ending), without
    placeholders (<name>, *, PRESET) and web addresses; a 'x.csv/.md' pair names x.csv."""
    out = []
    for m in _TOKEN.finditer(line):
        p = (m.group(1) or m.group(2)).split("#")[0].rstrip(".,:;").removesuffix("/.md")
        if not p or "://" in p or any(c in p for c in "<>*{}$") or any(seg.isupper() for seg in p.split("/")):
            continue
        if "/" in p.rstrip("/") and (p.endswith(EXTENSIONS) or p.endswith("/")):
            out.append(p)
    return out


def _generated(p: str) -> bool:
    """A path git ignores (reports/smoke/, cache/, .venv/): written by runs, so absent from a fresh clone."""
    return subprocess.run(["git", "check-ignore", "-q", p], cwd=REPO, timeout=60).returncode == 0


def _exists(md: Path, p: str) -> bool:
    bases = (md.parent, *BASES, *sorted((REPO / "reports" / "quick").glob("[0-9][0-9]_*/")))
    return any((b / p).exists() for b in bases) or _generated(p)


def test_every_path_named_in_markdown_exists():
    missing = []
    for md in _markdown_files():
        for n, line in enumerate(md.read_text().splitlines(), 1):
            if "git show" in line or "retired" in line:  # history, named as such
                continue
            missing += [f"{md.relative_to(REPO)}:{n}: {p}" for p in _named_paths(line) if not _exists(md, p)]
    assert not missing, "paths named in Markdown that do not exist:\n" + "\n".join(missing)


def test_the_check_sees_a_stale_path(tmp_path):
    md = tmp_path / "x.md"
    md.write_text("see `helpers/augment.py` and [the report](reports/quick/REPORT.md)\n")
    assert _named_paths(md.read_text()) == ["helpers/augment.py", "reports/quick/REPORT.md"]
    assert not _exists(md, "helpers/augment.py") and _exists(md, "reports/quick/REPORT.md")
    assert _exists(md, "training/augment.py") and _exists(md, "table1_searches.csv")  # package- and report-relative
    assert _exists(md, "reports/smoke/") and _exists(md, "cache/")  # ignored by git: made by runs, maybe not yet
