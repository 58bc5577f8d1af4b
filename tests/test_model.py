"""Network shapes, normalisation, scoring consistency and fusion stability."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from helpers.core.configs import ModelConfig, level_shapes
from helpers.core.device import resolve_device
from helpers.net.model import OrientationNet, count_parameters, images_to_tensor, preprocess


def _model(**kw) -> OrientationNet:
    torch.manual_seed(0)
    return OrientationNet(ModelConfig(**kw)).eval()


def _feats(model: OrientationNet, n: int, seed: int = 0) -> torch.Tensor:
    """Random unit-norm features shaped like the model's output (fast: no encoder)."""
    g = torch.Generator().manual_seed(seed)
    f = torch.randn(n, model.cfg.channels, model.feature_length, generator=g)
    return F.normalize(f, dim=1)


# ------------------------------------------------------------------------ config

@pytest.mark.parametrize("kw, field", [
    ({"image_size": 100}, "image_size"), ({"image_size": 48}, "image_size"),
    ({"fusion": "max"}, "fusion"), ({"scales": ()}, "scales"), ({"scales": (32, 8)}, "scales"),
    ({"scales": "local"}, "scales"), ({"scales": (16, 16)}, "scales"), ({"norm_window": 1}, "norm_window"),
    ({"channels": 0}, "channels"), ({"dropout": 1.0}, "dropout"), ({"local_norm": "yes"}, "local_norm"),
])
def test_config_rejects_bad_values(kw, field):
    with pytest.raises(ValueError, match=field):
        ModelConfig(**kw)


def test_config_roundtrip_and_canonical_order():
    cfg = ModelConfig(image_size=64, scales=[13, 32], norm_window=32, fusion="softmax")
    assert cfg.scales == (32, 13)
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    assert ModelConfig.from_dict(ModelConfig(scales="global").to_dict()).scales == "global"
    with pytest.raises(ValueError, match="unknown"):
        ModelConfig.from_dict({"bogus": 1})


def test_resolve_device():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type in ("cpu", "cuda")
    with pytest.raises(ValueError):
        resolve_device("tpu9")


# -------------------------------------------------------------------- preprocess

def test_local_norm_statistics_and_clamp():
    torch.manual_seed(0)
    x = torch.rand(2, 3, 64, 64)
    y = preprocess(x, local_norm=True, window=17)
    assert y.shape == (2, 1, 64, 64)
    assert abs(float(y.mean())) < 0.05
    assert 0.85 < float(y.std()) < 1.1
    # One bright pixel on black: (1 - 1/289) / (std + eps) ~ 14 before the clamp.
    spike = torch.zeros(1, 3, 64, 64)
    spike[..., 30, 30] = 1.0
    z = preprocess(spike, window=17)
    assert float(z.max()) == pytest.approx(6.0)
    assert float(z.abs().max()) <= 6.0
    # Flat images (rendered background) map to zero, not noise.
    assert float(preprocess(torch.full((1, 3, 64, 64), 0.3)).abs().max()) < 1e-4


@pytest.mark.parametrize("window", [16, 17, 32])
def test_local_norm_window_sizes_keep_shape(window):
    y = preprocess(torch.rand(1, 3, 64, 64), window=window)
    assert y.shape == (1, 1, 64, 64) and torch.isfinite(y).all()


def test_global_standardisation_without_local_norm():
    y = preprocess(torch.rand(3, 3, 64, 64), local_norm=False)
    assert torch.allclose(y.mean(dim=(1, 2, 3)), torch.zeros(3), atol=1e-5)
    assert torch.allclose(y.std(dim=(1, 2, 3)), torch.ones(3), atol=0.05)


def test_images_to_tensor():
    arr = np.zeros((2, 8, 8, 3), np.uint8)
    arr[0, 1, 2] = (255, 0, 51)
    t = images_to_tensor(arr)
    assert t.shape == (2, 3, 8, 8) and t.dtype == torch.float32
    assert torch.allclose(t[0, :, 1, 2], torch.tensor([1.0, 0.0, 0.2]))


# ------------------------------------------------------------------------ shapes

@pytest.mark.parametrize("size", [128, 64])
def test_encode_shapes_and_unit_norm(size):
    model = _model(image_size=size)
    s4, s8 = size // 4, size // 8
    assert model.scale_shapes == {32: (s4, s4), 16: (s8, s8), 13: (s8 - 3, s8 - 3)}
    assert model.scale_shapes == level_shapes(size)
    with torch.inference_mode():
        f = model.encode(torch.rand(2, 3, size, size))
    L = s4 * s4 + s8 * s8 + (s8 - 3) ** 2
    assert f.shape == (2, 128, L) and f.dtype == torch.float32
    if size == 128:
        assert L == 1449
    assert torch.allclose(f.norm(dim=1), torch.ones(2, L), atol=1e-5)
    sl = model.scale_slices
    assert [sl[k].stop - sl[k].start for k in (32, 16, 13)] == [s4 * s4, s8 * s8, (s8 - 3) ** 2]
    with pytest.raises(ValueError, match="images"):
        model.encode(torch.rand(1, 3, size + 16, size + 16))


