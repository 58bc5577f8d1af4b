"""Sections 2, 3 and the training A/B of the CPU benchmark: the network's training and encoding speed.

* ``train``: images/s of one optimisation step (``helpers.training.train.train_step``);
* ``encode``: references/s of ``model.encode`` under ``inference_mode``;
* ``train_ab``: the training step as of git 1c2d2ee (A) against today's (B) in
  one process, interleaved, plus where a step's time goes (data vs compute).

Also the shared model constructor :func:`_model` and the monotone fusion
read-out used by the fusion and retrieval sections. Called by
``benchmarks/bench.py``.
"""

from __future__ import annotations

import inspect
import math
import statistics
from typing import TYPE_CHECKING, Any

import numpy as np
from timing import Probe, gate, log, measure, wait_quiet

if TYPE_CHECKING:
    from bench_config import BenchConfig


def _model(size: int, seed: int = 0, monotone: bool = False):
    import torch

    from helpers.core.configs import ModelConfig
    from helpers.net.model import OrientationNet

    torch.manual_seed(seed)
    m = OrientationNet(ModelConfig(image_size=size))
    if monotone:
        monotone_readout(m)
    return m


def monotone_readout(model) -> None:
    """Set the fusion MLP to score = tanh(3 * mean over levels of the fused cosine).

    The encoder, decoder and the per-location logit convs stay randomly
    initialised; only the MLP weights change, so the computation (and its
    cost) is exactly that of the trained network. A random MLP would make the
    score an arbitrary function of the fused vectors; this readout makes it
    grow with feature similarity, so the fast search walks a realistic score
    landscape (its comparison count depends on that).
    """
    import torch

    if model.fusion is None:
        return
    lin1, lin2 = model.fusion.mlp[0], model.fusion.mlp[2]
    with torch.no_grad():
        lin1.weight.zero_()
        lin1.bias.zero_()
        lin1.weight[0].fill_(1.0 / len(model.scale_slices))
        lin2.weight.zero_()
        lin2.bias.zero_()
        lin2.weight[0, 0] = 3.0


def _train_step_fn():
    """helpers.training.train.train_step if present with the expected signature, else a local copy."""
    try:
        from helpers.training.train import train_step

        params = list(inspect.signature(train_step).parameters)
        if params[:7] == ["model", "optimizer", "images", "q_obj", "q_rot", "r_obj", "r_rot"]:
            return train_step, "helpers.training.train.train_step"
    except ImportError:
        pass

    import torch

    def local_step(model, optimizer, images, q_obj, q_rot, r_obj, r_rot, tau=0.1, weighted=True):
        b = len(q_obj)
        feats = model.encode(images)
        scores = model.score(feats[:b], feats[b:])
        try:
            from helpers.training.losses import pair_weights, weighted_info_nce

            w = pair_weights(q_obj, q_rot, r_obj, r_rot) if weighted else None
            loss = weighted_info_nce(scores, torch.arange(b), w, tau)
        except ImportError:
            loss = torch.nn.functional.cross_entropy(scores / tau, torch.arange(b))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        return float(loss.detach())

    return local_step, "bench.local_step (helpers.training.train.train_step unavailable)"


def bench_train(cfg: BenchConfig, size: int) -> dict:
    """Training images/s: encode queries+references, fuse (B x 2B scores), weighted infoNCE, Adam step."""
    import torch

    from helpers.core.rotations import haar_uniform

    step, which = _train_step_fn()
    model = _model(size, cfg.seed).train()
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    rng = np.random.default_rng(cfg.seed)
    b, m = cfg.train_queries, cfg.train_refs
    images = torch.rand(b + m, 3, size, size, generator=torch.Generator().manual_seed(cfg.seed))
    q_obj = rng.integers(0, 13, b)
    r_obj = np.concatenate([q_obj, rng.integers(0, 13, m - b)])
    q_rot = haar_uniform(b, seed=cfg.seed)
    r_rot = np.concatenate([q_rot, haar_uniform(m - b, seed=cfg.seed + 1)])
    losses = []
    steps = cfg.train_steps if size < 128 else cfg.train_steps_large
    wait_quiet()
    t = measure(lambda _: losses.append(step(model, opt, images, q_obj, q_rot, r_obj, r_rot)), steps,
                cfg.train_warmup)
    if not all(math.isfinite(v) for v in losses):
        raise RuntimeError(f"bench_train({size}): non-finite loss {losses}")
    n_img = b + m
    return {**t, "image_size": size, "queries": b, "references": m, "images_per_step": n_img,
            "images_per_s": n_img / t["median_s"], "queries_per_s": b / t["median_s"],
            "step_fn": which, "loss_first_last": [losses[0], losses[-1]],
            "note": "random images; one forward over all queries+references, B x 2B fusion scores with "
                    "autograd, weighted infoNCE (tau 0.1), backward, Adam step"}


