"""Field validators shared by the config dataclasses: each raises ValueError naming class, field and what was expected."""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np


def _ints(obj: object, names: tuple[str, ...], lo: int = 1, none_ok: bool = False) -> None:
    """Each named field an int >= ``lo`` (or None when ``none_ok``), stored as a Python int."""
    for name in names:
        v = getattr(obj, name)
        if none_ok and v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{type(obj).__name__}.{name}: expected an int >= {lo}{' or None' if none_ok else ''}, "
                             f"got {v!r}")
        object.__setattr__(obj, name, int(v))  # (frozen dataclasses too)


def _bools(obj: object, names: tuple[str, ...]) -> None:
    for name in names:
        v = getattr(obj, name)
        if not isinstance(v, (bool, np.bool_)):
            raise ValueError(f"{type(obj).__name__}.{name}: expected a bool, got {v!r}")
        object.__setattr__(obj, name, bool(v))


def _choice(obj: object, name: str, options: tuple | dict) -> None:
    if getattr(obj, name) not in options:
        raise ValueError(f"{type(obj).__name__}.{name}: expected one of {tuple(options)}, got {getattr(obj, name)!r}")


def _from_dict(cls: type, d: dict) -> Any:
    """``cls(**d)``; unknown keys are an error naming the class."""
    unknown = set(d) - {f.name for f in fields(cls)}
    if unknown:
        raise ValueError(f"{cls.__name__}.from_dict: unknown keys {sorted(unknown)}")
    return cls(**d)
