"""The retrieval network: multi-scale local features and their learned fusion.

Follows the method of Zhao, Hu & Salzmann (ECCV 2022) as described in
``docs/method.md``:

* :func:`preprocess` turns RGB crops into locally normalised grey images.
* :class:`OrientationNet` encodes an image (with the :mod:`helpers.net.backbone`
  encoder-decoder) into unit-norm feature maps at up to three decoder levels (named 32, 16 and 13 after their side length at a
  128 px input), and scores a query against references by fusing the
  per-location similarities.

Feature tensors are ``(B, C, L)`` float: the selected levels' maps flattened
row-major and concatenated in the order 32, 16, 13 (``L = 1449`` at 128 px
with all three). :attr:`OrientationNet.scale_slices` splits ``L`` again.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint

from ..core.configs import ModelConfig, level_shapes
from ..core.local_norm import images_to_tensor, preprocess  # re-exported: callers import them from here too
from ..core.precision import autocast
from . import fusion_kernel
from .backbone import Decoder, Encoder

# Block budgets (elements) for the float32 products q_i * r_j formed when
# fusing many pairs. 2**17 floats = 512 kB stays in a CPU core's L2 cache,
# which measured 2-3x faster than larger blocks for the passes over each block.
# With autograd, blocks are checkpointed and Python overhead per block
# matters more than cache, so they are larger.
_BLOCK_ELEMENTS = 2 ** 17
_BLOCK_ELEMENTS_GRAD = 2 ** 22
# On a GPU the blocks are sized for launch overhead, not a cache: 2**26 floats = 256 MB.
_BLOCK_ELEMENTS_GPU = 2 ** 26
# Reference dtypes scored as they are stored (anything else is promoted to float32 first).
_KERNEL_DTYPES = (torch.float16, torch.float32)
# References per slice in the bilinear-logit path (slice * C * X <= this): the
# float32 copy of the slice that the batched matmul needs stays at 16 MB.
_SLICE_ELEMENTS = 2 ** 22
# From this many queries on, logits come from the bilinear form (one batched
# matmul shared by all queries) instead of from each query's product block.
# Measured at 128 px, one thread: Q=1 blocked 1.6x faster, Q=2 about even,
# Q=4 bilinear 2x faster, Q=16 3.3x.
_BILINEAR_MIN_QUERIES = 2


# --------------------------------------------------------------------------- fusion

class Fusion(nn.Module):
    """Learned fusion head: per-level 1x1 conv to the logits, then an MLP.

    Per level a 1x1 conv (stored as Linear, weight (K, C)) maps the local
    similarity q*r at every location to K logits: K=2 (local l, global g) for
    "adaptive", K=1 (l) for "sigmoid", K=1 (g) for "softmax".
    """

    def __init__(self, fusion: str, levels: tuple[int, ...], channels: int, hidden: int = 128) -> None:
        super().__init__()
        self.fusion = fusion
        k = 2 if fusion == "adaptive" else 1
        self.logit = nn.ModuleDict({str(lv): nn.Linear(channels, k) for lv in levels})
        self.mlp = nn.Sequential(nn.Linear(len(levels) * channels, hidden), nn.LeakyReLU(),
                                 nn.Linear(hidden, 1))

    def log_weights(self, logits: torch.Tensor) -> torch.Tensor:
        """Unnormalised log fusion weights (..., X) from logits (..., K, X).

        All variants are written as a log so that one softmax normalises them
        stably: adaptive exp(g) sigmoid(l) -> g + logsigmoid(l); sigmoid ->
        logsigmoid(l); softmax -> g.
        """
        if self.fusion == "adaptive":
            return logits[..., 1, :] + F.logsigmoid(logits[..., 0, :])
        if self.fusion == "sigmoid":
            return F.logsigmoid(logits[..., 0, :])
        return logits[..., 0, :]

    def head(self, v: torch.Tensor) -> torch.Tensor:
        """Concatenated per-level vectors (..., n_levels*C) -> score (...) in (-1, 1)."""
        return torch.tanh(self.mlp(v)).squeeze(-1)


def _fuse_block(fusion: "Fusion", w: torch.Tensor, b: torch.Tensor,
                q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """Fused vectors of one query against a block of references at one level.

    Args:
        fusion: provides the log-weight rule of the variant.
        w, b: (K, C), (K,) the level's 1x1 logit conv.
        q: (C, X) float32 query map; r: (Rb, C, X) reference maps (float16 is
            promoted inside the product, so no separate cast pass).

    Returns:
        (Rb, C): v[j, c] = sum_x a[j, x] q[c, x] r[j, c, x], with a the
        normalised fusion weights computed from the logits W (q*r) + b.
    """
    prod = r * q                                                  # (Rb, C, X) local similarity
    logits = torch.bmm(w.expand(prod.shape[0], -1, -1), prod) + b[:, None]                # (Rb, K, X)
    a = torch.softmax(fusion.log_weights(logits), dim=-1)        # (Rb, X)
    return (prod * a.unsqueeze(1)).sum(-1)  # thin bmm is slow on CPU (benchmarks/README.md, Hot-path history)


def _weighted_block(a: torch.Tensor, q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """v[j, c] = sum_x a[j, x] q[c, x] r[j, c, x]; a (Rb,X), q (C,X), r (Rb,C,X) -> (Rb,C)."""
    return torch.bmm(r * q, a.unsqueeze(-1)).squeeze(-1)


class OrientationNet(nn.Module):
    """Encoder-decoder plus fusion head (see module docstring).

    Attributes:
        cfg: the :class:`ModelConfig`.
        scale_shapes: level -> (h, w) of its map in the feature tensor
            ({13: (1, 1)} for "global").
        scale_slices: level -> slice of the L axis holding that level.
        feature_length: L.
    """

    def __init__(self, cfg: ModelConfig | None = None) -> None:
        super().__init__()
        self.cfg = cfg if cfg is not None else ModelConfig()
        c = self.cfg
        self.encoder = Encoder()
        self.decoder = Decoder(c.levels, c.channels, c.dropout)
        learned = not c.is_global and c.fusion != "avg"
        self.fusion = Fusion(c.fusion, c.levels, c.channels) if learned else None
        shapes = level_shapes(c.image_size)
        self.scale_shapes: dict[int, tuple[int, int]] = (
            {13: (1, 1)} if c.is_global else {lv: shapes[lv] for lv in c.levels})
        self.scale_slices: dict[int, slice] = {}
        start = 0
        for lv, (h, w) in self.scale_shapes.items():
            self.scale_slices[lv] = slice(start, start + h * w)
            start += h * w
        self.feature_length = start
        # Inference-time fusion on CPU: "auto" uses the fused kernel (helpers.net.fusion_kernel) when
        # it builds, "eager" always the PyTorch ops, "kernel" insists on the kernel. Not part of
        # the config: both compute the same scores (to float32 rounding).
        self.fusion_backend = "auto"
        # Precision of the encoder-decoder's convolutions: "fp32" or "bf16" (autocast, see
        # helpers.core.precision). A runtime setting like fusion_backend, not part of the config:
        # training records the one it used in its checkpoints.
        self.precision = "fp32"
        # NHWC convolutions are ~1.2x faster on CPU here (oneDNN), forward and backward;
        # load_state_dict copies into these parameters and keeps their layout.
        self.to(memory_format=torch.channels_last)

    # ------------------------------------------------------------------ encoding

    def preprocess(self, images: torch.Tensor) -> torch.Tensor:
        """:func:`preprocess` with this model's settings: (B,3,S,S) -> (B,1,S,S)."""
        return preprocess(images, self.cfg.local_norm, self.cfg.norm_window)

    def encode(self, images: torch.Tensor) -> torch.Tensor:
        """Images (B, 3, S, S) float in [0, 1] (or uint8) -> features (B, C, L) float32.

        Each location is a unit vector over C. For "global", L = 1: the raw
        level-13 head output averaged over locations, then L2-normalised.
        """
        s = self.cfg.image_size
        if not torch.is_tensor(images):
            raise ValueError(f"images: expected a torch tensor (B,3,{s},{s}), got {type(images).__name__}")
        if images.ndim != 4 or tuple(images.shape[1:]) != (3, s, s):
            raise ValueError(f"images: expected (B,3,{s},{s}), got {tuple(images.shape)}")
        if images.dtype != torch.uint8:
            if not images.is_floating_point():
                raise ValueError(f"images: expected uint8 in [0, 255] or float in [0, 1], got {images.dtype}")
            if images.numel() and (images.min() < -1e-3 or images.max() > 1.0 + 1e-3):
                raise ValueError(f"images: float images must lie in [0, 1] (got [{float(images.min()):.3g}, "
                                 f"{float(images.max()):.3g}]); divide 8-bit values by 255")
        x = self.preprocess(images.to(next(self.parameters()).device))
        with autocast(self.precision, x.device):
            maps = self.decoder(*self.encoder(x))
        # Features leave the network as float32 (normalised, scored and cached as before).
        maps = {lv: m.float() for lv, m in maps.items()}
        if self.cfg.is_global:
            return F.normalize(maps[13].mean(dim=(2, 3)), dim=1).unsqueeze(-1)
        flat = [F.normalize(maps[lv], dim=1).flatten(2) for lv in self.cfg.levels]
        return torch.cat(flat, dim=2)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.encode(images)

    # ------------------------------------------------------------------- scoring

    def _check(self, f: torch.Tensor, name: str) -> None:
        want = (self.cfg.channels, self.feature_length)
        if f.ndim != 3 or tuple(f.shape[1:]) != want:
            raise ValueError(f"{name}: expected features (N,{want[0]},{want[1]}), got {tuple(f.shape)}")

    def _fusion_params(self, level: int) -> tuple[torch.Tensor, torch.Tensor]:
        lin = self.fusion.logit[str(level)]
        return lin.weight, lin.bias

    def _fused_vectors(self, level: int, q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
        """Per-level fused vectors for all pairs: q (Q,C,X), r (R,C,X) -> (Q, R, C).

        v[i, j, c] = sum_x a_ij(x) q_ic(x) r_jc(x). The three factors share x,
        so no order of contractions avoids a Q*R*C*X intermediate; it is
        formed in blocks of (one query, Rb references) with Rb*C*X bounded,
        so memory never grows with Q or R. With autograd each block is
        checkpointed, so backward keeps only its inputs, not the blocks.

        The logits l_ij(x) = sum_c W_c q_ic(x) r_jc(x) + b are bilinear in
        (q, r). With several queries they are computed for all queries at
        once as a batched matmul over x (W folded into q); with a single
        query it is cheaper to take them from each product block, which is
        in cache anyway (see ``_BILINEAR_MIN_QUERIES``).
        """
        w, b = self._fusion_params(level)
        nq, c, nx = q.shape
        grad = torch.is_grad_enabled() and (q.requires_grad or r.requires_grad or w.requires_grad)
        gpu = q.device.type != "cpu"
        budget = _BLOCK_ELEMENTS_GPU if gpu else (_BLOCK_ELEMENTS_GRAD if grad else _BLOCK_ELEMENTS)
        rb = max(1, budget // (c * nx))

        def run(fn, *args):
            return checkpoint(fn, *args, use_reentrant=False) if grad else fn(*args)

        if nq < _BILINEAR_MIN_QUERIES:
            return torch.stack([torch.cat([run(_fuse_block, self.fusion, w, b, q[i], r[s:s + rb])
                                           for s in range(0, r.shape[0], rb)], 0) for i in range(nq)], 0)
        k = w.shape[0]
        qw = (q.unsqueeze(1) * w[None, :, :, None]).reshape(nq * k, c, nx)  # (Q*K, C, X)
        step = max(1, (_BLOCK_ELEMENTS_GPU if gpu else _SLICE_ELEMENTS) // (c * nx))
        out = []
        for s0 in range(0, r.shape[0], step):
            rs = r[s0:s0 + step].float()
            logits = torch.einsum("mcx,rcx->mrx", qw, rs)                   # (Q*K, Rs, X)
            logits = logits.reshape(nq, k, -1, nx).transpose(1, 2) + b[:, None]
            a = torch.softmax(self.fusion.log_weights(logits), dim=-1)      # (Q, Rs, X)
            out.append(torch.stack([torch.cat([run(_weighted_block, a[i, s:s + rb], q[i], rs[s:s + rb])
                                               for s in range(0, rs.shape[0], rb)], 0)
                                    for i in range(nq)], 0))
        return torch.cat(out, 1)

    def _score_chunk(self, q: torch.Tensor, r: torch.Tensor, rows: torch.Tensor | None = None) -> torch.Tensor:
        """q (Q,C,L) float32, r (Rc,C,L) float16/32 on the same device -> (Q, Rc).

        ``rows`` (M,) int64: score r[rows] instead -> (Q, M). The CPU kernel reads
        those rows in place (no gathered copy); other paths gather them first.
        """
        kernel = None if self.cfg.is_global or self.fusion is None else self._kernel(q, r)
        if rows is not None and (kernel is None or not r.is_contiguous() or r.dtype not in _KERNEL_DTYPES):
            r, rows = r[rows].to(device=q.device, dtype=r.dtype if r.dtype in _KERNEL_DTYPES else torch.float32), None
        if self.cfg.is_global:
            return q[:, :, 0] @ r[:, :, 0].float().T
        if self.fusion is None:  # "avg": per-level mean cosine is one matmul on flattened maps
            total = 0.0
            for sl in self.scale_slices.values():
                n = sl.stop - sl.start
                total = total + q[:, :, sl].flatten(1) @ r[:, :, sl].float().flatten(1).T / n
            return total / len(self.scale_slices)
        if kernel is not None:
            # One kernel call per query covers every level (level-major (M, n*C), as the cat below).
            r = r.contiguous()
            if rows is None:
                rows = torch.arange(r.shape[0])
            mode = fusion_kernel.MODES[self.cfg.fusion]
            params = [self._fusion_params(lv) for lv in self.scale_slices]
            w = torch.stack([t.detach().float() for t, _ in params]).contiguous()  # (n, K, C)
            b = torch.stack([t.detach().float() for _, t in params]).contiguous()  # (n, K)
            offs = [sl.start for sl in self.scale_slices.values()]
            widths = [sl.stop - sl.start for sl in self.scale_slices.values()]
            fused = torch.stack([kernel.fuse_levels(q[i].contiguous(), r, rows, offs, widths, w, b, mode)
                                 for i in range(q.shape[0])], 0)
            return self.fusion.head(fused)
        vs = [self._fused_vectors(lv, q[:, :, sl], r[:, :, sl]) for lv, sl in self.scale_slices.items()]
        return self.fusion.head(torch.cat(vs, dim=-1))

    def _kernel(self, q: torch.Tensor, r: torch.Tensor):
        """The fused CPU kernel if this call may use it (inference on CPU, learned fusion), else None."""
        if self.fusion_backend == "eager" or q.device.type != "cpu" or r.device.type != "cpu":
            return None
        if torch.is_grad_enabled() and (q.requires_grad or r.requires_grad
                                        or any(p.requires_grad for p in self.fusion.parameters())):
            return None  # training: the eager path has autograd
        kernel = fusion_kernel.get()
        if kernel is None and self.fusion_backend == "kernel":
            raise RuntimeError(f"fusion_backend='kernel' but the kernel is unavailable: "
                               f"{fusion_kernel.status()['reason']}")
        return kernel

    def score(self, q: torch.Tensor, r: torch.Tensor, chunk: int = 1024,
              rows: torch.Tensor | None = None) -> torch.Tensor:
        """All query/reference scores.

        Args:
            q: (Q, C, L) query features.
            r: (R, C, L) reference features, float16/32 on any device (e.g.
                a float16 memory-mapped cache on CPU); moved to q's device one
                chunk at a time and promoted to float32 block by block.
            rows: optional (M,) int64 indices: score only r[rows] -> (Q, M), in
                that order. On CPU the fused kernel reads those rows where
                they lie (a memory-mapped bank is not copied); elsewhere each
                chunk of rows is gathered first.
            chunk: references (or rows) per chunk. Peak extra memory is about one
                chunk on q's device (``chunk * C * L`` elements of r's dtype)
                plus the (Q, chunk, C) fused vectors; the float32 working
                blocks are capped (q*r blocks 0.5 MB, 16 MB with autograd;
                with several queries a 16 MB float32 slice of r plus its
                logits, about Q x 0.25 MB), whatever R and chunk.

        Returns:
            (Q, R) float32 scores: tanh output of the fusion head in (-1, 1),
            or a mean cosine in [-1, 1] for "avg" and "global".

        Differentiable (used for training) and safe under inference_mode.
        Without autograd on CPU the learned fusion runs in the fused kernel of
        :mod:`helpers.net.fusion_kernel` (see ``fusion_backend``); same scores to
        float32 rounding.
        """
        self._check(q, "q")
        self._check(r, "r")
        if chunk < 1:
            raise ValueError(f"chunk: expected >= 1, got {chunk}")
        q = q.float()
        if rows is not None:
            rows = torch.as_tensor(rows, dtype=torch.int64, device="cpu")
            if rows.ndim != 1 or (len(rows) and (int(rows.min()) < 0 or int(rows.max()) >= r.shape[0])):
                raise ValueError(f"rows: expected (M,) indices in [0, {r.shape[0]}), got shape {tuple(rows.shape)}"
                                 + (f", range [{int(rows.min())}, {int(rows.max())}]" if rows.numel() else ""))
            out = [self._score_chunk(q, r, rows[s:s + chunk]) for s in range(0, len(rows), chunk)]
            return torch.cat(out, dim=1) if out else q.new_zeros(q.shape[0], 0)
        keep = r.dtype in _KERNEL_DTYPES
        out = [self._score_chunk(q, r[s:s + chunk].to(device=q.device,
                                                      dtype=r.dtype if keep else torch.float32))
               for s in range(0, r.shape[0], chunk)]
        return torch.cat(out, dim=1) if out else q.new_zeros(q.shape[0], 0)

    def _pair_weights(self, q: torch.Tensor, r: torch.Tensor) -> dict[int, tuple[torch.Tensor, torch.Tensor]]:
        """Per level: (local similarity q*r (B,C,X), fusion weights (B,X)) for aligned pairs."""
        out = {}
        for lv, sl in self.scale_slices.items():
            prod = q[:, :, sl] * r[:, :, sl]
            if self.fusion is None:
                a = prod.new_full((prod.shape[0], prod.shape[2]), 1.0 / prod.shape[2])
            else:
                w, b = self._fusion_params(lv)
                logits = torch.einsum("kc,bcx->bkx", w, prod) + b[:, None]
                a = torch.softmax(self.fusion.log_weights(logits), dim=-1)
            out[lv] = (prod, a)
        return out

    def score_pairs(self, q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
        """Scores of aligned pairs: q (B,C,L), r (B,C,L) -> (B,), equal to diag of :meth:`score`."""
        self._check(q, "q")
        self._check(r, "r")
        if q.shape[0] != r.shape[0]:
            raise ValueError(f"score_pairs: q and r must have the same batch size, got {q.shape[0]} and {r.shape[0]}")
        q = q.float()
        r = r.to(device=q.device, dtype=torch.float32)
        parts = self._pair_weights(q, r)
        if self.fusion is None:
            # Uniform weights: mean of per-level mean cosines (same as "avg"/"global" in score).
            cos = [(prod * a[:, None]).sum(dim=(1, 2)) for prod, a in parts.values()]
            return torch.stack(cos, 0).mean(0)
        vs = [torch.bmm(prod, a.unsqueeze(-1)).squeeze(-1) for prod, a in parts.values()]
        return self.fusion.head(torch.cat(vs, dim=-1))

    def fusion_maps(self, q: torch.Tensor, r: torch.Tensor) -> dict[int, torch.Tensor]:
        """Normalised fusion weights for aligned pairs: level -> (B, h, w), each map sums to 1.

        Uniform for "avg" and "global". Meant for confidence-map figures.
        """
        self._check(q, "q")
        self._check(r, "r")
        parts = self._pair_weights(q.float(), r.to(device=q.device, dtype=torch.float32))
        return {lv: a.reshape(a.shape[0], *self.scale_shapes[lv]) for lv, (_, a) in parts.items()}


def count_parameters(model: OrientationNet) -> dict[str, int]:
    """Trainable parameter counts: encoder_decoder, fusion_head (0 for avg/global), total."""
    enc = sum(p.numel() for m in (model.encoder, model.decoder) for p in m.parameters())
    fus = 0 if model.fusion is None else sum(p.numel() for p in model.fusion.parameters())
    return {"encoder_decoder": enc, "fusion_head": fus, "total": enc + fus}