def bench_encode(cfg: BenchConfig, size: int) -> dict:
    """Reference encoding rate: model.encode on a batch under inference_mode (eval mode)."""
    import torch

    model = _model(size, cfg.seed).eval()
    x = torch.rand(cfg.encode_batch, 3, size, size, generator=torch.Generator().manual_seed(cfg.seed))

    def run(_):
        with torch.inference_mode():
            return model.encode(x)

    shape = tuple(run(None).shape)
    reps = cfg.encode_repeats if size < 128 else cfg.encode_repeats_large
    wait_quiet()
    t = measure(run, reps, 1)
    return {**t, "image_size": size, "batch": cfg.encode_batch, "feature_shape": list(shape[1:]),
            "refs_per_s": cfg.encode_batch / t["median_s"]}



# --------------------------------------------------------------------------- training A/B

AB_BASE_COMMIT = "1c2d2ee"


def _box_mean_1c2d2ee(padded, window: int):
    """The local-normalisation box filter as of git 1c2d2ee: ONE window x window stride-1
    average pool (O(HW r^2)), used for mu and for the mean of squares alike."""
    import torch.nn.functional as F

    return F.avg_pool2d(padded, window, stride=1)


class _Variant:
    """Context manager: the training step of variant "A" (git 1c2d2ee) or "B" (today's code).

    The only change to the training step since 1c2d2ee is ``helpers.core.local_norm._box_mean``
    (``preprocess`` looks it up at call time), so A swaps the old 2-D pool in and
    restores today's on exit, even if the step raises.
    """

    def __init__(self, name: str):
        self.name = name

    def __enter__(self) -> "_Variant":
        import helpers.core.local_norm as hm

        self._saved = hm._box_mean
        if self.name == "A":
            hm._box_mean = _box_mean_1c2d2ee
        return self

    def __exit__(self, *exc) -> None:
        import helpers.core.local_norm as hm

        hm._box_mean = self._saved


def synthetic_train_views(n_objects: int, n_refs: int, n_queries: int, size: int, context: float,
                          seed: int) -> tuple[dict, dict]:
    """(references, training queries): name -> ObjectViews shaped like ``helpers.study.pipeline.prepare_data``'s.

    References: (n_refs, S, S, 3) uint8, a textured ellipse on black, with masks.
    Queries: stored with context like the study's training queries: side
    C = round(S * context), the object (an ellipse of side ~S) centred on a noise
    background, with (C, C) bool masks, so the in-plane augmentation re-takes a
    box from the rotated mask as in training. Rotations are Haar-uniform. The
    content is arbitrary: the data side's cost depends on the shapes, not on it.
    """
    from helpers.core.rotations import haar_uniform
    from helpers.core.views import ObjectViews

    rng = np.random.default_rng(seed)

    def draw(n: int, side: int, background: bool) -> tuple[np.ndarray, np.ndarray]:
        yy, xx = np.mgrid[:side, :side].astype(np.float32) - (side - 1) / 2
        ax = rng.uniform(0.3, 0.5, (n, 1, 1, 2)).astype(np.float32) * size
        masks = (xx / ax[..., 0]) ** 2 + (yy / ax[..., 1]) ** 2 <= 1.0  # (n, side, side)
        obj = rng.uniform(40, 215, (n, 1, 1, 3)) + rng.normal(0, 25, (n, side, side, 3))
        bg = rng.uniform(0, 255, (n, side, side, 3)) if background else np.zeros((n, side, side, 3))
        img = np.where(masks[..., None], obj, bg)
        return np.clip(img, 0, 255).astype(np.uint8), masks

    side = int(round(size * context))
    refs, queries = {}, {}
    for o in range(n_objects):
        name = f"obj{o:02d}"
        img, masks = draw(n_refs, size, False)
        refs[name] = ObjectViews(name, img, haar_uniform(n_refs, seed=seed + 2 * o).astype(np.float32), masks)
        img, masks = draw(n_queries, side, True)
        queries[name] = ObjectViews(name, img, haar_uniform(n_queries, seed=seed + 2 * o + 1).astype(np.float32),
                                    masks, kind="query")
    return refs, queries


