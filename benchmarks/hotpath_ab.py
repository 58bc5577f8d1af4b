#!/usr/bin/env python
"""A/B evidence for two proposed hot-path changes (nothing in src/ is modified).

1. ``helpers.net.model._fuse_block`` (the Q=1 path every retrieval uses): the
   logits ``torch.matmul(w, prod)`` with w (K, C) and prod (Rb, C, X) is
   folded by torch into one skinny ``mm`` (Rb*X, C) @ (C, K) on a transposed
   view when Rb = 1 (every level-32 block at 128 px) and is slow there.
   Variants, swapped in by monkeypatching and checked to give the same
   scores:
   * ``bmm_logits``: ``torch.bmm(w.expand(Rb, -1, -1), prod)``;
   * ``mulsum``: weighted sum as ``(prod * a[:, None]).sum(-1)`` instead of
     ``bmm(prod, a[..., None])``;
   * both.
2. ``helpers.search.retrieval``: ``greedy_search`` and ``ReferenceBank.ref_feats``
   copy float16 reference features to float32 in numpy before scoring; the
   model's ``score`` already promotes float16 blocks inside its product.
   Variant: hand the float16 chunk to the scorer.

Run: ``.venv/bin/python benchmarks/hotpath_ab.py`` (about 2 minutes). The
variants are interleaved over 5 rounds and the median is reported, with the
share of the CPUs used by other processes (noise indicator).
"""

from __future__ import annotations

import statistics
import sys
from pathlib import Path

import numpy as np


def main() -> int:
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench

    import helpers.net.model as hm
    import helpers.search.retrieval as hr
    from helpers.core.rotations import haar_uniform

    torch.set_num_threads(2)
    orig_fb = hm._fuse_block

    def fb_bmm(fusion, w, b, q, r, mulsum=False):
        prod = r * q
        logits = torch.bmm(w.expand(prod.shape[0], -1, -1), prod) + b[:, None]
        a = torch.softmax(fusion.log_weights(logits), dim=-1)
        return (prod * a.unsqueeze(1)).sum(-1) if mulsum else torch.bmm(prod, a.unsqueeze(-1)).squeeze(-1)

    def fb_mulsum(fusion, w, b, q, r):
        prod = r * q
        logits = torch.matmul(w, prod) + b[:, None]
        a = torch.softmax(fusion.log_weights(logits), dim=-1)
        return (prod * a.unsqueeze(1)).sum(-1)

    variants = {"current": orig_fb, "bmm_logits": fb_bmm, "mulsum": fb_mulsum,
                "bmm_logits+mulsum": lambda *a: fb_bmm(*a, mulsum=True)}
    for size, n_refs in ((64, 2048), (128, 512)):
        model = bench._model(size, 0).eval()
        length = model.feature_length
        pool = bench._unit_features(256, 128, length, 1, np.float16)
        r = torch.from_numpy(pool[np.arange(n_refs) % 256])
        q = torch.from_numpy(bench._unit_features(1, 128, length, 2))
        rates = {k: [] for k in variants}
        diffs = dict.fromkeys(variants, 0.0)
        others = []
        with torch.inference_mode():
            ref = model.score(q, r)
            for _ in range(5):
                for k, fb in variants.items():
                    hm._fuse_block = fb
                    model.score(q, r[:16])
                    with bench.Probe() as p:
                        out = model.score(q, r)
                    diffs[k] = max(diffs[k], float((out - ref).abs().max()))
                    rates[k].append(n_refs / p.wall)
                    others.append(p.others or 0.0)
        hm._fuse_block = orig_fb
        base = statistics.median(rates["current"])
        print(f"model.score Q=1, R={n_refs} float16, {size} px (max share of CPUs used by others {max(others):.2f})")
        for k, v in rates.items():
            m = statistics.median(v)
            print(f"   {k:20s} {m:8.0f} pair-scores/s  x{m / base:.2f}  max|score diff| {diffs[k]:.1e}")

    # ---- retrieval: float16 chunks straight to the scorer
    k_obj, n_refs, c = 13, 2000, 128
    model = bench._model(64, 0, monotone=True).eval()
    length = model.feature_length
    rots = haar_uniform(n_refs, seed=0)
    bases = bench._smooth_bases(k_obj, c, length, 0)
    feats = [bench._smooth_features(b, rots, c, length).astype(np.float16) for b in bases]
    bank = hr.ReferenceBank(feats, rots, [str(i) for i in range(k_obj)])
    scorer = hr.model_scorer(model)
    rng = np.random.default_rng(1)
    queries = [torch.from_numpy(bench._smooth_features(bases[i % k_obj], haar_uniform(1, seed=10 + i), c, length,
                                                       1.0, rng)[0]) for i in range(3)]

    def greedy_fp16(query_feat, bank, scorer, group=1024):
        qt = hr._as_query(query_feat)
        best = (-np.inf, 0, 0)
        for o, f in enumerate(bank.feats):
            for s in range(0, bank.n_refs, group):
                sc = hr._run_scorer(scorer, qt, torch.from_numpy(np.ascontiguousarray(f[s:s + group])))
                j = int(np.argmax(sc))
                if sc[j] > best[0]:
                    best = (float(sc[j]), o, s + j)
        score, o, ri = best
        return hr.Prediction(o, ri, score, bank.n_objects * bank.n_refs, bank.rotations[ri].copy(), bank.names[o])

    orig_ref_feats = hr.ReferenceBank.ref_feats

    def ref_feats_fp16(self, obj, idx):
        idx = np.asarray(idx, dtype=np.int64)
        order = np.argsort(idx)
        out = np.empty((len(idx), *self.feats[obj].shape[1:]), dtype=self.feats[obj].dtype)
        out[order] = self.feats[obj][idx[order]]
        return torch.from_numpy(out)

    def run(label, fn, patch):
        hr.ReferenceBank.ref_feats = patch
        fn(queries[0], bank, scorer)
        secs, preds = [], []
        for qf in queries:
            with bench.Probe() as p:
                pr = fn(qf, bank, scorer)
            secs.append(p.wall)
            preds.append((pr.obj_index, pr.ref_index, pr.score, pr.n_comparisons))
        hr.ReferenceBank.ref_feats = orig_ref_feats
        return statistics.median(secs), preds

    print(f"retrieval over {k_obj} x {n_refs} float16 references at 64 px (median of {len(queries)} queries)")
    for name, cur, new in (("greedy_search", (hr.greedy_search, orig_ref_feats), (greedy_fp16, orig_ref_feats)),
                           ("fast_search", (hr.fast_search, orig_ref_feats), (hr.fast_search, ref_feats_fp16))):
        t0, p0 = run(name, *cur)
        t1, p1 = run(name, *new)
        print(f"   {name:14s} current {t0:.2f} s/query, float16 chunks {t1:.2f} s/query: x{t0 / t1:.2f}, "
              f"identical predictions: {p0 == p1}")
        hm._fuse_block = variants["bmm_logits+mulsum"]
        t2, p2 = run(name, *new)
        hm._fuse_block = orig_fb
        same = [a[:2] == b[:2] and abs(a[2] - b[2]) < 1e-6 for a, b in zip(p0, p2)]
        print(f"   {name:14s} float16 chunks + bmm_logits+mulsum {t2:.2f} s/query: x{t0 / t2:.2f}, "
              f"same predictions: {all(same)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
