"""Retrieval section of bench_gpu.py: fast vs greedy search over a synthetic bank held on the device.

``TorchReferenceBank`` keeps the float16 features in device memory while the
search code, anchors, FPS and neighbourhoods stay the library's own. Only the
standard library and numpy are imported at module level.
"""

from __future__ import annotations

import statistics
import time

import numpy as np
from bench_train import monotone_readout  # the CPU benchmark's score readout, the same on the GPU
from gpu_sections import Ctx, _log, cuda_mem, release_cuda


def _torch_bank_class():
    """ReferenceBank subclass whose features are torch tensors (e.g. on the GPU).

    ReferenceBank reads features only in ``ref_feats`` and ``chunk`` (numpy
    indexing into its arrays); these two are overridden with torch indexing, so
    the search code, anchors, FPS and neighbourhoods are the library's own.
    ``model_scorer`` moves its inputs with ``.to(device)``: a no-op here.
    """
    import torch

    from helpers.search.retrieval import ReferenceBank

    class TorchReferenceBank(ReferenceBank):
        def ref_feats(self, obj: int, idx: np.ndarray) -> torch.Tensor:
            src = self.feats[obj]
            return src.index_select(0, torch.as_tensor(np.asarray(idx, dtype=np.int64), device=src.device))

        def chunk(self, obj: int, start: int, stop: int) -> torch.Tensor:
            return self.feats[obj][start:stop]

    return TorchReferenceBank


def _smooth(basis, rots9, c: int, length: int, noise: float = 0.0, gen=None):
    """unit-over-C of reshape([vec9(R), 1] @ basis) (+ noise), float32 (n, C, L) on basis's device."""
    import torch

    v = torch.cat([rots9, torch.ones(len(rots9), 1, device=rots9.device)], 1)
    x = (v @ basis).view(len(rots9), c, length)
    if noise:
        x = x + noise * torch.randn(x.shape, generator=gen, device=x.device)
    return x / x.norm(dim=1, keepdim=True)