def _ab_batches(cfg: BenchConfig) -> tuple[Any, np.ndarray, np.random.Generator, list[tuple]]:
    """(batcher, order, rng, batches) for the training A/B at ``train_ab_size``.

    ``batcher`` is a ``helpers.training.batches._Batcher`` over a synthetic set,
    ``order`` the pick stream of ``(train_ab_steps + train_ab_data_repeats + 1) *
    train_ab_batch`` indices, ``rng`` the generator the batcher draws from (its
    state carries on into :func:`_ab_data_side`), and ``batches`` the
    ``train_ab_steps`` batches ``(images (3B, 3, S, S) float tensor, q_obj, q_rot,
    r_obj, r_rot)`` that every A and B block trains on.
    """
    from helpers.core.configs import AugmentConfig
    from helpers.net.model import images_to_tensor
    from helpers.training.batches import _Batcher, _order_stream

    size, b, n_steps = cfg.train_ab_size, cfg.train_ab_batch, cfg.train_ab_steps
    refs, queries = synthetic_train_views(cfg.train_ab_objects, cfg.train_ab_refs_per_object,
                                          cfg.train_ab_queries_per_object, size, cfg.train_ab_context, cfg.seed)
    names = sorted(refs)
    batcher = _Batcher(names, refs, queries, AugmentConfig(), size, "own")
    rng = np.random.default_rng(cfg.seed)
    n_data = cfg.train_ab_data_repeats + 1
    order = _order_stream(rng, len(batcher), (n_steps + n_data) * b)

    def make(i: int) -> tuple:
        imgs, q_obj, q_rot, r_obj, r_rot = batcher.make(order[i * b:(i + 1) * b], rng)
        return images_to_tensor(imgs), q_obj, q_rot, r_obj, r_rot

    batches = [make(i) for i in range(n_steps)]  # the SAME batches for every A and B block
    return batcher, order, rng, batches


def _ab_data_side(cfg: BenchConfig, batcher, order: np.ndarray, rng: np.random.Generator) -> tuple[dict, dict]:
    """(data, parts): what ``train()`` does per step before ``train_step`` (batch assembly and augmentation,
    then to tensor), timed by :func:`timing.measure`.

    ``data`` is measure's dict (seconds per step); ``parts`` holds per-call seconds,
    ``{"make_s": [...], "to_tensor_s": [...]}``, the warm-up call first.
    """
    from helpers.net.model import images_to_tensor

    b, n_steps = cfg.train_ab_batch, cfg.train_ab_steps
    n_data = cfg.train_ab_data_repeats + 1
    calls = [0]
    parts: dict[str, list] = {"make_s": [], "to_tensor_s": []}

    def data_step(_):
        i = n_steps + calls[0] % n_data  # (a re-run contended repeat reuses picks)
        calls[0] += 1
        with Probe() as p1:
            imgs, *_labels = batcher.make(order[i * b:(i + 1) * b], rng)
        with Probe() as p2:
            images_to_tensor(imgs)
        parts["make_s"].append(p1.wall)
        parts["to_tensor_s"].append(p2.wall)

    wait_quiet()
    data = measure(data_step, cfg.train_ab_data_repeats, 1)
    return data, parts


def _ab_block(model, init: dict, step, batches: list[tuple], seed: int, variant: str) -> tuple[Probe, list[float]]:
    """(probe, losses): one block of ``len(batches)`` training steps of ``variant`` ("A" or "B")
    from the weights ``init`` with a fresh Adam; ``probe.wall`` is the block's seconds."""
    import torch

    model.load_state_dict(init)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    torch.manual_seed(seed)  # dropout draws
    with _Variant(variant):
        with Probe() as p:
            losses = [step(model, opt, *bt) for bt in batches]
    return p, losses


