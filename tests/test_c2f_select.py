"""Choosing the coarse-to-fine settings on held-out queries: agreement with fast retrieval, cheapest first."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_retrieval import cosine_scorer

from helpers.core.configs import SearchConfig
from helpers.core.rotations import haar_uniform
from helpers.search.c2f_select import c2f_candidates, select_c2f
from helpers.search.retrieval import ReferenceBank, search_all

K, R, K_AC = 5, 400, 64
BASE = SearchConfig("fast", k_ac=K_AC, fps_k=16, schedule="converge")


def noisy_setup(noise: float, n_q: int = 30, seed: int = 0):
    """A bank of random features and queries that are noisy copies of random references."""
    rng = np.random.default_rng(seed)
    feats = [rng.standard_normal((R, 8, 4)).astype(np.float32) for _ in range(K)]
    bank = ReferenceBank(feats, haar_uniform(R, seed=1), [f"o{k}" for k in range(K)], k_ac=K_AC)
    objs, refs = rng.integers(0, K, n_q), rng.integers(0, R, n_q)
    q = np.stack([feats[o][r] + noise * rng.standard_normal((8, 4)) for o, r in zip(objs, refs)]).astype(np.float32)
    return bank, q


def test_candidates_grid_and_refusal():
    c = c2f_candidates([8, 16], [1, 3], [1], k_ac=64)
    assert [(d["family"], d["coarse_k"], d["refine_objects"]) for d in c] == [
        ("one cut", 8, 1), ("one cut", 8, 3), ("one cut", 16, 1), ("one cut", 16, 3), ("halving", 8, 1),
        ("halving", 16, 1)]
    assert c2f_candidates([], [1], [1], k_ac=64) == []
    with pytest.raises(ValueError, match="k_ac=64"):
        c2f_candidates([64], [1], [], k_ac=64)


def test_cheapest_candidate_that_agrees_enough_is_chosen():
    bank, q = noisy_setup(noise=0.3)
    cands = c2f_candidates([4, 16], [1, K], [1], K_AC)
    table, chosen = select_c2f(q, bank, cosine_scorer, BASE, cands, min_agreement=1.0, progress=False)
    assert len(table) == len(cands) and table["chosen"].sum() == 2
    # refine_objects = K refines every object: exactly fast retrieval, so agreement is 1 and a pick exists.
    full = table[(table["family"] == "one cut") & (table["refine_objects"] == K)]
    assert (full["agreement_with_fast"] == 1.0).all() and (full["comparisons_vs_fast"] >= 1.0 - 1e-9).all()
    one = chosen["one cut"]
    assert one["met"] and one["agreement_with_fast"] == 1.0
    met = table[(table["family"] == "one cut") & table["met"]]
    assert one["mean_comparisons"] == met["mean_comparisons"].min()
    # What is reported is what the search does: the chosen settings reproduce the agreement.
    fast = search_all(q, bank, cosine_scorer, BASE, progress=False)
    c2f = replace(BASE, method="c2f", coarse_k=one["coarse_k"], refine_objects=one["refine_objects"],
                  halving=one["halving"])
    again = search_all(q, bank, cosine_scorer, c2f, progress=False)
    assert [(p.obj_index, p.ref_index) for p in again] == [(p.obj_index, p.ref_index) for p in fast]
    assert chosen["halving"]["halving"] is True


def test_no_candidate_agrees_enough_most_agreeing_is_flagged():
    bank, q = noisy_setup(noise=3.0, n_q=40)  # so noisy that one coarse anchor per object misleads
    cands = c2f_candidates([1, 2], [1], [], K_AC)
    table, chosen = select_c2f(q, bank, cosine_scorer, BASE, cands, min_agreement=1.0, progress=False)
    assert set(chosen) == {"one cut"} and not table["met"].any()
    best = table.sort_values(["agreement_with_fast", "mean_comparisons"], ascending=[False, True]).iloc[0]
    assert not chosen["one cut"]["met"] and chosen["one cut"]["coarse_k"] == best["coarse_k"]
    assert chosen["one cut"]["agreement_with_fast"] < 1.0


def test_bad_arguments_are_refused():
    bank, q = noisy_setup(noise=0.3, n_q=2)
    with pytest.raises(ValueError, match="min_agreement"):
        select_c2f(q, bank, cosine_scorer, BASE, [], min_agreement=0.0)
    with pytest.raises(ValueError, match="no held-out queries"):
        select_c2f(q[:0], bank, cosine_scorer, BASE, [], progress=False)
