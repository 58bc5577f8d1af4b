"""Notebook parameters: names and types from each notebook's ``parameters`` cell, values from rules
here, and the typed configurations built from them.

Each notebook's first code cell (tagged ``parameters``) holds plain typed literals; it is the schema.
:func:`check_parameters` (the notebook's second cell) re-reads that cell from the notebook file and
checks the values the kernel actually has (defaults, possibly overridden by papermill's injected
cell): unknown names and wrong types (:func:`check_mapping`), then values out of their domain
(:func:`check_values`: ``-p fusion adaptve``, ``-p epochs -1``), so a bad value stops the run there
with a message naming the notebook, the parameter and what was expected, instead of minutes later
inside training. :func:`configs_from` then turns the checked parameters into the typed
configurations (:mod:`helpers.core.configs`) that every later step takes.
"""

from __future__ import annotations

import ast
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..core.configs import (QUERY_STYLES, AugmentConfig, DataConfig, ModelConfig, SearchConfig, TrainConfig,
                            paper_ratio_search, parse_scales)
from ..core.paths import REPO_ROOT, repo_path
from ..data.bop import BOPFormatError
from ..data.linemod_real import bop_folders
from ..evaluation.paper import COMPONENT_LABELS
from .experiments import experiment
from .parameter_rules import FUSIONS, ParameterError, check_model_choice, scales_ok, zoo_entries
from .parameter_rules import param_error as _err

NOTEBOOK_DIR = REPO_ROOT / "notebooks"