def bench_retrieval(ctx: Ctx, cap_s: float, size: int, out: dict) -> dict:
    """Fast vs greedy search over K x R synthetic float16 features held on the device."""
    import torch

    from helpers.core.configs import ModelConfig
    from helpers.core.rotations import haar_uniform
    from helpers.net.model import OrientationNet
    from helpers.core.configs import SearchConfig
    from helpers.search.retrieval import fast_search, greedy_search, model_scorer, search_all

    t_sec = time.perf_counter()
    stop_at = t_sec + cap_s
    a = ctx.args
    dev = torch.device(ctx.device)
    K, R_req = a.retr_objects, a.retr_refs
    k_ac, fps_k = (a.k_ac, a.fps_k)
    torch.manual_seed(0)
    model = OrientationNet(ModelConfig(image_size=size)).to(dev).eval()
    monotone_readout(model)
    c, length = model.cfg.channels, model.feature_length
    with torch.inference_mode():
        enc_shape = tuple(model.encode(torch.rand(1, 3, size, size, device=dev)).shape)
    per_ref = c * length * 2
    out.update({
        "image_size": size, "n_objects": K, "R_requested": R_req, "C": c, "L": length,
        "L_matches_encode": enc_shape[1:] == (c, length), "bytes_per_reference_f16": per_ref,
        "features": "synthetic, rotation-smooth (as benchmarks/bench.py): unit-over-C of [vec9(R),1] @ B_object, "
                    "generated on the device and stored float16 in device memory; queries: the same map for a "
                    "random rotation of a random object plus N(0,1) noise, re-normalised, float32",
        "model": "random-init OrientationNet (seed 0), fusion MLP set to the monotone readout "
                 "tanh(3 * mean fused cosine) as benchmarks/bench.py; same operations and cost as a trained model",
        "bank": "TorchReferenceBank: helpers.search.retrieval.ReferenceBank subclass overriding ref_feats/chunk with torch "
                "indexing (features stay on the device); search code unchanged",
        "scorer": f"helpers.search.retrieval.model_scorer(model, {ctx.device!r}) (chunk 1024; returns CPU scores, i.e. syncs)",
        "fast_params": {"k_ac": k_ac, "fps_k": fps_k, "schedule": "converge", "top_anchors": 3, "group": 1024},
        "greedy_params": {"group": 1024}, "cap_s": cap_s, "cut_short": False})
    # ---- how many references fit
    R = R_req
    if ctx.cuda:
        free, total = torch.cuda.mem_get_info()
        margin = a.gpu_margin_gb * 2 ** 30
        anchors = K * min(k_ac, R) * per_ref
        need = K * R * per_ref + anchors + margin
        out["memory_check"] = {"free_bytes": free, "total_bytes": total, "bank_bytes": K * R * per_ref,
                               "anchor_copy_bytes": anchors, "margin_bytes": margin, "needed_bytes": need}
        if need > free:
            R = int((free - margin) // (K * per_ref + K * per_ref * min(k_ac, R) / R))
            R = max(0, (R // 500) * 500)
            out["memory_check"]["reduced_R_to"] = R
            _log(f"retrieval: only {free / 2**30:.1f} GiB free, R reduced to {R}")
            if R < 1:
                out["skipped"] = "not enough device memory"
                return out
    out["R"] = R
    out["bank_bytes"] = K * R * per_ref
    # ---- generate the bank on the device
    rots = haar_uniform(R, seed=0)
    rots9 = torch.from_numpy(rots.reshape(R, 9).astype(np.float32)).to(dev)
    gen = torch.Generator(device=dev).manual_seed(1)
    ctx.sync()
    t0 = time.perf_counter()
    bases, feats = [], []
    step = 500 if ctx.cuda else 50
    for _o in range(K):
        basis = torch.randn(10, c * length, generator=gen, device=dev)
        f = torch.empty(R, c, length, dtype=torch.float16, device=dev)
        for s in range(0, R, step):
            f[s:s + step] = _smooth(basis, rots9[s:s + step], c, length).half()
        bases.append(basis)
        feats.append(f)
    ctx.sync()
    out["generate_s"] = time.perf_counter() - t0
    _log(f"retrieval: generated {K} x {R} features ({K * R * per_ref / 1e9:.1f} GB) in {out['generate_s']:.1f} s")
    # ---- queries
    n_q = max(a.fast_queries, a.greedy_queries, a.batch_queries)
    rng = np.random.default_rng(5)
    q_obj = rng.integers(0, K, n_q)
    q_rot = torch.from_numpy(haar_uniform(n_q, seed=6).reshape(n_q, 9).astype(np.float32)).to(dev)
    qgen = torch.Generator(device=dev).manual_seed(7)
    queries = [_smooth(bases[o], q_rot[i:i + 1], c, length, 1.0, qgen)[0] for i, o in enumerate(q_obj)]
    warm = _smooth(bases[0], torch.from_numpy(haar_uniform(1, seed=99).reshape(1, 9).astype(np.float32)).to(dev),
                   c, length, 1.0, qgen)[0]
    out["query_objects"] = q_obj.tolist()
    # ---- bank
    Bank = _torch_bank_class()
    names = [f"obj{o:02d}" for o in range(K)]
    t0 = time.perf_counter()
    bank = Bank(feats, rots, names, k_ac=k_ac)
    out["bank_build_s"] = time.perf_counter() - t0  # FPS of the anchors (CPU, numpy)
    t0 = time.perf_counter()
    bank.anchor_feats(k_ac)
    ctx.sync()
    out["anchor_gather_s"] = time.perf_counter() - t0
    out["anchors_k"] = int(len(bank.anchors(k_ac)))
    scorer = model_scorer(model, dev)
    if ctx.cuda:
        out["cuda_memory_after_bank"] = cuda_mem()

    def timed_queries(fn, bk, qs, deadline, *args, **kw):
        preds, secs = [], []
        for q in qs:
            if secs and time.perf_counter() + max(secs) > deadline:
                break
            ctx.sync()
            t0 = time.perf_counter()
            preds.append(fn(q, bk, scorer, *args, **kw))
            ctx.sync()
            secs.append(time.perf_counter() - t0)
        comps = [p.n_comparisons for p in preds]
        return preds, {"n_queries": len(preds), "n_planned": len(qs), "cut_short": len(preds) < len(qs),
                       "s_per_query_median": statistics.median(secs) if secs else None, "s_per_query_all": secs,
                       "comparisons_per_query_median": statistics.median(comps) if comps else None,
                       "comparisons_per_query_all": comps,
                       "pair_scores_per_s": sum(comps) / sum(secs) if secs else None}

    # ---- fast (single query)
    t0 = time.perf_counter()
    fast_cfg = SearchConfig("fast", k_ac=k_ac, fps_k=fps_k)
    fast_search(warm, bank, scorer, fast_cfg)
    ctx.sync()
    out["fast_warmup_s"] = time.perf_counter() - t0
    left = stop_at - time.perf_counter()
    fp, fast = timed_queries(fast_search, bank, queries[:a.fast_queries], time.perf_counter() + 0.3 * left, fast_cfg)
    out["fast"] = fast
    out["cut_short"] |= fast["cut_short"]
    _log(f"retrieval fast: {fast['s_per_query_median']:.3f} s/query, "
         f"{fast['comparisons_per_query_median']:.0f} comparisons")
    # ---- greedy: estimate from the fast pair rate; shrink to a sub-bank (extrapolated) if it cannot fit
    rate = fast["pair_scores_per_s"] or 1.0
    est = K * R / rate
    left = stop_at - time.perf_counter() - (0.25 * (stop_at - time.perf_counter()) if a.batch_queries else 0)
    out["greedy_estimate_s_per_query"] = est
    k_sub = K
    n_greedy = min(a.greedy_queries, max(1, int(left * 0.8 // est)))
    if est > 0.8 * left:
        k_sub = max(1, int(K * 0.8 * left / est))
        n_greedy = 1
    gbank = bank if k_sub == K else Bank(feats[:k_sub], rots, names[:k_sub], k_ac=min(k_ac, 1))
    g_idx = [i for i in range(n_q) if q_obj[i] < k_sub][:n_greedy] or [0]
    gp, greedy = timed_queries(greedy_search, gbank, [queries[i] for i in g_idx], stop_at, group=1024)
    greedy["objects_in_bank"] = k_sub
    if k_sub < K:
        greedy["extrapolated_to_all_objects"] = True
        greedy["s_per_query_measured_median"] = greedy["s_per_query_median"]
        greedy["s_per_query_median"] = greedy["s_per_query_median"] * K / k_sub
        greedy["comparisons_per_query_median"] = K * R
        greedy["note"] = (f"only {k_sub} of {K} objects fit the time cap: seconds measured over {k_sub} x {R} "
                          f"references and scaled by {K}/{k_sub} (greedy cost is linear in the bank size)")
        out["cut_short"] = True
    out["greedy"] = greedy
    out["cut_short"] |= greedy["cut_short"]
    _log(f"retrieval greedy ({k_sub} objects): {greedy['s_per_query_median']:.3f} s/query"
         f"{' (extrapolated)' if k_sub < K else ''}")
    if fast["s_per_query_median"] and greedy["s_per_query_median"]:
        out["speedup_greedy_over_fast"] = greedy["s_per_query_median"] / fast["s_per_query_median"]
        out["comparison_ratio_greedy_over_fast"] = K * R / fast["comparisons_per_query_median"]
    common = [(fp[j], gp[i]) for i, j in enumerate(g_idx) if j < len(fp) and i < len(gp)] if k_sub == K else []
    out["fast_greedy_same_reference"] = (float(np.mean([f.obj_index == g.obj_index and f.ref_index == g.ref_index
                                                         for f, g in common])) if common else None)
    out["greedy_object_correct"] = (float(np.mean([gp[i].obj_index == q_obj[j] for i, j in enumerate(g_idx)
                                                   if i < len(gp)])) if gp and k_sub == K else None)
    # ---- fast, anchors of a batch of queries scored together (search_all query_batch)
    qb_n = a.batch_queries
    if qb_n and fast["s_per_query_median"]:
        left = stop_at - time.perf_counter()
        if qb_n * fast["s_per_query_median"] * 1.5 < left:
            qb = torch.stack(queries[:qb_n])
            ctx.sync()
            t0 = time.perf_counter()
            bp = search_all(qb, bank, scorer, SearchConfig("fast", k_ac=k_ac, fps_k=fps_k, query_batch=qb_n), progress=False)
            ctx.sync()
            wall = time.perf_counter() - t0
            out["fast_batched"] = {
                "n_queries": len(bp), "query_batch": qb_n, "wall_s": wall, "s_per_query_mean": wall / len(bp),
                "s_per_query_median": statistics.median(p.seconds for p in bp),
                "comparisons_per_query_median": statistics.median(p.n_comparisons for p in bp),
                "same_predictions_as_single_query": float(np.mean(
                    [x.obj_index == y.obj_index and x.ref_index == y.ref_index for x, y in zip(bp, fp)]))
                if fp else None,
                "note": "search_all(method='fast', query_batch=n): anchors of n queries scored in one many-query pass"}
            _log(f"retrieval fast batched: {wall / len(bp):.3f} s/query")
        else:
            out["fast_batched"] = {"skipped": f"{qb_n} queries x {fast['s_per_query_median']:.2f} s would exceed "
                                              f"the {left:.0f} s left"}
            out["cut_short"] = True
    if ctx.cuda:
        out["cuda_memory_end"] = cuda_mem()
    out["section_s"] = time.perf_counter() - t_sec
    del bank, gbank, feats, bases, model
    release_cuda()
    return out
