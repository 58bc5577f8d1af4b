"""Greedy and fast retrieval on synthetic features whose scores are known in closed form."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from helpers.core.configs import SearchConfig, paper_ratio_search
from helpers.core.rotations import geodesic_deg, haar_uniform, nearest
from helpers.search.retrieval import ReferenceBank, authors_sizes, fast_search, greedy_search, model_scorer, search_all
from helpers.study.parameters import check_parameters, configs_from


def cosine_scorer(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """Mean over locations of the per-location cosine, (M,)."""
    r = r.float()  # banks hand float16 chunks through unchanged
    qn = q / q.norm(dim=1, keepdim=True)
    rn = r / r.norm(dim=1, keepdim=True)
    return (qn * rn).sum(1).mean(-1)


OBJ_PENALTY = 0.3


def rotation_scorer(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """Smooth synthetic score: cos(geodesic angle) minus a penalty when the object code differs.

    Features are (9 + K, 1): the flattened rotation, then a one-hot object code.
    trace(Rq^T Rr) = 1 + 2 cos(angle).
    """
    tr = (q[:, :9, 0] * r[:, :9, 0]).sum(1)
    same = (q[:, 9:, 0] * r[:, 9:, 0]).sum(1)
    return (tr - 1) / 2 - OBJ_PENALTY * (1 - same)


def synthetic_feats(rots: np.ndarray, obj: int, n_obj: int, dtype=np.float32) -> np.ndarray:
    """(N, 9 + K, 1) features of rotations ``rots`` for object ``obj``."""
    f = np.zeros((len(rots), 9 + n_obj, 1), dtype)
    f[:, :9, 0] = rots.reshape(-1, 9)
    f[:, 9 + obj, 0] = 1
    return f


def synthetic_bank(n_obj: int, n_refs: int, dtype=np.float32, k_ac: int = 1024, seed: int = 0) -> ReferenceBank:
    rots = haar_uniform(n_refs, seed=seed)
    feats = [synthetic_feats(rots, k, n_obj, dtype) for k in range(n_obj)]
    return ReferenceBank(feats, rots, [f"obj{k}" for k in range(n_obj)], k_ac=k_ac)


def test_exact_reference_found():
    rng = np.random.default_rng(0)
    R = 300
    feats = [rng.standard_normal((R, 8, 5)).astype(np.float16) for _ in range(3)]
    bank = ReferenceBank(feats, haar_uniform(R, seed=1), ["a", "b", "c"], k_ac=50)
    p = greedy_search(torch.from_numpy(feats[2][17].astype(np.float32)), bank, cosine_scorer, group=64)
    assert (p.obj_index, p.ref_index, p.obj_name) == (2, 17, "c")
    assert p.score == pytest.approx(1.0, abs=1e-5) and p.n_comparisons == 3 * R
    assert np.allclose(p.R_est, bank.rotations[17])
    # A query equal to an anchor is found by the fast search too (whatever the feature geometry).
    a = int(bank.anchors(50)[7])
    pf = fast_search(feats[1][a].astype(np.float32)[None], bank, cosine_scorer, SearchConfig(k_ac=50, fps_k=16))
    assert (pf.obj_index, pf.ref_index) == (1, a) and pf.score == pytest.approx(1.0, abs=1e-5)


def test_fast_equals_greedy_on_smooth_scores():
    K, R = 4, 2000
    bank = synthetic_bank(K, R, k_ac=64)
    truths = haar_uniform(25, seed=5)
    objs = np.arange(25) % K
    queries = np.stack([synthetic_feats(truths[i:i + 1], objs[i], K)[0] for i in range(25)])
    greedy = search_all(queries, bank, rotation_scorer, SearchConfig(method="greedy", group=512), progress=False)
    fast = search_all(queries, bank, rotation_scorer, SearchConfig(method="fast", k_ac=64, fps_k=32), progress=False)
    nn_idx, _ = nearest(truths, bank.rotations)
    for i, (g, f) in enumerate(zip(greedy, fast)):
        assert g.obj_index == objs[i] and g.ref_index == nn_idx[i]  # greedy = true nearest reference
        assert (f.obj_index, f.ref_index) == (g.obj_index, g.ref_index), f"query {i}"
        assert g.n_comparisons == K * R
        # Anchors of every object, plus a few levels of at most fps_k each.
        assert K * 64 < f.n_comparisons < K * 64 + 12 * 32
    # The authors' fixed schedule lands close to greedy (not necessarily on it).
    auth = search_all(queries, bank, rotation_scorer, SearchConfig(method="fast", k_ac=64, fps_k=32, schedule="authors"), progress=False)
    err = geodesic_deg(np.stack([a.R_est for a in auth]), np.stack([g.R_est for g in greedy]))
    assert all(a.obj_index == g.obj_index for a, g in zip(auth, greedy))
    assert np.median(err) < 25
    assert all(a.n_comparisons <= K * 64 + 4 * 32 for a in auth)


def test_comparisons_not_double_counted():
    calls = []

    def counting(q, r):
        calls.append(len(r))
        return rotation_scorer(q, r)

    bank = synthetic_bank(3, 500, k_ac=40)
    q = synthetic_feats(haar_uniform(1, seed=9), 1, 3)[0]
    p = fast_search(q, bank, counting, SearchConfig(k_ac=40, fps_k=20))
    assert sum(calls) == p.n_comparisons
    # All references already anchors: nothing left to refine beyond them.
    p_all = fast_search(q, bank, rotation_scorer, SearchConfig(k_ac=500))
    assert p_all.n_comparisons == 3 * 500


def test_authors_sizes():
    assert authors_sizes(10_000) == [4096, 2048, 1024, 512]
    assert authors_sizes(20_000) == [4096, 2048, 1024, 512]
    assert authors_sizes(1000) == [410, 205, 102, 51]
    assert authors_sizes(3) == [1, 1, 1, 1]


def test_bad_inputs():
    bank = synthetic_bank(2, 50, k_ac=10)
    with pytest.raises(ValueError, match="does not match the bank"):
        greedy_search(np.zeros((5, 1), np.float32), bank, rotation_scorer)
    with pytest.raises(ValueError, match="SearchConfig.schedule: expected one of"):
        SearchConfig(schedule="nope")
    with pytest.raises(ValueError, match="cfg.method is 'greedy'"):
        fast_search(np.zeros((11, 1), np.float32), bank, rotation_scorer, SearchConfig("greedy"))
    with pytest.raises(ValueError, match="expected .50, C, L."):
        ReferenceBank([np.zeros((49, 11, 1))], bank.rotations, ["x"])
    with pytest.raises(ValueError, match="SearchConfig.method: expected one of"):
        SearchConfig(method="slow")
    with pytest.raises(ValueError, match=r"query_feats must be \(N,C,L\)"):
        search_all(np.zeros((11, 1)), bank, rotation_scorer, SearchConfig())


def test_model_scorer_duck_typed():
    class Fake:
        def score(self, q, r, chunk=1024):
            return rotation_scorer(q.expand(len(r), -1, -1), r)[None]

    bank = synthetic_bank(2, 100, k_ac=20)
    q = synthetic_feats(bank.rotations[42:43], 1, 2)[0]
    p = greedy_search(q, bank, model_scorer(Fake()))
    assert (p.obj_index, p.ref_index) == (1, 42)


def test_fast_scales_to_13_objects_10k_refs():
    K, R = 13, 10_000
    t0 = time.perf_counter()
    bank = synthetic_bank(K, R, dtype=np.float16)
    t_bank = time.perf_counter() - t0
    truths = haar_uniform(5, seed=11)
    queries = np.stack([synthetic_feats(truths[i:i + 1], i % K, K)[0] for i in range(5)])
    t0 = time.perf_counter()
    preds = search_all(queries, bank, rotation_scorer, SearchConfig(method="fast"), progress=False)
    t_q = (time.perf_counter() - t0) / len(queries)
    nn_idx, nn_ang = nearest(truths, bank.rotations)
    for i, p in enumerate(preds):
        assert p.obj_index == i % K
        assert geodesic_deg(p.R_est, truths[i]) < np.degrees(nn_ang[i]) + 3
        assert p.n_comparisons < K * 1024 + 2000  # vs K*R = 130,000 for greedy
    print(f"\nbank build {t_bank:.2f} s; fast_search {1000 * t_q:.0f} ms/query, "
          f"{np.mean([p.n_comparisons for p in preds]):.0f} comparisons/query")
    assert t_q < 2.0


def batched_rotation_scorer(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """:func:`rotation_scorer` for Q queries at once: (Q, F, 1), (M, F, 1) -> (Q, M)."""
    r = r.float()
    tr = q[:, :9, 0] @ r[:, :9, 0].T
    same = q[:, 9:, 0] @ r[:, 9:, 0].T
    return (tr - 1) / 2 - OBJ_PENALTY * (1 - same)


batched_rotation_scorer.batched = True


def test_batched_anchor_stage_matches_single_queries():
    K, R = 3, 1500
    bank = synthetic_bank(K, R, dtype=np.float16, k_ac=48)
    truths = haar_uniform(11, seed=8)
    queries = np.stack([synthetic_feats(truths[i:i + 1], i % K, K)[0] for i in range(11)])
    one = search_all(queries, bank, rotation_scorer, SearchConfig(method="fast", k_ac=48, fps_k=16, query_batch=1), progress=False)
    calls = []

    def spy(q, r):
        calls.append(tuple(q.shape))
        return batched_rotation_scorer(q, r)

    spy.batched = True
    many = search_all(queries, bank, spy, SearchConfig(method="fast", k_ac=48, fps_k=16, query_batch=4), progress=False)
    for a, b in zip(one, many):
        assert (a.obj_index, a.ref_index, a.n_comparisons) == (b.obj_index, b.ref_index, b.n_comparisons)
        assert a.score == pytest.approx(b.score, abs=1e-3)  # float16 refs, other summation order
        assert np.isfinite(b.seconds) and b.seconds > 0
    # Anchors of 4 + 4 + 3 queries went through 3 batched calls per object.
    assert sorted(c[0] for c in calls if c[0] > 1) == [3] * K + [4] * (2 * K)


def test_float16_bank_reaches_scorer_as_float16():
    bank = synthetic_bank(2, 60, dtype=np.float16, k_ac=10)
    assert bank.ref_feats(0, np.array([5, 1])).dtype == torch.float16
    assert bank.chunk(1, 0, 7).shape == (7, 11, 1)
    assert bank.anchor_feats(10)[1].shape == (10, 11, 1)
    assert synthetic_bank(2, 60, dtype=np.float64, k_ac=10).ref_feats(0, np.array([0])).dtype == torch.float32
    with pytest.raises(ValueError, match="SearchConfig.query_batch: expected an int >= 1"):
        SearchConfig(method="fast", query_batch=0)


def test_coarse_to_fine_matches_fast_and_scores_fewer_pairs():
    K, R = 6, 2000
    bank = synthetic_bank(K, R, k_ac=128)
    truths = haar_uniform(20, seed=7)
    objs = np.arange(20) % K
    queries = np.stack([synthetic_feats(truths[i:i + 1], objs[i], K)[0] for i in range(20)])
    fast = search_all(queries, bank, rotation_scorer, SearchConfig(method="fast", k_ac=128, fps_k=32), progress=False)
    c2f = search_all(queries, bank, rotation_scorer, SearchConfig(method="c2f", k_ac=128, fps_k=32, coarse_k=16, refine_objects=2), progress=False)
    for f, c in zip(fast, c2f):
        assert (c.obj_index, c.ref_index) == (f.obj_index, f.ref_index)
        # Coarse anchors of every object + the rest of the anchors of 2 objects + the same refinement.
        assert c.n_comparisons == f.n_comparisons - (K - 2) * (128 - 16)
    # Every object refined: exactly the authors' category stage.
    full = search_all(queries[:3], bank, rotation_scorer, SearchConfig(method="c2f", k_ac=128, fps_k=32, coarse_k=16, refine_objects=K), progress=False)
    assert [(p.obj_index, p.ref_index, p.n_comparisons) for p in full] == \
        [(p.obj_index, p.ref_index, p.n_comparisons) for p in fast[:3]]


def test_coarse_to_fine_counts_every_scored_pair_once():
    calls = []

    def counting(q, r):
        calls.append(len(r))
        return rotation_scorer(q, r)

    bank = synthetic_bank(4, 600, k_ac=64)
    q = synthetic_feats(haar_uniform(1, seed=3), 2, 4)[0]
    p = fast_search(q, bank, counting, SearchConfig("c2f", k_ac=64, fps_k=16, coarse_k=8, refine_objects=1))
    assert sum(calls) == p.n_comparisons and p.obj_index == 2
    with pytest.raises(ValueError, match="SearchConfig.refine_objects: expected an int >= 1"):
        SearchConfig("c2f", k_ac=64, coarse_k=8, refine_objects=0)


def test_coarse_to_fine_halving_rounds():
    """Successive halving: 6 objects x 16 anchors, the best 3 score 16 more, the best 2 all 128."""
    K, R = 6, 2000
    bank = synthetic_bank(K, R, k_ac=128)
    truths = haar_uniform(12, seed=11)
    objs = np.arange(12) % K
    queries = np.stack([synthetic_feats(truths[i:i + 1], objs[i], K)[0] for i in range(12)])
    calls = []

    def counting(q, r):
        calls.append(len(r))
        return rotation_scorer(q, r)

    fast = search_all(queries, bank, rotation_scorer, SearchConfig(method="fast", k_ac=128, fps_k=32), progress=False)
    for f, qf in zip(fast, queries):
        calls.clear()
        c = fast_search(qf, bank, counting, SearchConfig("c2f", k_ac=128, fps_k=32, coarse_k=16, refine_objects=2, halving=True))
        assert (c.obj_index, c.ref_index) == (f.obj_index, f.ref_index)
        assert c.n_comparisons == f.n_comparisons - (K * 128 - (K * 16 + 3 * 16 + 2 * 96))
        assert sum(calls) == c.n_comparisons
        assert calls[0] == K * 16  # the coarse round is one scorer call
    via_all = search_all(queries[:2], bank, rotation_scorer, SearchConfig(method="c2f", k_ac=128, fps_k=32, coarse_k=16, refine_objects=2, halving=True), progress=False)
    assert [p.n_comparisons for p in via_all] == [fast_search(q, bank, rotation_scorer, SearchConfig("c2f", k_ac=128, fps_k=32, coarse_k=16, refine_objects=2, halving=True)).n_comparisons
                                                  for q in queries[:2]]
    # Down to one object: 6 x 16, 3 x 16, 2 x 32, then the last one its other 64 anchors.
    for f, qf in zip(fast[:4], queries[:4]):
        calls.clear()
        one = fast_search(qf, bank, counting, SearchConfig("c2f", k_ac=128, fps_k=32, coarse_k=16, refine_objects=1, halving=True))
        assert calls[:4] == [K * 16, 16, 16, 16] and sum(calls[4:6]) == 64 and calls[6] == 64
        assert one.obj_index == f.obj_index and one.n_comparisons == sum(calls)
    with pytest.raises(ValueError, match="anchor_head_feats"):
        bank.anchor_head_feats(128, 0)


def test_row_indexed_scoring_reads_the_bank_in_place_and_changes_nothing(tmp_path):
    """A model scorer with ``rows`` scores a float16 memmap bank where it lies: same predictions, no copies."""
    from helpers.core.configs import ModelConfig
    from helpers.net.model import OrientationNet

    torch.manual_seed(0)
    model = OrientationNet(ModelConfig(image_size=64, scales=(16, 13))).eval()
    c, length = model.cfg.channels, model.feature_length
    rots = haar_uniform(300, seed=3)
    g = torch.Generator().manual_seed(4)
    feats = []
    for o in range(3):
        path = tmp_path / f"obj{o}.f16"
        f = torch.nn.functional.normalize(torch.randn(len(rots), c, length, generator=g), dim=1).half().numpy()
        f.tofile(path)
        feats.append(np.memmap(path, dtype=np.float16, mode="r", shape=f.shape))
    bank = ReferenceBank(feats, rots, ["a", "b", "c"], k_ac=32)
    src = bank.ref_source(1)
    assert src.shape == (300, c, length) and src.dtype == torch.float16
    assert src.data_ptr() == feats[1].ctypes.data  # shares the memmap's memory: no copy
    assert bank.ref_feats(1, np.array([4, 9, 200])).dtype == torch.float16  # sorted fast path
    assert torch.equal(bank.ref_feats(1, np.array([200, 4, 9]))[0], src[200])  # any order
    assert synthetic_bank(2, 60, dtype=np.float64, k_ac=10).ref_source(0) is None
    with_rows = model_scorer(model)
    assert with_rows.rows

    def gathered(q, r):  # the same model without the row path
        return with_rows(q, r)

    gathered.batched = True
    q = torch.nn.functional.normalize(torch.randn(4, c, length, generator=g), dim=1)
    for cfg in (SearchConfig(k_ac=32, fps_k=16), SearchConfig("c2f", k_ac=32, fps_k=16, coarse_k=8, refine_objects=2),
                SearchConfig("c2f", k_ac=32, fps_k=16, coarse_k=8, refine_objects=1, halving=True)):
        for i in range(len(q)):
            a = fast_search(q[i], bank, with_rows, cfg)
            b = fast_search(q[i], bank, gathered, cfg)
            assert (a.obj_index, a.ref_index, a.n_comparisons) == (b.obj_index, b.ref_index, b.n_comparisons)
            assert a.score == pytest.approx(b.score, abs=1e-6)


def test_duck_typed_model_without_rows_gets_gathered_refs():
    class Fake:
        def score(self, q, r, chunk=1024):
            return rotation_scorer(q.expand(len(r), -1, -1), r)[None]

    scorer = model_scorer(Fake())
    assert not scorer.rows
    bank = synthetic_bank(2, 100, k_ac=20)
    q = synthetic_feats(bank.rotations[42:43], 1, 2)[0]
    p = fast_search(q, bank, scorer, SearchConfig(k_ac=20, fps_k=8))
    assert (p.obj_index, p.ref_index) == (1, 42)


def test_fast_search_defaults_to_the_papers_ratios():
    assert (paper_ratio_search(10000).k_ac, paper_ratio_search(10000).fps_k) == (1024, 256)  # the paper's budget
    assert (paper_ratio_search(512).k_ac, paper_ratio_search(512).fps_k) == (52, 13)
    assert (paper_ratio_search(48).k_ac, paper_ratio_search(48).fps_k) == (5, 1)
    s = paper_ratio_search(512, k_ac=128, fps_k=32)  # a named variant is taken as given
    assert (s.k_ac, s.fps_k, s.method) == (128, 32, "fast")
    assert paper_ratio_search(2048, k_ac=100).fps_k == 25  # fps_k follows the given k_ac
    with pytest.raises(ValueError, match="n_refs"):
        paper_ratio_search(0)
    P = check_parameters("03_evaluate", {"n_references": 512, "k_ac": 0, "fps_k": 0})
    assert (configs_from(P).search.k_ac, configs_from(P).search.fps_k) == (52, 13)


@pytest.mark.parametrize("fusion", ["adaptive", "avg"])
def test_greedy_queries_sharing_reference_tiles_give_the_same_answers(fusion):
    """Greedy with ``query_batch`` > 1 (queries sharing each tile of ``group`` references, one scorer call per
    query and tile) returns exactly the one-query-at-a-time answers and scores, for the fused-kernel path and the
    "avg" matmul path of a real model over a float16 bank; each query's seconds are its share of the batch."""
    from helpers.core.configs import ModelConfig
    from helpers.net.model import OrientationNet

    torch.manual_seed(0)
    model = OrientationNet(ModelConfig(image_size=64, scales=(16, 13), fusion=fusion)).eval()
    c, length = model.cfg.channels, model.feature_length
    g = torch.Generator().manual_seed(5)
    feats = [torch.nn.functional.normalize(torch.randn(90, c, length, generator=g), dim=1).half().numpy()
             for _ in range(3)]
    bank = ReferenceBank(feats, haar_uniform(90, seed=6), ["a", "b", "c"], k_ac=16)
    q = torch.nn.functional.normalize(torch.randn(7, c, length, generator=g), dim=1)
    scorer = model_scorer(model)
    one = search_all(q, bank, scorer, SearchConfig("greedy"), progress=False)
    tiled = search_all(q, bank, scorer, SearchConfig("greedy", group=32, query_batch=3), progress=False)
    assert [(p.obj_index, p.ref_index, p.score, p.n_comparisons) for p in one] == \
        [(p.obj_index, p.ref_index, p.score, p.n_comparisons) for p in tiled]
    assert tiled[0].seconds == tiled[1].seconds == tiled[2].seconds > 0  # the first batch's equal shares
