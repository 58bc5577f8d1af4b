"""Per-query evaluations kept on disk, so a model that several notebooks score on the same queries, references
and search is scored once (notebook 13's longer-budget models are notebook 03's split models, for example).

A cached table holds what every accuracy, interval and claim is computed from (the per-query rows); it has no
timings, so a result read back has an empty ``seconds_per_query``: callers that report speed must not use it.
"""

from __future__ import annotations

import inspect
from dataclasses import asdict
from pathlib import Path
from typing import Any

import pandas as pd

from ...core import rotations
from ...core.configs import SearchConfig
from ...core.fileio import atomic_write_text, source_digest, stable_hash
from ...core.paths import cache_dir
from ...core.views import ObjectViews
from ...evaluation import metrics
from ...evaluation.metrics import summarise_queries
from ...net import fusion_kernel
from ...search import retrieval
from ...search.features import model_fingerprint
from ..pipeline import StudyData, encode_queries, evaluate, reference_bank

#: The error threshold (degrees) every cached table is scored with (Rota. Acc.'s 30 deg).
THRESHOLD_DEG = 30.0


def scoring_sources() -> list[Path]:
    """The source files that turn encoded views into a per-query table beyond the encoder and the model's own
    ``score`` (which :func:`model_fingerprint` covers): the search package, the fused scoring kernel, the error
    metrics and the rotation maths (symmetric errors)."""
    net = Path(fusion_kernel.__file__).parent
    return [Path(retrieval.__file__).parent, net / "fusion_kernel.py", net / "fusion_kernel.cpp",
            Path(metrics.__file__), Path(rotations.__file__)]


def scoring_code() -> str:
    """Digest of :func:`scoring_sources` and of the pipeline's own steps that evaluate (their source text alone:
    the rest of ``study/pipeline.py`` is data and training code, whose edits leave a table valid)."""
    steps = [inspect.getsource(f) for f in (evaluate, reference_bank, encode_queries)]
    return stable_hash([source_digest(scoring_sources()), steps])


def evals_folder(data: StudyData) -> Path:
    """The cache's folder of per-query tables (``<cache>/evals``) for ``data``'s cache."""
    return cache_dir(data.cfg.cache_dir or None) / "evals"


def eval_key(model: Any, data: StudyData, bench: list[str], queries: dict[str, ObjectViews], n_refs: int,
             search: SearchConfig) -> str:
    """What a per-query table depends on: the weights, the reference sets of ``bench`` (and how many of each,
    0: all), the query sets, the search and the symmetries the errors are scored under (a table scored before
    an object's symmetries were declared, or changed, is not reused) and the code that scores
    (:func:`scoring_code`: a table of older code is not reused either)."""
    sym = {n: [e.symmetries, e.symmetry_axes] for n, e in ((n, data.manifest.object(n)) for n in queries)}
    # Greedy scores every reference: its answers depend on nothing else of the config (how it batches the work
    # included, tests/test_retrieval.py), so notebook 04's greedy and notebook 13's protocol search share tables.
    how = {"method": "greedy"} if search.method == "greedy" else asdict(search)
    return stable_hash({"model": model_fingerprint(model), "bank": [data.key(n) for n in bench], "eval_refs": n_refs,
                        "queries": {n: [v.meta.get("key"), len(v)] for n, v in queries.items()},
                        "search": how, "threshold_deg": THRESHOLD_DEG, "symmetries": sym,
                        "columns": "R_est,R_gt", "code": scoring_code()})


def cached_evaluate(model: Any, data: StudyData, bench: list[str], queries: dict[str, ObjectViews],
                    search: SearchConfig, folder: str | Path, n_refs: int = 0, device: str = "auto") -> dict[str, Any]:
    """:func:`helpers.study.pipeline.evaluate` of ``queries`` among the first ``n_refs`` references (0: all) of the
    objects ``bench``, its per-query table kept as ``folder/<key>.csv`` (:func:`eval_key`).

    Returns evaluate's dict; read back from ``folder`` it has "per_query", "per_object", "means", "cached" (the
    file) and empty "seconds_per_query" / "comparisons" / "records"."""
    f = Path(folder) / f"{eval_key(model, data, bench, queries, n_refs, search)}.csv"
    if f.exists():
        pq = pd.read_csv(f)
        per_object, means = summarise_queries(pq)
        return {"per_query": pq, "per_object": per_object, "means": means, "cached": str(f),
                "seconds_per_query": [], "comparisons": [], "records": []}
    bank = reference_bank(model, data, bench, device=device, k_ac=search.k_ac, n_refs=n_refs or None)
    r = evaluate(model, bank, queries, search, device, threshold_deg=THRESHOLD_DEG)
    f.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(f, r["per_query"].to_csv(index=False))
    return r
