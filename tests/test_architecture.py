"""The package's architecture, checked: layers (import-linter contracts in pyproject.toml), no
function-level imports of the package's own modules, a documented __init__ per layer, short files."""

import ast
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PKG = REPO / "src" / "helpers"
LAYERS = ("core", "data", "net", "training", "search", "evaluation", "study")
#: Longest module (lines) and function (lines, decorators and docstring included) the style allows.
MAX_FILE_LINES, MAX_FUNCTION_LINES = 520, 80


def _modules() -> list[Path]:
    return sorted(PKG.rglob("*.py"))


def test_import_contracts_hold():
    """Lower layers never import higher ones; siblings marked independent never import each other;
    no import cycle between the modules of one layer (pyproject.toml, [tool.importlinter])."""
    exe = Path(sys.executable).parent / "lint-imports"
    res = subprocess.run([str(exe), "--config", str(REPO / "pyproject.toml"), "--no-cache"], cwd=REPO,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-2000:]
    n = len(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"])
    assert n >= 3 and f"{n} kept, 0 broken" in res.stdout, res.stdout[-2000:]


def _type_checking_lines(tree: ast.Module) -> set[int]:
    out = set()
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            out |= {n.lineno for n in ast.walk(node) if hasattr(n, "lineno")}
    return out


def test_no_function_level_imports_of_the_package():
    """Imports of helpers' own modules sit at the top of each module, so the import graph (and
    import-linter) sees every dependency; a deferred one must say why on its line ("# deferred: ...")."""
    bad = []
    for p in _modules():
        src = p.read_text()
        tree, lines = ast.parse(src), src.splitlines()
        skip = _type_checking_lines(tree)
        for node in ast.walk(tree):
            own = isinstance(node, ast.ImportFrom) and (node.level > 0 or (node.module or "").startswith("helpers"))
            own |= isinstance(node, ast.Import) and any(a.name.startswith("helpers") for a in node.names)
            if own and node not in tree.body and node.lineno not in skip \
                    and "# deferred:" not in lines[node.lineno - 1]:
                bad.append(f"{p.relative_to(REPO)}:{node.lineno}: {lines[node.lineno - 1].strip()}")
    assert not bad, "function-level imports of the package:\n" + "\n".join(bad)


@pytest.mark.parametrize("layer", LAYERS)
def test_each_layer_says_what_it_holds_and_may_import(layer):
    doc = ast.get_docstring(ast.parse((PKG / layer / "__init__.py").read_text())) or ""
    assert "May import:" in doc and len(doc) > 120, f"helpers/{layer}/__init__.py: docstring must say what it holds " \
                                                    "and what it may import"


def test_every_module_lives_in_a_layer():
    loose = [p.name for p in PKG.glob("*.py") if p.name != "__init__.py"]
    assert not loose, f"modules outside the layer sub-packages: {loose}"
    assert {p.name for p in PKG.iterdir() if p.is_dir() and not p.name.startswith("__")} == set(LAYERS)


def test_modules_and_functions_stay_short():
    long_files, long_funcs = [], []
    for p in _modules():
        src = p.read_text()
        n = len(src.splitlines())
        if n > MAX_FILE_LINES:
            long_files.append(f"{p.relative_to(REPO)}: {n} lines")
        for node in ast.walk(ast.parse(src)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                start = min([node.lineno] + [d.lineno for d in node.decorator_list])
                if node.end_lineno - start + 1 > MAX_FUNCTION_LINES:
                    long_funcs.append(f"{p.relative_to(REPO)}:{node.lineno} {node.name}: "
                                      f"{node.end_lineno - start + 1} lines")
    assert not long_files and not long_funcs, "\n".join(long_files + long_funcs)