# Names IPython/papermill put in a kernel's namespace that are not parameters.
_KERNEL_NAMES = {"In", "Out", "get_ipython", "exit", "quit", "open"}


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
    outside its domain (:func:`check_values`).
    """
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


_SPLITS = (1, 2, 3)

# name -> minimum allowed integer value
_MIN_INT = {
    "image_size": 64, "render_size": 64, "n_references": 1, "n_train_queries": 1, "n_val_queries": 1,
    "n_test_queries": 1, "epochs": 1, "batch_size": 1, "val_every": 1, "val_refs": 1, "k_ac": 0, "fps_k": 0,
    "byo_refs": 1, "group": 1, "query_batch": 1, "norm_window": 2,
    "seed": 0, "workers": 0, "steps_per_epoch": 0, "warmup_steps": 0, "clean_steps": 0, "seen_queries": 0,
    "occluded_queries": 0, "eval_refs": 0, "byo_queries": 0, "zoo_steps": 0,
    "n_seeds": 1, "test_queries": 0, "query": 0, "top_k": 1, "n_queries": 1, "old_k_ac": 1, "old_fps_k": 1,
}
_CHOICES = {
    "lr_schedule": ("step", "cosine"),
    "random_ref": ("own", "any"),
    "fusion": FUSIONS,
    "eval_method": ("fast", "greedy", "density"),
    "models": ("train", "zoo"),
}


def check_values(notebook: str, P: dict[str, Any]) -> None:
    """Raise :class:`ParameterError` on the first parameter value out of its domain.

    ``P`` holds already type-checked values (see :func:`check_mapping`).
    Names this module has no rule for are left alone.
    """
    for name, lo in _MIN_INT.items():
        if name in P and P[name] < lo:
            raise _err(notebook, name, f"an int >= {lo}", P[name])
    for name, options in _CHOICES.items():
        if name in P and P[name] not in options:
            raise _err(notebook, name, f"one of {list(options)}", P[name])
    if "query_style" in P and P["query_style"] not in QUERY_STYLES:
        raise _err(notebook, "query_style", f"one of {list(QUERY_STYLES)}", P["query_style"])
    if "lr" in P and not P["lr"] > 0:
        raise _err(notebook, "lr", "a learning rate > 0", P["lr"])
    if "train_context" in P and not 1.0 <= P["train_context"] <= 2.0:
        raise _err(notebook, "train_context", "a crop-side multiple in [1, 2]", P["train_context"])
    if "render_size" in P and "image_size" in P and P["render_size"] < P["image_size"]:
        raise _err(notebook, "render_size", f">= image_size ({P['image_size']})", P["render_size"])
    if "split" in P and P["split"] not in _SPLITS:
        raise _err(notebook, "split", f"one of {list(_SPLITS)}", P["split"])
    if P.get("zoo_steps") and P.get("models") == "zoo":
        _check_zoo_steps(notebook, P["zoo_steps"])
    for name in ("splits", "baseline_splits"):
        v = P.get(name)
        if v is not None and (not v or len(set(v)) != len(v) or not set(v) <= set(_SPLITS)):
            raise _err(notebook, name, f"a non-empty list of distinct splits among {list(_SPLITS)}", v)
    if "scales" in P and not scales_ok(P["scales"]):
        raise _err(notebook, "scales", "'global' or a comma list of 32/16/13", P["scales"])
    if "variants" in P:
        _check_variants(notebook, P["variants"])
    exp = experiment(notebook)
    if exp is not None and exp.check is not None:  # what only this notebook's parameters need
        exp.check(notebook, P)
    if "seeded_variants" in P:
        _check_seeded(notebook, P["seeded_variants"], P.get("variants"))
    if "test_queries" in P and P.get("n_test_queries") is not None and P["test_queries"] > P["n_test_queries"]:
        raise _err(notebook, "test_queries", f"0 (all) or at most n_test_queries={P['n_test_queries']}",
                   P["test_queries"])
    if "byo_queries" in P and P.get("n_test_queries") is not None:  # 10: the photos come from the test set
        cap, what = (P["test_queries"], "test_queries") if P.get("test_queries") else (P["n_test_queries"],
                                                                                        "n_test_queries")
        if P["byo_queries"] > cap:
            raise _err(notebook, "byo_queries", f"0 (all) or at most {what}={cap}", P["byo_queries"])
    if "reference_counts" in P:
        rc = P["reference_counts"]
        if not rc or any(c < 1 for c in rc) or list(rc) != sorted(set(rc)):
            raise _err(notebook, "reference_counts", "a non-empty ascending list of distinct counts >= 1", rc)
    if "device" in P:
        d = P["device"]
        if not (d in ("auto", "cpu", "cuda") or (d.startswith("cuda:") and d[5:].isdigit())):
            raise _err(notebook, "device", "'auto', 'cpu', 'cuda' or 'cuda:N'", d)
    for name, may_be_empty in (("coarse_k", True), ("refine_objects", False), ("halving_refine_objects", True)):
        v = P.get(name)  # coarse-to-fine candidates (07): chosen among on held-out views of seen objects
        if v is not None and ((not v and not may_be_empty) or len(set(v)) != len(v) or any(x < 1 for x in v)):
            raise _err(notebook, name, f"a list of distinct ints >= 1{' (empty: skip)' if may_be_empty else ''}", v)
    if P.get("bop_root") and "bop_split" not in P:  # 09's bop_root is one T-LESS folder, read with its bop_split
        _check_bop_root(notebook, P)
    if P.get("report_dir") and not repo_path(P["report_dir"]).is_dir():
        raise _err(notebook, "report_dir", "'' or an existing report folder (relative paths from the repository "
                   f"root: {REPO_ROOT})", P["report_dir"])
    fv = P.get("fast_variants")  # 07: named fast-retrieval budgets beside the paper-ratio default
    if fv is not None and any(not isinstance(x, list) or len(x) != 2 or not all(isinstance(i, int) and i >= 1 for i in x)
                              for x in fv):
        raise _err(notebook, "fast_variants", "a list of [k_ac, fps_k] pairs of ints >= 1", fv)
    k_ac = _effective_k_ac(P)
    if "coarse_k" in P and k_ac is not None and any(x >= k_ac for x in P["coarse_k"]):
        raise _err(notebook, "coarse_k", f"candidates < k_ac={k_ac} (a coarse round smaller than the anchors)",
                   P["coarse_k"])
    if "c2f_min_agreement" in P and not 0.0 < P["c2f_min_agreement"] <= 1.0:
        raise _err(notebook, "c2f_min_agreement", "a share in (0, 1]", P["c2f_min_agreement"])
    if "lr_milestones" in P:
        m = P["lr_milestones"]
        if list(m) != sorted(set(m)) or any(x < 1 for x in m):
            raise _err(notebook, "lr_milestones", "increasing positive epochs", m)
    _check_configs(notebook, P)


def _check_bop_root(notebook: str, P: dict[str, Any]) -> None:
    """Real data: the folder's layout, and the choices that only the rendered benchmark has."""
    try:
        bop_folders(P["bop_root"])
    except BOPFormatError as e:
        raise ParameterError(f"notebook {notebook}: parameter 'bop_root': {e}") from None
    if P.get("models") == "zoo":
        raise _err(notebook, "models", "'train' with bop_root (the zoo's models trained on the rendered benchmark's "
                   "objects, not on LineMOD's)", P["models"])
    if P.get("held_out_model"):
        raise _err(notebook, "held_out_model", "'' with bop_root (real LineMOD has no held-out objects)",
                   P["held_out_model"])


