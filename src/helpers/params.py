"""Notebook parameters: the committed ``parameters`` cell is the schema.

Each notebook's first code cell (tagged ``parameters``) holds plain typed
literals. :func:`check_parameters` re-reads that cell from the notebook file,
and checks the values the kernel actually has (defaults, possibly overridden
by papermill's injected cell): unknown names and wrong types are errors that
name the notebook, the parameter and what was expected.
"""

from __future__ import annotations

import ast
import json
from pathlib import Path
from typing import Any

from .paths import REPO_ROOT

NOTEBOOK_DIR = REPO_ROOT / "notebooks"

# Names IPython/papermill put in a kernel's namespace that are not parameters.
_KERNEL_NAMES = {"In", "Out", "get_ipython", "exit", "quit", "open"}


class ParameterError(ValueError):
    """A notebook parameter is unknown, has the wrong type or a value outside its domain."""


def notebook_path(name: str) -> Path:
    p = NOTEBOOK_DIR / (name if name.endswith(".ipynb") else f"{name}.ipynb")
    if not p.exists():
        raise FileNotFoundError(f"notebook {p} does not exist")
    return p


def parameters_source(path: str | Path) -> str:
    """Source of the cell tagged ``parameters`` (must be the first code cell)."""
    nb = json.loads(Path(path).read_text())
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    if not code or "parameters" not in code[0].get("metadata", {}).get("tags", []):
        raise ParameterError(f"{path}: the first code cell must be tagged 'parameters'")
    src = code[0]["source"]
    return "".join(src) if isinstance(src, list) else src


def declared_parameters(path: str | Path) -> dict[str, Any]:
    """{name: default} from the parameters cell; every statement must be
    ``name = <literal>`` (no derived values)."""
    tree = ast.parse(parameters_source(path))
    out = {}
    for node in tree.body:
        if not (isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)):
            raise ParameterError(f"{path}: parameters cell may only hold 'name = literal' lines "
                                 f"(line {node.lineno})")
        try:
            out[node.targets[0].id] = ast.literal_eval(node.value)
        except ValueError:
            raise ParameterError(f"{path}: parameter {node.targets[0].id!r} is not a plain literal "
                                 f"(line {node.lineno})") from None
    return out


def type_name(v: Any) -> str:
    return type(v).__name__


def check_value(nb: str, name: str, default: Any, value: Any) -> Any:
    """Check one value against its default's type; returns it (ints accepted for floats)."""
    if default is None:
        return value
    want = type(default)
    ok = isinstance(value, want) and not (want is int and isinstance(value, bool))
    if want is float and isinstance(value, int) and not isinstance(value, bool):
        ok, value = True, float(value)
    if want is list and ok and default and value:
        et = type(default[0])
        ok = all(isinstance(x, et) and not (et is int and isinstance(x, bool)) for x in value)
    if not ok:
        raise ParameterError(f"notebook {nb}: parameter {name!r} expects {want.__name__}"
                             f"{' of ' + type(default[0]).__name__ if want is list and default else ''}, "
                             f"got {type_name(value)} {value!r}")
    return value


def check_parameters(notebook: str, namespace: dict[str, Any]) -> dict[str, Any]:
    """Validate a kernel namespace against ``notebooks/<notebook>.ipynb``'s parameters cell.

    Returns {name: value} of the parameters. Raises ParameterError on a name
    that is not a declared parameter, on a value of another type, or on a value
    outside its domain (:func:`helpers.param_values.check_values`).
    """
    from .param_values import check_values

    declared = declared_parameters(notebook_path(notebook))
    P = check_mapping(notebook, declared, {k: v for k, v in namespace.items() if _is_user_name(k, v)})
    check_values(notebook, P)
    return P


def check_mapping(notebook: str, declared: dict[str, Any], given: dict[str, Any]) -> dict[str, Any]:
    """Validate ``given`` names/types against ``declared`` defaults; missing ones take defaults."""
    unknown = sorted(set(given) - set(declared))
    if unknown:
        raise ParameterError(f"notebook {notebook}: unknown parameter(s) {unknown}; "
                             f"declared: {sorted(declared)}")
    out = dict(declared)
    for k, v in given.items():
        out[k] = check_value(notebook, k, declared[k], v)
    return out


def _is_user_name(k: str, v: Any) -> bool:
    if k.startswith("_") or k in _KERNEL_NAMES:
        return False
    # Modules, functions and classes imported before the check are not parameters.
    return not (callable(v) or type(v).__name__ == "module")
