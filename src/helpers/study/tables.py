"""Tables written as CSV and Markdown side by side."""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd

from ..core.fileio import atomic_write_text


def write_table(df: pd.DataFrame, path_stem: str | os.PathLike, floatfmt: str = ".2f", index: bool = False) -> tuple[Path, Path]:
    """Write ``<stem>.csv`` and ``<stem>.md``; returns both paths."""
    stem = Path(path_stem)
    csv = atomic_write_text(stem.with_suffix(".csv"), df.to_csv(index=index))
    md = atomic_write_text(stem.with_suffix(".md"), df.to_markdown(index=index, floatfmt=floatfmt) + "\n")
    return csv, md
