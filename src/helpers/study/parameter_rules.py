"""What the parameter checks of every notebook share: the error type, its message and the model-choice
rule. :mod:`helpers.study.parameters` checks the names every notebook uses; an experiment module
(:mod:`helpers.study.experiments`) checks its own notebook's names with these."""

from __future__ import annotations

from typing import Any

import yaml

from ..core.paths import REPO_ROOT, is_checkpoint_choice, repo_path


class ParameterError(ValueError):
    """A notebook parameter is unknown, has the wrong type or a value outside its domain."""


def param_error(nb: str, name: str, want: str, value: Any) -> ParameterError:
    """The error for parameter ``name`` of notebook ``nb``: what was expected and what was given."""
    return ParameterError(f"notebook {nb}: parameter {name!r} expects {want}, got {value!r}")


FUSIONS = ("adaptive", "sigmoid", "softmax", "avg")
LEVELS = ("32", "16", "13")


def scales_ok(s: str) -> bool:
    """'global' or a comma list of distinct levels among 32, 16, 13."""
    if s == "global":
        return True
    parts = [p.strip() for p in s.split(",")]
    return bool(parts) and len(set(parts)) == len(parts) and set(parts) <= set(LEVELS)


def zoo_entries() -> dict:
    """models/zoo.yaml's entries by name, read directly: the zoo module pulls in training."""
    zoo_yaml = REPO_ROOT / "models" / "zoo.yaml"
    return (yaml.safe_load(zoo_yaml.read_text()) or {}).get("models") or {} if zoo_yaml.exists() else {}


def check_model_choice(notebook: str, name: str, choice: str, image_size: int) -> None:
    """A model parameter: a zoo model's name taking ``image_size`` px crops, or an existing checkpoint file."""
    if is_checkpoint_choice(choice):
        if not repo_path(choice).is_file():
            raise param_error(notebook, name, "a zoo model name or an existing checkpoint (.pt) file "
                              f"(relative paths from the repository root: {REPO_ROOT})", choice)
        return
    zoo = zoo_entries()
    if choice not in zoo:
        raise param_error(notebook, name, f"a zoo model among {sorted(zoo)} or a checkpoint (.pt) file", choice)
    if zoo[choice]["data"]["image_size"] != image_size:
        raise param_error(notebook, name, f"a model taking image_size={image_size} px crops "
                          f"({choice} takes {zoo[choice]['data']['image_size']})", choice)