def test_encode_size_96():
    model = _model(image_size=96, scales=(16, 13))
    with torch.inference_mode():
        f = model.encode(torch.rand(1, 3, 96, 96))
    assert f.shape == (1, 128, 12 * 12 + 9 * 9)


def test_only_needed_decoder_parts():
    full = count_parameters(_model(image_size=64))["encoder_decoder"]
    m13 = _model(image_size=64, scales=(13,))
    assert not hasattr(m13.decoder, "up13") and not hasattr(m13.decoder, "merge32")
    assert count_parameters(m13)["encoder_decoder"] < full
    m16 = _model(image_size=64, scales=(16,))
    assert hasattr(m16.decoder, "up13") and not hasattr(m16.decoder, "merge32")


def test_parameter_counts():
    counts = count_parameters(_model())
    assert abs(counts["encoder_decoder"] - 1.9e6) / 1.9e6 < 0.10
    assert abs(counts["fusion_head"] - 50e3) / 50e3 < 0.10
    assert count_parameters(_model(fusion="avg"))["fusion_head"] == 0
    assert count_parameters(_model(scales="global"))["fusion_head"] == 0


# ----------------------------------------------------------------------- scoring

VARIANTS = [("adaptive", (32, 16, 13)), ("sigmoid", (32, 16, 13)), ("softmax", (32, 16, 13)),
            ("avg", (32, 16, 13)), ("adaptive", (32,)), ("adaptive", (16,)), ("adaptive", (13,)),
            ("softmax", (16, 13)), ("avg", (32, 13)), ("adaptive", "global")]


@pytest.mark.parametrize("fusion, scales", VARIANTS)
def test_score_variants_consistent(fusion, scales):
    model = _model(image_size=64, fusion=fusion, scales=scales)
    with torch.inference_mode():
        f = model.encode(torch.rand(5, 3, 64, 64))
        q, r = f[:2], f[2:]
        s = model.score(q, r)
        assert s.shape == (2, 3) and torch.isfinite(s).all()
        assert float(s.abs().max()) <= 1.0 + 1e-6
        for i in range(2):
            pairs = model.score_pairs(q[i:i + 1].expand(3, -1, -1), r)
            assert torch.allclose(s[i], pairs, atol=1e-5)
        maps = model.fusion_maps(q[:1].expand(3, -1, -1), r)
    assert set(maps) == set(model.scale_shapes)
    for lv, m in maps.items():
        assert m.shape == (3, *model.scale_shapes[lv])
        assert torch.allclose(m.sum(dim=(1, 2)), torch.ones(3), atol=1e-5)


def test_global_is_cosine_and_avg_is_mean_cosine():
    g = _model(image_size=64, scales="global")
    f = _feats(g, 4)
    assert f.shape[2] == 1
    assert torch.allclose(g.score(f[:2], f[2:]), f[:2, :, 0] @ f[2:, :, 0].T, atol=1e-6)
    a = _model(image_size=64, fusion="avg")
    f = _feats(a, 3)
    cos = (f[0] * f[1]).sum(0)  # (L,) local cosines
    want = np.mean([float(cos[sl].mean()) for sl in a.scale_slices.values()])
    assert float(a.score(f[:1], f[1:2])) == pytest.approx(want, abs=1e-6)
    assert float(a.score(f[:1], f[:1])) == pytest.approx(1.0, abs=1e-5)


@pytest.mark.parametrize("fusion, nq", [("adaptive", 1), ("adaptive", 3), ("sigmoid", 1), ("avg", 2),
                                         ("global", 2)])
def test_chunked_equals_unchunked_and_float16_refs(fusion, nq):
    """One query takes the product-block path, several the bilinear-logit path: both must agree."""
    kw = {"scales": "global"} if fusion == "global" else {"fusion": fusion}
    model = _model(image_size=64, **kw)
    q, r = _feats(model, nq, seed=1), _feats(model, 37, seed=2)
    with torch.inference_mode():
        full = model.score(q, r, chunk=1024)
        if fusion != "avg" and fusion != "global":
            for i in range(nq):
                assert torch.allclose(model.score(q[i:i + 1], r), full[i:i + 1], atol=1e-6)
        for chunk in (1, 5, 16):
            assert torch.allclose(model.score(q, r, chunk=chunk), full, atol=1e-6)
        half = model.score(q, r.half(), chunk=8)
    assert half.dtype == torch.float32
    assert torch.allclose(half, full, atol=5e-3)
    assert model.score(q, r[:0]).shape == (nq, 0)


