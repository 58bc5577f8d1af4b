"""Section 4 of the CPU benchmark: dense GEMM rate, and the learned fusion's pair scores/s against it.

* ``gemm``: fp32 ``torch.matmul`` n x n, this machine's dense-arithmetic ceiling;
* ``fusion``: ``model.score`` (inference) of float32 queries against float16
  references, with the FLOPs per pair counted from the code
  (:func:`fusion_flops_per_pair`) and the fraction of the GEMM rate achieved.

Called by ``benchmarks/bench.py``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from bench_train import _model
from timing import log, measure, wait_quiet

if TYPE_CHECKING:
    from bench_config import BenchConfig


def bench_gemm(cfg: BenchConfig) -> dict:
    """fp32 GEMM rate of this machine (torch.matmul n x n by n x n)."""
    import torch

    g = torch.Generator().manual_seed(cfg.seed)
    a = torch.randn(cfg.gemm_n, cfg.gemm_n, generator=g)
    bm = torch.randn(cfg.gemm_n, cfg.gemm_n, generator=g)
    wait_quiet()
    t = measure(lambda _: torch.matmul(a, bm), cfg.gemm_repeats, 1)
    flops = 2.0 * cfg.gemm_n ** 3
    return {**t, "n": cfg.gemm_n, "flops": flops, "gflops_per_s": flops / t["median_s"] / 1e9}


def fusion_flops_per_pair(model) -> dict:
    """FLOPs of one query/reference score in ``OrientationNet.score`` (inference), counted from the code.

    Per level with X locations and C channels, ``_fuse_block`` does:

    * ``prod = r * q``: C*X multiplies;
    * ``logits = w @ prod + b``: 2*K*C*X (K = 2 logits for "adaptive", 1 for
      "sigmoid"/"softmax") plus K*X bias adds;
    * log weights and softmax over X: ~ X*(3 if K=2: logsigmoid, add) + 4*X
      (max-subtract, exp, sum, divide), counted as 1 FLOP per elementwise op
      (transcendentals are several FLOPs in reality; this part is < 2 %);
    * weighted sum ``bmm(prod, a)``: 2*C*X.

    Then the head on the concatenated n_levels*C vector: Linear (2*in*out +
    out), LeakyReLU (out), Linear (2*in*out + out), tanh (1).
    The float16 -> float32 promotion of r is not counted (no arithmetic).
    """
    if model.fusion is None:
        raise ValueError("fusion_flops_per_pair: model has no learned fusion head")
    c = model.cfg.channels
    k = 2 if model.fusion.fusion == "adaptive" else 1
    per_level = {}
    for lv, sl in model.scale_slices.items():
        x = sl.stop - sl.start
        terms = {"product": c * x, "logits": 2 * k * c * x + k * x,
                 "softmax_weights": (3 * x if k == 2 else x) + 4 * x, "weighted_sum": 2 * c * x}
        per_level[str(lv)] = {"locations": x, **terms, "total": sum(terms.values())}
    head = 0
    for mod in model.fusion.mlp:
        if hasattr(mod, "in_features"):
            head += 2 * mod.in_features * mod.out_features + mod.out_features
        else:  # activation
            head += model.fusion.mlp[0].out_features
    head += 1  # tanh
    total = sum(v["total"] for v in per_level.values()) + head
    return {"per_level": per_level, "head_mlp": head, "total": total, "channels": c, "logits_K": k,
            "feature_length": model.feature_length,
            "formula": "sum over levels of (C*X + (2*K*C*X + K*X) + ~(3+4)*X + 2*C*X) + MLP; "
                       "~(2K+3)*C*L + 2*(3C*H) for K=2, H=128"}


def _unit_features(n: int, c: int, length: int, seed: int, dtype=np.float32) -> np.ndarray:
    """(n, C, L) random maps, each location a unit vector over C (like the encoder's output)."""
    x = np.random.default_rng(seed).standard_normal((n, c, length), dtype=np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return x.astype(dtype)


def bench_fusion(cfg: BenchConfig, size: int, gemm_gflops: float) -> dict:
    """Pair scores/s of model.score (inference) against float16 references, and the GEMM fraction."""
    import torch

    model = _model(size, cfg.seed).eval()
    c, length = model.cfg.channels, model.feature_length
    flops = fusion_flops_per_pair(model)
    pool = _unit_features(256, c, length, cfg.seed + 1, np.float16)
    q_all = torch.from_numpy(_unit_features(max(1, cfg.fusion_q), c, length, cfg.seed + 2))
    out: dict[str, Any] = {"image_size": size, "C": c, "L": length, "flops_per_pair": flops["total"],
                           "flop_count": flops, "reference_dtype": "float16", "query_dtype": "float32"}
    for nq, nr in ((1, cfg.fusion_refs_q1), (cfg.fusion_q, cfg.fusion_refs_qmany)):
        r = torch.from_numpy(pool[np.arange(nr) % len(pool)])
        q = q_all[:nq]
        with torch.inference_mode():
            model.score(q[:1], r[:64])  # warm-up on a small slice (same code path)

            def run(_):
                with torch.inference_mode():
                    return model.score(q, r)

            wait_quiet()
            t = measure(run, cfg.fusion_repeats, 0)
        pairs = nq * nr
        rate = pairs / t["median_s"]
        achieved = rate * flops["total"] / 1e9
        out[f"Q{nq}"] = {**t, "Q": nq, "R": nr, "pairs": pairs, "pair_scores_per_s": rate,
                         "achieved_gflops_per_s": achieved, "fraction_of_gemm": achieved / gemm_gflops,
                         "warmup_note": "one untimed score() on 64 references before the repeats"}
        log(f"fusion {size}px Q={nq}: {rate:.0f} pair-scores/s, {achieved:.2f} GFLOP/s")
    return out