def _ab_interleaved_runs(cfg: BenchConfig, model, init: dict, step, batches: list[tuple]) -> tuple[dict, int, float]:
    """(runs, n_retried, threshold): ``train_ab_repeats`` timed (probe, losses) blocks per variant.

    ``runs`` maps "A" and "B" to their blocks in run order, after
    ``train_ab_warmup`` untimed A, B pairs; ``n_retried`` counts pairs re-run
    because other processes used at least ``threshold`` (a fraction of all CPUs).
    """
    def block(variant: str) -> tuple[Probe, list[float]]:
        return _ab_block(model, init, step, batches, cfg.seed, variant)

    for _ in range(cfg.train_ab_warmup):
        block("A")
        block("B")
    runs: dict[str, list] = {"A": [], "B": []}
    n_retried = 0
    threshold = gate().threshold
    for _ in range(cfg.train_ab_repeats):
        wait_quiet()
        pair = {v: block(v) for v in ("A", "B")}
        for _ in range(cfg.retry_contended):  # re-run a pair that other processes disturbed
            if all(p.others is None or p.others < threshold for p, _ in pair.values()):
                break
            n_retried += 1
            wait_quiet()
            pair = {v: block(v) for v in ("A", "B")}
        for v in ("A", "B"):
            runs[v].append(pair[v])
    return runs, n_retried, threshold


def _ab_summary(blocks: list[tuple[Probe, list[float]]], n_steps: int, n_img: int, threshold: float) -> dict:
    """One variant's block seconds (all, median), seconds per step, images/s, contention and first-block losses."""
    walls = [p.wall for p, _ in blocks]
    known = [p.others for p, _ in blocks if p.others is not None]
    med = statistics.median(walls)
    return {"block_s_all": walls, "block_s_median": med, "s_per_step_median": med / n_steps,
            "images_per_s": n_img / med, "others_cpu_fraction": statistics.median(known) if known else None,
            "contended_blocks": sum(1 for o in known if o >= threshold),
            "losses": blocks[0][1], "loss_after_n_steps": blocks[0][1][-1]}


def _max_diff(xs: list[list[float]], ys: list[list[float]]) -> float:
    """The largest |x - y| over paired loss lists."""
    return max(abs(x - y) for lx, ly in zip(xs, ys) for x, y in zip(lx, ly))


def _ab_preprocess(cfg: BenchConfig, model, x, compute_s: float) -> dict:
    """The changed function alone: ``model.preprocess`` of one batch ``x`` (3B, 3, S, S), A vs B interleaved.

    Returns seconds per call (medians and all), A's over B's, the largest
    output difference, and B's share of ``compute_s`` (B's seconds per training step).
    """
    import torch

    pp: dict[str, list] = {"A": [], "B": []}
    outs = {}
    with torch.no_grad():
        for _ in range(max(3, 2 * cfg.train_ab_repeats)):
            for v in ("A", "B"):
                with _Variant(v):
                    outs[v] = model.preprocess(x)
                    with Probe() as p:
                        for _ in range(cfg.train_ab_preprocess_calls):
                            model.preprocess(x)
                pp[v].append(p.wall / cfg.train_ab_preprocess_calls)
    pp_a, pp_b = statistics.median(pp["A"]), statistics.median(pp["B"])
    return {"batch": list(x.shape), "calls_per_timing": cfg.train_ab_preprocess_calls,
            "A_s_median": pp_a, "B_s_median": pp_b, "speedup_A_over_B": pp_a / pp_b,
            "A_s_all": pp["A"], "B_s_all": pp["B"],
            "max_abs_diff": float((outs["A"] - outs["B"]).abs().max()),
            "share_of_B_step": pp_b / compute_s}


def _ab_breakdown(cfg: BenchConfig, data: dict, parts: dict, compute_s: float) -> dict:
    """Data vs compute seconds per training step (``data`` and ``parts`` from :func:`_ab_data_side`)."""
    data_s = data["median_s"]
    return {
        "data_s_per_step": data_s, "make_s_median": statistics.median(parts["make_s"][1:]),
        "to_tensor_s_median": statistics.median(parts["to_tensor_s"][1:]),  # [1:]: not the warm-up
        "compute_s_per_step": compute_s, "data_fraction": data_s / (data_s + compute_s),
        "data": data,
        "synthetic_set": {"objects": cfg.train_ab_objects, "refs_per_object": cfg.train_ab_refs_per_object,
                          "queries_per_object": cfg.train_ab_queries_per_object,
                          "query_side": int(round(cfg.train_ab_size * cfg.train_ab_context)), "masks": True,
                          "augment": "AugmentConfig() defaults", "random_ref": "own"},
        "note": "data = helpers.training.batches._Batcher.make (query views with context, augmentation incl. in-plane "
                "re-crop from the mask, nearest-rotation positives, random references) + images_to_tensor, "
                "as train() does before each step; compute = B's train_step median over the A/B blocks; "
                "train() runs them one after the other, so a step costs about their sum"}


