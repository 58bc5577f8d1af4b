"""Where things live on disk: repository root, caches, run folders.

Nothing here creates directories at import time.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Repository root (``src/helpers/paths.py`` -> three levels up).
REPO_ROOT = Path(__file__).resolve().parents[3]  # src/helpers/core/paths.py -> repository


def is_checkpoint_choice(choice: str) -> bool:
    """True when a model choice names a checkpoint file (``*.pt`` or a path) rather than a zoo model."""
    return choice.endswith(".pt") or "/" in choice or os.sep in choice


def repo_path(path: str | os.PathLike) -> Path:
    """``path`` itself if absolute, else relative to the repository root (where notebook parameters'
    relative paths, such as ``out_dir``, are read from)."""
    p = Path(path).expanduser()
    return p if p.is_absolute() else REPO_ROOT / p


def default_manifest() -> Path:
    """Path of the committed ``data_manifest.yaml``."""
    return REPO_ROOT / "data_manifest.yaml"


def cache_dir(override: str | os.PathLike | None = None) -> Path:
    """Root of content-hashed caches (renders, features).

    Order: explicit ``override`` > ``$HELPERS_CACHE_DIR`` > ``<repo>/cache``.
    """
    if override:
        return Path(override).expanduser().resolve()
    env = os.environ.get("HELPERS_CACHE_DIR")
    if env:
        return Path(env).expanduser().resolve()
    return REPO_ROOT / "cache"


def reports_dir(preset: str | None = None) -> Path:
    """``<repo>/reports`` or ``<repo>/reports/<preset>``."""
    root = REPO_ROOT / "reports"
    return root / preset if preset else root


def _roots() -> list[tuple[str, str]]:
    """(absolute prefix, what it stands for), longest first, so that the most specific role wins
    (a cache or virtual environment inside the repository is named as such)."""
    import sys
    import tempfile

    repo = str(REPO_ROOT)
    pairs = [(str(cache_dir()), "<cache>"), (sys.prefix, "<venv>"), (sys.base_prefix, "<python>"),
             (repo + os.sep, ""), (repo, "."), (os.path.realpath(tempfile.gettempdir()), "<tmp>"),
             (tempfile.gettempdir(), "<tmp>"), (os.path.expanduser("~"), "~")]
    pairs = [(p, r) for p, r in pairs if len(p) > 1]  # never "/" itself
    return sorted(set(pairs), key=lambda pr: -len(pr[0]))


def portable(value: str | os.PathLike) -> str:
    """``value`` with this machine's absolute paths named by their role, so that a result file
    says the same on every machine and tells nothing about it: the cache root becomes
    ``<cache>``, the repository a relative path, the Python environment ``<venv>`` (its base
    installation ``<python>``), the temporary folder ``<tmp>`` and the home folder ``~``."""
    import re

    text = os.fspath(value)
    for prefix, role in _roots():
        # Only whole path components: "/work/main" must not rewrite "/work/main2".
        # ... and only where a path starts: "/tmp" must not rewrite "/var/tmp".
        tail = r"(?![\w-]|\.\w)" if not prefix.endswith(os.sep) else ""
        # (A terminal colour code such as "\x1b[0;32m" may come right before a path in a traceback.)
        text = re.sub(r"(?:(?<![\w.~-])|(?<=\dm))" + re.escape(prefix) + tail, role.replace("\\", "\\\\"), text)
    return text


def portable_obj(obj):
    """:func:`portable` applied to every string inside a JSON-like object (dicts, lists)."""
    if isinstance(obj, dict):
        return {k: portable_obj(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [portable_obj(v) for v in obj]
    if isinstance(obj, (str, Path)):
        return portable(obj)
    return obj
