"""Where things live on disk: repository root, caches, run folders.

Nothing here creates directories at import time.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Repository root (``src/helpers/paths.py`` -> three levels up).
REPO_ROOT = Path(__file__).resolve().parents[2]


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