def _ab_code(r: int) -> tuple[str, str]:
    """(A's, B's) description of the box filter each variant runs, for a window of ``r`` pixels."""
    return (f"git {AB_BASE_COMMIT}: preprocess box filter = one {r}x{r} "
            "F.avg_pool2d(padded, window, stride=1) for mu and one for the mean of squares "
            "(helpers.net.model._box_mean monkeypatched for the A blocks, restored after)",
            "working tree: helpers.net.model._box_mean, separable 1 x r then r x 1 stride-1 average pools "
            "(measured_sources has the hashes)")


def bench_train_ab(cfg: BenchConfig) -> dict:
    """Training step A (git 1c2d2ee) vs B (today) at ``train_ab_size``, and data vs compute per step.

    A and B run in this process on the same batches (built once by
    ``helpers.training.batches._Batcher`` from a synthetic set, as ``train()`` builds them)
    from the same initial weights and seed, in interleaved blocks A, B, A, B, ...
    of ``train_ab_steps`` steps each (fresh Adam per block), so drift of the
    machine's speed hits both alike. The losses after N steps must agree to
    float rounding (the two box filters differ by ~1e-7 relative).
    """
    import copy

    size, b, n_steps = cfg.train_ab_size, cfg.train_ab_batch, cfg.train_ab_steps
    step, which = _train_step_fn()
    batcher, order, rng, batches = _ab_batches(cfg)
    data, parts = _ab_data_side(cfg, batcher, order, rng)

    model = _model(size, cfg.seed).train()
    init = copy.deepcopy(model.state_dict())
    runs, n_retried, threshold = _ab_interleaved_runs(cfg, model, init, step, batches)
    n_img = 3 * b * n_steps
    out_a, out_b = _ab_summary(runs["A"], n_steps, n_img, threshold), _ab_summary(runs["B"], n_steps, n_img, threshold)
    all_losses = {v: [ls for _, ls in runs[v]] for v in runs}
    if not all(math.isfinite(x) for v in all_losses.values() for ls in v for x in ls):
        raise RuntimeError(f"bench_train_ab: non-finite loss {all_losses}")
    out_a["code"], out_b["code"] = _ab_code(model.cfg.norm_window)

    compute_s = out_b["s_per_step_median"]
    preprocess = _ab_preprocess(cfg, model, batches[0][0], compute_s)
    pair_ratios = [pa.wall / pb.wall for (pa, _), (pb, _) in zip(runs["A"], runs["B"])]  # = B images/s / A's
    data_s = data["median_s"]
    res = {
        "image_size": size, "queries_per_step": b, "images_per_step": 3 * b, "steps_per_block": n_steps,
        "repeats": cfg.train_ab_repeats, "warmup_blocks_per_variant": cfg.train_ab_warmup,
        "retried_pairs": n_retried, "order": "A, B, A, B, ... (each pair re-run if contended)",
        "step_fn": which, "A": out_a, "B": out_b,
        "ratio_images_per_s_B_over_A": out_b["images_per_s"] / out_a["images_per_s"],
        "ratio_B_over_A_per_pair": pair_ratios, "ratio_B_over_A_pair_median": statistics.median(pair_ratios),
        "loss_max_abs_diff_A_vs_B": _max_diff(all_losses["A"], all_losses["B"]),
        "loss_max_abs_diff_A_repeats": _max_diff(all_losses["A"], all_losses["A"][:1] * len(all_losses["A"])),
        "loss_max_abs_diff_B_repeats": _max_diff(all_losses["B"], all_losses["B"][:1] * len(all_losses["B"])),
        "preprocess": preprocess,
        "breakdown": _ab_breakdown(cfg, data, parts, compute_s),
        "note": "same process, same initial weights (state_dict copy), same seed, same batches for every block; "
                "B is the working tree, which may hold uncommitted changes besides the box filter (e.g. an input "
                "range check in encode); those run in both A and B, so the ratio isolates the box filter"}
    log(f"train_ab {size}px: A {out_a['images_per_s']:.1f}, B {out_b['images_per_s']:.1f} images/s "
        f"(B/A {res['ratio_images_per_s_B_over_A']:.3f}), loss diff {res['loss_max_abs_diff_A_vs_B']:.1e}, "
        f"data {data_s * 1e3:.0f} ms vs compute {compute_s * 1e3:.0f} ms per step")
    return res