def _check_zoo_steps(notebook: str, steps: int) -> None:
    """``zoo_steps``: a budget some published zoo model has (which models have it, notebook 03 finds)."""
    zoo = zoo_entries()
    budgets = sorted({int(e["steps"]) for e in zoo.values()})
    if steps not in budgets:
        raise _err(notebook, "zoo_steps", f"0 or a budget of the published zoo, one of {budgets}", steps)


def _check_variants(notebook: str, variants: list) -> None:
    """A non-empty list without repeats (what each variant may be, its experiment checks)."""
    if not variants or len(set(variants)) != len(variants):
        raise _err(notebook, "variants", "a non-empty list without repeats", variants)


def _check_seeded(notebook: str, seeded: list, variants: list | None) -> None:
    """Seeded variants must be variants of this notebook (components: the four labels of 08)."""
    known = list(variants) if variants is not None else list(COMPONENT_LABELS)
    if (not all(isinstance(v, str) for v in seeded) or len(set(seeded)) != len(seeded)
            or not set(seeded) <= set(known)):
        raise _err(notebook, "seeded_variants", f"distinct labels among {known}", seeded)


def _check_configs(notebook: str, P: dict[str, Any]) -> None:
    """Let the typed configurations check what they know (same messages as at training)."""
    try:
        configs_from(P)
    except ValueError as e:
        raise ParameterError(f"notebook {notebook}: {e}") from None


# ------------------------------------------------------------------ typed configurations

_DATA = ("image_size", "render_size", "n_references", "n_train_queries", "n_val_queries", "n_test_queries",
         "query_style", "train_context", "seed", "workers", "cache_dir")
_MODEL = ("image_size", "fusion", "scales", "local_norm", "norm_window")
_TRAIN = ("epochs", "steps_per_epoch", "batch_size", "lr", "lr_milestones", "lr_schedule", "warmup_steps",
          "clean_steps", "random_ref", "weighted_loss", "seed", "device", "train_occlusion", "val_every")


@dataclass(frozen=True)
class StudyConfigs:
    """The typed configurations of one notebook run; None where the notebook has no such parameters."""

    data: DataConfig | None
    train: TrainConfig | None
    search: SearchConfig | None


def configs_from(P: dict[str, Any]) -> StudyConfigs:
    """Build the typed configurations from checked parameters (the only place that reads them).

    ``data`` from the benchmark sizes (:data:`_DATA`), ``train`` (with its ``model``) from the
    training and architecture parameters, ``search`` from ``eval_method`` (notebook 03) or, in
    notebook 07, as fast retrieval's settings (``k_ac``, ``fps_k``, ``group``) that its other rows vary.
    A set of parameters that is only partly present gives None (e.g. notebook 01 has no training).
    """
    has = set(P).issuperset
    data = DataConfig(**{k: P[k] for k in _DATA}) if has(_DATA) else None
    train = None
    if has(_MODEL + _TRAIN):
        model = ModelConfig(image_size=P["image_size"], fusion=P["fusion"], scales=parse_scales(P["scales"]),
                            local_norm=P["local_norm"], norm_window=P["norm_window"])
        train = TrainConfig(epochs=P["epochs"], steps_per_epoch=P["steps_per_epoch"] or None,
                            batch_size=P["batch_size"], lr=P["lr"], lr_milestones=tuple(P["lr_milestones"]),
                            lr_schedule=P["lr_schedule"], warmup_steps=P["warmup_steps"],
                            clean_steps=P["clean_steps"], random_ref=P["random_ref"],
                            weighted_loss=P["weighted_loss"], seed=P["seed"], device=P["device"],
                            occlusion=P["train_occlusion"], augment=AugmentConfig(), val_every=P["val_every"],
                            model=model)
    search = None
    if has(("k_ac", "fps_k", "n_references")):
        # "density": fast search at these settings is the candidate; notebook 03 keeps it or takes greedy by
        # the anchors' coverage of the references (helpers.study.protocols.linemod.density_matched_search)
        method = P.get("eval_method", "fast")
        search = paper_ratio_search(P["n_references"], P["k_ac"], P["fps_k"],
                                    method="fast" if method == "density" else method, group=P.get("group", 1024))
    return StudyConfigs(data, train, search)


def _effective_k_ac(P: dict[str, Any]) -> int | None:
    """The anchors per object fast retrieval will use: ``k_ac``, or the paper's ratio of ``n_references`` at 0."""
    if "k_ac" not in P or "n_references" not in P:
        return None
    return paper_ratio_search(P["n_references"], P["k_ac"], P["fps_k"] if "fps_k" in P else 0).k_ac
