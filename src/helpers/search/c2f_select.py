"""Choose the coarse-to-fine search's settings on held-out views of SEEN objects.

The coarse-to-fine category stage (:func:`helpers.search.retrieval.fast_search` with
``coarse_k``) is ours, not the authors'; its settings trade pair scores for the risk
of dropping, in the coarse round, the object that the authors' fast retrieval would
pick. They must not be tuned on the unseen test queries whose accuracy they are
then judged by, so :func:`select_c2f` picks them on the held-out validation views
of the split's SEEN objects, without their labels: a candidate's *agreement* is the
share of those queries on which it retrieves exactly what fast retrieval retrieves
(same object, same reference). Agreement ``a`` bounds the accuracy difference on
those queries to ``1 - a`` (a query can only change its outcome where the two
disagree), so ``min_agreement = 0.99`` asks for "within 1 point" where it can be
checked honestly. The rule per family (one cut, successive halving): the cheapest
candidate (fewest mean pair scores per query) whose agreement reaches
``min_agreement``; if none does, the most agreeing one (then the cheapest), flagged
``met = False``. Seen objects are easier for the model than unseen ones, so the
agreement reached here is an optimistic guide for the unseen test, which reports its
own agreement.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from ..core.configs import SearchConfig
from .retrieval import search_all

FAMILIES = ("one cut", "halving")


def c2f_candidates(coarse_ks: list[int], refine_objects: list[int], halving_refine_objects: list[int],
                   k_ac: int) -> list[dict[str, Any]]:
    """The settings to choose among: every ``coarse_k`` with every ``refine_objects`` (one cut)
    and with every ``halving_refine_objects`` (successive halving).

    A ``coarse_k`` >= ``k_ac`` has no coarse round (it is fast retrieval itself) and is refused.
    Returns dicts {"family", "coarse_k", "refine_objects", "halving"}; empty when ``coarse_ks`` is.
    """
    bad = [k for k in coarse_ks if not 1 <= k < k_ac]
    if bad:
        raise ValueError(f"coarse_k: every candidate must lie in [1, k_ac={k_ac}) (a coarse round smaller "
                         f"than the full anchor set), got {bad}")
    out = [{"family": "one cut", "coarse_k": k, "refine_objects": r, "halving": False}
           for k in coarse_ks for r in refine_objects]
    out += [{"family": "halving", "coarse_k": k, "refine_objects": r, "halving": True}
            for k in coarse_ks for r in halving_refine_objects]
    return out


def _same(a: Any, b: Any) -> bool:
    return a.obj_index == b.obj_index and a.ref_index == b.ref_index


def select_c2f(query_feats: Any, bank: Any, scorer: Any, base: SearchConfig, candidates: list[dict[str, Any]],
               min_agreement: float = 0.99, progress: bool = True) -> tuple[pd.DataFrame, dict[str, dict]]:
    """Score every candidate against fast retrieval on the same (held-out, seen) queries.

    Args:
        query_feats: (N, C, L) features of held-out views of seen objects.
        bank, scorer: as for :func:`helpers.search.retrieval.search_all`.
        base: fast retrieval's settings (``method="fast"``); every candidate shares them and
            changes only the coarse-to-fine fields.
        candidates: from :func:`c2f_candidates`.
        min_agreement: share in (0, 1] of queries on which a candidate must retrieve what fast does.

    Returns:
        (table: one row per candidate with ``agreement_with_fast``, ``mean_comparisons``,
        ``comparisons_vs_fast`` (ratio), ``chosen``, ``met``;
        chosen: family -> {"coarse_k", "refine_objects", "halving", "agreement_with_fast",
        "mean_comparisons", "met"} for each family that has candidates).
    """
    from tqdm.auto import tqdm

    if not 0.0 < min_agreement <= 1.0:
        raise ValueError(f"select_c2f: min_agreement must lie in (0, 1], got {min_agreement!r}")
    if len(query_feats) == 0:
        raise ValueError("select_c2f: no held-out queries to choose the coarse-to-fine settings on")
    if base.method != "fast":
        raise ValueError(f"select_c2f: base must be fast retrieval's settings (method 'fast'), got {base.method!r}")
    fast = search_all(query_feats, bank, scorer, base, progress=False)
    fast_cost = float(np.mean([p.n_comparisons for p in fast]))
    rows = []
    for cand in tqdm(candidates, desc="c2f candidates (seen val)", unit="setting", disable=not progress):
        c2f = replace(base, method="c2f", coarse_k=cand["coarse_k"], refine_objects=cand["refine_objects"],
                      halving=cand["halving"])
        preds = search_all(query_feats, bank, scorer, c2f, progress=False)
        cost = float(np.mean([p.n_comparisons for p in preds]))
        rows.append({**cand, "agreement_with_fast": float(np.mean([_same(p, f) for p, f in zip(preds, fast)])),
                     "mean_comparisons": cost, "comparisons_vs_fast": cost / fast_cost})
    table = pd.DataFrame(rows, columns=["family", "coarse_k", "refine_objects", "halving", "agreement_with_fast",
                                        "mean_comparisons", "comparisons_vs_fast"])
    table["met"] = table["agreement_with_fast"] >= min_agreement - 1e-12
    table["chosen"] = False
    chosen: dict[str, dict] = {}
    for fam in FAMILIES:
        g = table[table["family"] == fam]
        if g.empty:
            continue
        ok = g[g["met"]]
        # cheapest that agrees enough (ties: more agreement, then the smaller coarse round);
        # otherwise the most agreeing (ties: cheapest)
        pick = (ok.sort_values(["mean_comparisons", "agreement_with_fast", "coarse_k"],
                               ascending=[True, False, True]) if len(ok) else
                g.sort_values(["agreement_with_fast", "mean_comparisons"], ascending=[False, True])).index[0]
        table.loc[pick, "chosen"] = True
        r = table.loc[pick]
        chosen[fam] = {"coarse_k": int(r["coarse_k"]), "refine_objects": int(r["refine_objects"]),
                       "halving": bool(r["halving"]), "agreement_with_fast": float(r["agreement_with_fast"]),
                       "mean_comparisons": float(r["mean_comparisons"]), "met": bool(r["met"])}
    return table, chosen
