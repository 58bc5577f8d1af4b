"""Augmentation, training steps, deterministic resume, validation and checkpoints."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch

import helpers.training.train as train_mod
from helpers.core.configs import AugmentConfig, ModelConfig, TrainConfig
from helpers.core.rotations import geodesic_deg, haar_uniform, inplane_rotate_label
from helpers.core.views import ObjectViews
from helpers.net.model import OrientationNet, images_to_tensor
from helpers.training.augment import augment_batch, augment_image
from helpers.training.losses import pair_weights, weighted_info_nce
from helpers.training.train import load_model, train, train_step
from helpers.training.validation import plot_history, selection_metric, validate

SIZE = 64


def make_views(name: str, n: int, seed: int, obj: int = 0, background: bool = False) -> ObjectViews:
    """Simple drawn 'renders': an asymmetric 3D stick figure projected with each rotation."""
    rng = np.random.default_rng(seed)
    rots = haar_uniform(n, rng).astype(np.float32)
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 0.6, 0], [0, 0, 0.3], [0.5, 0.5, 0]], np.float64) - 0.2
    pts[:, obj % 3] *= 1.5  # objects differ in shape
    colours = [(255, 60, 60), (60, 255, 60), (60, 60, 255), (255, 255, 0)]
    imgs = np.zeros((n, SIZE, SIZE, 3), np.uint8)
    for i in range(n):
        if background:
            imgs[i] = rng.integers(0, 80, (SIZE, SIZE, 3), dtype=np.uint8)
        p = (pts @ rots[i].T.astype(np.float64))[:, :2] * SIZE * 0.35 + SIZE / 2
        for k in range(1, len(p)):
            cv2.line(imgs[i], tuple(int(v) for v in p[0]), tuple(int(v) for v in p[k]), colours[k - 1], 3)
    return ObjectViews(name, imgs, rots, kind="query" if background else "reference")


def tiny_data():
    names = ["aa", "bb"]
    refs = {n: make_views(n, 24, 10 + i, i) for i, n in enumerate(names)}
    queries = {n: make_views(n, 6, 20 + i, i, background=True) for i, n in enumerate(names)}
    val_refs = {n: refs[n].subset(np.arange(0, 24, 3)) for n in names}
    val_queries = {n: make_views(n, 3, 30 + i, i, background=True) for i, n in enumerate(names)}
    return refs, queries, val_refs, val_queries


def tiny_cfg(**kw) -> TrainConfig:
    base = dict(epochs=3, steps_per_epoch=2, batch_size=2, lr=1e-3, lr_milestones=(2,), seed=3,
                device="cpu", progress=False, num_threads=1, model=ModelConfig(image_size=SIZE, channels=32))
    base.update(kw)
    return TrainConfig(**base)


# ---------------------------------------------------------------------- augment

def test_augment_is_deterministic_and_updates_label():
    img = make_views("x", 1, 0, background=True).images[0]
    R = haar_uniform(1, 1)[0]
    cfg = AugmentConfig(occlusion=True, occlusion_p=1.0, blur_p=1.0, inplane_p=1.0)
    a1, r1 = augment_image(img, R, np.random.default_rng(5), cfg)
    a2, r2 = augment_image(img, R, np.random.default_rng(5), cfg)
    assert a1.dtype == np.uint8 and a1.shape == img.shape
    assert np.array_equal(a1, a2) and np.array_equal(r1, r2)
    assert not np.array_equal(a1, img)
    # The label moved by an in-plane rotation only: R' = Rz R with |angle| <= inplane_deg.
    delta = r1 @ R.T
    assert np.allclose(delta[2], [0, 0, 1], atol=1e-9) and geodesic_deg(r1, R) <= cfg.inplane_max + 1e-6
    # Same draw with only the in-plane switch: the label equals inplane_rotate_label at that angle.
    only = AugmentConfig(hsv=False, noise=False, blur=False, inplane_p=1.0)
    _, r3 = augment_image(img, R, np.random.default_rng(5), only)
    angle = np.degrees(np.arctan2(delta[0, 1], delta[0, 0]))  # delta = rot_z(-angle): [0,1] = sin(angle)
    assert np.allclose(r3, inplane_rotate_label(R, angle), atol=1e-9)
    off, roff = augment_image(img, R, np.random.default_rng(5), AugmentConfig(enabled=False))
    assert np.array_equal(off, img) and np.array_equal(roff, R)
    imgs, rots = augment_batch(np.stack([img, img]), np.stack([R, R]), np.random.default_rng(0), cfg)
    assert imgs.shape == (2, SIZE, SIZE, 3) and rots.shape == (2, 3, 3)
    with pytest.raises(ValueError, match="blur_p"):
        AugmentConfig(blur_p=2.0)


def test_inplane_recrop_rotates_the_whole_view_without_mirroring_or_cutting():
    """Authors' in-plane augmentation: rotate the whole stored view on an enlarged canvas,
    re-take the tight box from the rotated mask. New area is exactly zero (nothing mirrored),
    the object is never cut, and the output is the crop size."""
    from helpers.training.augment import box_crop, centre_crop, rotate_inplane

    C, S = 48, 32
    img = np.full((C, C, 3), 200, np.uint8)  # bright "surroundings": a mirrored border would copy them
    mask = np.zeros((C, C), bool)
    mask[14:34, 18:30] = True  # an upright 20 x 12 object
    img[mask] = (255, 0, 0)
    for angle in (0.0, 17.0, -45.0, 60.0, 90.0):
        rot, rmask = rotate_inplane(img, angle, mask)
        full = rotate_inplane(np.full_like(img, 255), angle)[0]
        # Pixels outside the rotated canvas are zero, never copies of the border.
        assert (rot[full.max(axis=2) == 0] == 0).all()
        assert rot.shape[0] >= C and rot.shape[1] >= C
        # Nothing cut: the rotated mask keeps the object's area.
        assert abs(rmask.sum() - mask.sum()) <= 0.1 * mask.sum()
        out = box_crop(rot, rmask, S)
        assert out.shape == (S, S, 3)
    # A quarter turn makes the tall object wide: its red pixels span the crop's width.
    rot, rmask = rotate_inplane(img, 90.0, mask)
    red = (box_crop(rot, rmask, S)[..., 0] > 200) & (box_crop(rot, rmask, S)[..., 1] < 60)
    ys, xs = np.nonzero(red)
    assert xs.max() - xs.min() > 1.4 * (ys.max() - ys.min())
    assert np.array_equal(centre_crop(img, S), img[8:40, 8:40])


def test_inplane_recrop_label_matches_a_render(manifest):
    """The augmented label is the rotation whose reference render looks like the augmented
    query: the silhouette of a query re-cropped after a 40 deg turn overlaps the reference
    rendered at the new label (IoU > 0.8), and not the one at the old label."""
    from helpers.core.configs import RenderConfig
    from helpers.data.meshes import load_object
    from helpers.data.render import render_reference

    obj = load_object("mug", manifest)
    rc = RenderConfig(size=48, render_size=72)
    R = haar_uniform(1, seed=4)[0]
    img, mask = render_reference(obj, R, rc)
    cfg = AugmentConfig(hsv=False, noise=False, blur=False, inplane_p=1.0, inplane_deg=1e6, inplane_max=40.0)
    out, R2 = augment_image(img, R, np.random.default_rng(1), cfg, mask=mask, size=48)
    assert abs(geodesic_deg(R2, R) - 40.0) < 1e-6  # N(0, 1e6 deg) clipped at 40
    _, m_new = render_reference(obj, R2, rc)
    q = out.max(axis=2) > 0
    iou = lambda a, b: (a & b).sum() / (a | b).sum()  # noqa: E731
    assert iou(q, m_new) > 0.8
    assert iou(q, mask) < iou(q, m_new)


# ------------------------------------------------------------------------ config

def test_train_config_validation_and_roundtrip():
    cfg = tiny_cfg(augment=AugmentConfig(hue_deg=5.0))
    again = TrainConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert again == cfg
    for kw, field in [({"epochs": 0}, "epochs"), ({"batch_size": 1.5}, "batch_size"), ({"lr": 0}, "lr"),
                      ({"lr_milestones": (5, 2)}, "lr_milestones"), ({"tau": -1}, "tau"),
                      ({"steps_per_epoch": 0}, "steps_per_epoch"), ({"model": 3}, "model")]:
        with pytest.raises(ValueError, match=field):
            tiny_cfg(**kw)


# ------------------------------------------------------------------------- train

def test_few_steps_reduce_loss_on_fixed_batch():
    torch.manual_seed(0)
    model = OrientationNet(ModelConfig(image_size=SIZE, channels=32, dropout=0.0))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    refs = make_views("a", 8, 1)
    q_rot = refs.rotations[:4].astype(np.float64)
    images = images_to_tensor(np.concatenate([refs.images[:4], refs.images[:4], refs.images[4:8]]))
    q_obj, r_obj = np.zeros(4, int), np.zeros(8, int)
    r_rot = np.concatenate([q_rot, refs.rotations[4:8]])
    losses = [train_step(model, opt, images, q_obj, q_rot, r_obj, r_rot) for _ in range(6)]
    assert losses[-1] < losses[0]
    # train_step reports exactly the loss of the batch before its update.
    with torch.no_grad():
        f = model.encode(images)
        s = model.score(f[:4], f[4:])
        now = weighted_info_nce(s, torch.arange(4), pair_weights(q_obj, q_rot, r_obj, r_rot))
    assert float(now) < losses[0]


def _weights(path):
    return torch.load(path, weights_only=True)["model"]


def test_resume_after_interruption_equals_uninterrupted(tmp_path, monkeypatch):
    data = tiny_data()
    cfg = tiny_cfg()
    full = train(cfg, *data, tmp_path / "full")
    assert [h["epoch"] for h in full.history] == [1, 2, 3]
    assert full.history[2]["lr"] == pytest.approx(1e-4)  # milestone after epoch 2

    # Interrupt in the middle of epoch 3 (step 5 of 6): last.pt holds epoch 2.
    calls = {"n": 0}
    real_step = train_mod.train_step

    def flaky(*a, **k):
        calls["n"] += 1
        if calls["n"] == 6:
            raise KeyboardInterrupt
        return real_step(*a, **k)

    monkeypatch.setattr(train_mod, "train_step", flaky)
    with pytest.raises(KeyboardInterrupt):
        train(cfg, *data, tmp_path / "cut")
    monkeypatch.setattr(train_mod, "train_step", real_step)
    assert torch.load(tmp_path / "cut" / "last.pt", weights_only=True)["epoch"] == 2

    resumed = train(cfg, *data, tmp_path / "cut")
    assert [h["epoch"] for h in resumed.history] == [1, 2, 3]
    a, b = _weights(full.last_path), _weights(resumed.last_path)
    assert all(torch.equal(a[k], b[k]) for k in a)
    for h1, h2 in zip(full.history, resumed.history):
        assert h1["train_loss"] == h2["train_loss"] and h1["val"] == h2["val"] and h1["lr"] == h2["lr"]
    ck = torch.load(resumed.last_path, weights_only=True)
    assert ck["global_step"] == 6 and ck["epoch"] == 3

    # Nothing left to do: a second resume returns the stored history untouched.
    again = train(cfg, *data, tmp_path / "cut")
    assert len(again.history) == 3 and np.isnan(again.train_images_per_s)
    # A resume with a different trajectory-relevant setting is refused.
    with pytest.raises(ValueError, match="lr"):
        train(replace(cfg, lr=5e-4, epochs=4), *data, tmp_path / "cut")


def test_outputs_best_checkpoint_and_load(tmp_path):
    data = tiny_data()
    cfg = tiny_cfg(epochs=2, steps_per_epoch=None, val_every=1, weighted_loss=False, occlusion=True)
    res = train(cfg, *data, tmp_path)
    # steps_per_epoch=None: one pass over 12 queries with batch 2.
    assert res.history[-1]["global_step"] == 12
    hist = json.loads((tmp_path / "history.json").read_text())
    assert len(hist["history"]) == 2 and hist["best_epoch"] in (1, 2)
    assert (tmp_path / "history.png").stat().st_size > 0
    assert res.best_path.exists() and res.train_images_per_s > 0
    for h in res.history:
        assert set(h["val"]) == {"class_acc", "rot_acc", "median_err_deg"}
        assert 0.0 < h["cpu_share"] < 2.0  # the epoch's CPU per wall second per thread (zoo speed rule)
    model, ck = load_model(res.best_path, device="cpu")
    assert not model.training and model.cfg == cfg.model
    assert ck["epoch"] == hist["best_epoch"]
    # Selected on the mean of class and rotation accuracy (default), later epoch on ties.
    scores = [(h["val"]["class_acc"] + h["val"]["rot_acc"]) / 2 for h in res.history]
    assert hist["best_epoch"] == max(i + 1 for i, v in enumerate(scores) if v == max(scores))
    with pytest.raises(ValueError, match="select_on"):
        tiny_cfg(select_on="loss")


def test_selection_metric():
    v = {"class_acc": 0.5, "rot_acc": 0.1}
    assert selection_metric(v, "mean_acc") == pytest.approx(0.3)
    assert selection_metric(v, "rot_acc") == pytest.approx(0.1)


def test_validate_perfect_when_queries_are_references():
    torch.manual_seed(0)
    model = OrientationNet(ModelConfig(image_size=SIZE, fusion="avg", channels=32))
    refs = {n: make_views(n, 6, 40 + i, i) for i, n in enumerate(["aa", "bb"])}
    out = validate(model, refs, refs, device="cpu", batch_size=4)
    assert out["class_acc"] == 1.0 and out["rot_acc"] == 1.0
    assert out["median_err_deg"] == pytest.approx(0.0, abs=0.01)  # float32 rotations
    assert set(out["per_object"]) == {"aa", "bb"}


def test_train_rejects_unseen_validation_objects(tmp_path):
    refs, queries, val_refs, val_queries = tiny_data()
    extra = {"zz": make_views("zz", 2, 99)}
    with pytest.raises(ValueError, match="seen"):
        train(tiny_cfg(), refs, queries, {**val_refs, **extra}, {**val_queries, **extra}, tmp_path)
    with pytest.raises(ValueError, match="model expects"):
        train(tiny_cfg(model=ModelConfig(image_size=128)), refs, queries, val_refs, val_queries, tmp_path)


def test_plot_history_without_validation(tmp_path):
    path = plot_history([{"epoch": 1, "train_loss": 2.0, "val": None},
                         {"epoch": 2, "train_loss": 1.5, "val": None}], tmp_path / "h.png")
    assert path.stat().st_size > 0