def test_score_checks_feature_shapes():
    model = _model(image_size=64)
    with pytest.raises(ValueError, match="expected features"):
        model.score(torch.zeros(1, 128, 10), torch.zeros(1, 128, 10))
    with pytest.raises(ValueError, match="chunk"):
        model.score(_feats(model, 1), _feats(model, 1), chunk=0)


@pytest.mark.parametrize("fusion", ["adaptive", "sigmoid", "softmax"])
def test_fusion_weights_finite_for_extreme_logits(fusion):
    model = _model(image_size=64, fusion=fusion)
    q, r = _feats(model, 2, seed=3), _feats(model, 2, seed=4)
    for lin in model.fusion.logit.values():
        k = lin.weight.shape[0]
        with torch.no_grad():
            # Constant extreme logits (bias) ...
            lin.weight.zero_()
            lin.bias.copy_(torch.tensor([-1e4, 1e4][:k]))
    for attempt in range(2):
        with torch.no_grad():
            maps = model.fusion_maps(q, r)
            s = model.score(q, r)
        assert torch.isfinite(s).all()
        for m in maps.values():
            assert torch.isfinite(m).all()
            assert torch.allclose(m.sum(dim=(1, 2)), torch.ones(2), atol=1e-5)
        # ... then logits of +-1e4 varying over locations.
        for lin in model.fusion.logit.values():
            with torch.no_grad():
                lin.weight.fill_(1e6)
                lin.bias.zero_()


@pytest.mark.parametrize("nq", [1, 3])
def test_score_gradient_matches_pairs(nq):
    """The checkpointed many-to-many paths give the same gradients as the direct pair path."""
    model = _model(image_size=64)
    q0, r0 = _feats(model, nq, 5), _feats(model, nq, 6)
    grads = []
    for fn in (lambda q, r: model.score(q, r).diagonal().sum(), lambda q, r: model.score_pairs(q, r).sum()):
        model.zero_grad()
        q, r = q0.clone().requires_grad_(), r0.clone().requires_grad_()
        fn(q, r).backward()
        w = model.fusion.logit["32"].weight.grad.clone()
        grads.append((q.grad, r.grad, w))
    for a, b in zip(*grads):
        assert torch.allclose(a, b, atol=1e-6)


def test_encode_is_differentiable_and_dropout_only_in_train():
    model = _model(image_size=64)
    x = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        assert torch.equal(model.encode(x), model.encode(x))  # eval: deterministic
    model.train()
    f = model.encode(x)
    model.score(f[:1], f[1:]).sum().backward()
    assert model.encoder.stem.weight.grad is not None
    assert model.fusion.mlp[0].weight.grad is not None


# ------------------------------------------------------------- fused CPU kernel

def _kernel_or_skip():
    from helpers.net import fusion_kernel

    if fusion_kernel.get() is None:
        pytest.skip(f"fusion kernel unavailable: {fusion_kernel.status()['reason']}")


@pytest.mark.parametrize("fusion, scales", [("adaptive", (32, 16, 13)), ("sigmoid", (32, 16, 13)),
                                            ("softmax", (16, 13)), ("adaptive", (13,)), ("sigmoid", (32,))])
@pytest.mark.parametrize("nq", [1, 3])
def test_kernel_matches_eager(fusion, scales, nq):
    """The fused kernel computes the eager fusion's scores (float16 and float32 references, any chunking)."""
    _kernel_or_skip()
    model = _model(image_size=64, fusion=fusion, scales=scales)
    with torch.no_grad():  # non-trivial logit weights, so the fusion weights are far from uniform
        for lin in model.fusion.logit.values():
            lin.weight.normal_(0.0, 3.0)
    q, r = _feats(model, nq, seed=7), _feats(model, 29, seed=8)
    with torch.inference_mode():
        for refs in (r, r.half()):
            model.fusion_backend = "eager"
            want = model.score(q, refs, chunk=8)
            model.fusion_backend = "kernel"
            for chunk in (1, 8, 1024):
                got = model.score(q, refs, chunk=chunk)
                assert got.shape == want.shape
                assert torch.allclose(got, want, atol=1e-6), float((got - want).abs().max())


def test_kernel_results_do_not_depend_on_threads():
    _kernel_or_skip()
    model = _model(image_size=64)
    model.fusion_backend = "kernel"
    q, r = _feats(model, 2, seed=9), _feats(model, 50, seed=10).half()
    n = torch.get_num_threads()
    try:
        with torch.inference_mode():
            torch.set_num_threads(1)
            one = model.score(q, r)
            torch.set_num_threads(2)
            two = model.score(q, r)
    finally:
        torch.set_num_threads(n)
    assert torch.equal(one, two)


def test_kernel_not_used_with_autograd_and_can_be_disabled(monkeypatch):
    from helpers.net import fusion_kernel

    model = _model(image_size=64)
    q, r = _feats(model, 1, seed=11), _feats(model, 3, seed=12)
    # With gradients the eager (differentiable) path runs, whatever the backend setting.
    model.fusion_backend = "kernel"
    assert model._kernel(q, r) is None
    s = model.score(q.requires_grad_(), r)
    assert s.requires_grad
    monkeypatch.setenv("HELPERS_FUSION_KERNEL", "0")
    assert fusion_kernel.get() is None
    assert "disabled" in fusion_kernel.status()["reason"]
    model.fusion_backend = "auto"
    with torch.inference_mode():
        assert torch.isfinite(model.score(q.detach(), r)).all()  # eager fallback
        model.fusion_backend = "kernel"
        with pytest.raises(RuntimeError, match="kernel is unavailable"):
            model.score(q.detach(), r)


@pytest.mark.parametrize("fusion, scales", [("adaptive", (32, 16, 13)), ("softmax", (16, 13)),
                                            ("avg", (32, 16, 13)), ("adaptive", "global")])
@pytest.mark.parametrize("backend", ["eager", "kernel"])
def test_score_rows_equals_scoring_the_gathered_rows(fusion, scales, backend):
    """score(q, r, rows=idx) == score(q, r[idx]) in idx order (repeats allowed), any chunk, float16 too."""
    if backend == "kernel":
        _kernel_or_skip()
    model = _model(image_size=64, fusion=fusion, scales=scales)
    model.fusion_backend = backend
    q, r = _feats(model, 2, seed=21), _feats(model, 40, seed=22)
    idx = torch.tensor([7, 3, 39, 3, 0, 12, 25])
    with torch.inference_mode():
        for refs in (r, r.half()):
            want = model.score(q, refs[idx])
            for chunk in (1, 3, 1024):
                got = model.score(q, refs, chunk=chunk, rows=idx)
                assert got.shape == (2, len(idx))
                assert torch.allclose(got, want, atol=1e-6), float((got - want).abs().max())
            assert model.score(q, refs, rows=torch.zeros(0, dtype=torch.long)).shape == (2, 0)
        with pytest.raises(ValueError, match="rows"):
            model.score(q, r, rows=torch.tensor([0, 40]))
        with pytest.raises(ValueError, match="rows"):
            model.score(q, r, rows=torch.tensor([-1]))


def test_kernel_all_levels_equals_one_level_at_a_time():
    """fuse_levels (all levels, rows read in place) == fuse level by level on the gathered rows."""
    from helpers.net import fusion_kernel

    _kernel_or_skip()
    kernel = fusion_kernel.get()
    model = _model(image_size=64, fusion="adaptive", scales=(32, 16, 13))
    with torch.no_grad():
        for lin in model.fusion.logit.values():
            lin.weight.normal_(0.0, 3.0)
    q, r = _feats(model, 1, seed=23)[0], _feats(model, 30, seed=24).half()
    rows = torch.tensor([29, 0, 5, 5, 17])
    levels = list(model.scale_slices.items())
    w = torch.stack([model._fusion_params(lv)[0].detach() for lv, _ in levels]).contiguous()
    b = torch.stack([model._fusion_params(lv)[1].detach() for lv, _ in levels]).contiguous()
    offs, widths = [sl.start for _, sl in levels], [sl.stop - sl.start for _, sl in levels]
    got = kernel.fuse_levels(q, r, rows, offs, widths, w, b, fusion_kernel.MODES["adaptive"])
    gathered = r[rows].contiguous()
    want = torch.cat([kernel.fuse(q[:, sl].contiguous(), gathered, sl.start, sl.stop - sl.start, w[i], b[i], 0)
                      for i, (_, sl) in enumerate(levels)], dim=1)
    assert got.shape == (len(rows), len(levels) * model.cfg.channels)
    assert torch.allclose(got, want, atol=1e-6)
    with pytest.raises(RuntimeError, match="out of range"):
        kernel.fuse_levels(q, r, torch.tensor([30]), offs, widths, w, b, 0)
