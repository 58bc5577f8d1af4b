"""Every typed configuration of the study, in one place, validated on construction.

Notebooks build these from their parameters (:func:`helpers.study.parameters.configs_from`); every
step below takes them, never the parameter dict. All are plain dataclasses that serialise with
``to_dict``/``asdict`` (checkpoints, run folders, presets).

* :class:`RenderConfig`, :class:`QueryStyle` (+ the named styles): how views are rendered and cropped.
* :class:`DataConfig`: sizes of the rendered benchmark.
* :class:`ModelConfig` (+ level geometry): the network's architecture switches.
* :class:`AugmentConfig`, :class:`TrainConfig`: query augmentation and training.
* :class:`SearchConfig`: retrieval; :class:`HogConfig`: the HOG baseline.
* :class:`TlessConfig`: sizes of the T-LESS-like set.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np

from .device import resolve_device
from .precision import PRECISIONS, resolve_precision


def _ints(obj: object, names: tuple[str, ...], lo: int = 1, none_ok: bool = False) -> None:
    """Each named field an int >= ``lo`` (or None when ``none_ok``), stored as a Python int."""
    for name in names:
        v = getattr(obj, name)
        if none_ok and v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{type(obj).__name__}.{name}: expected an int >= {lo}{' or None' if none_ok else ''}, "
                             f"got {v!r}")
        object.__setattr__(obj, name, int(v))  # (frozen dataclasses too)


def _bools(obj: object, names: tuple[str, ...]) -> None:
    for name in names:
        v = getattr(obj, name)
        if not isinstance(v, (bool, np.bool_)):
            raise ValueError(f"{type(obj).__name__}.{name}: expected a bool, got {v!r}")
        object.__setattr__(obj, name, bool(v))


def _choice(obj: object, name: str, options: tuple | dict) -> None:
    if getattr(obj, name) not in options:
        raise ValueError(f"{type(obj).__name__}.{name}: expected one of {tuple(options)}, got {getattr(obj, name)!r}")


def _from_dict(cls: type, d: dict) -> Any:
    """``cls(**d)``; unknown keys are an error naming the class."""
    unknown = set(d) - {f.name for f in fields(cls)}
    if unknown:
        raise ValueError(f"{cls.__name__}.from_dict: unknown keys {sorted(unknown)}")
    return cls(**d)

# ---------------------------------------------------------------- rendering

@dataclass(frozen=True)
class RenderConfig:
    """How views are rendered and cropped.

    Attributes:
        size: output crop side, pixels.
        render_size: side of the internal render, pixels (crops are taken from it).
        distance_diameters: camera-object distance in object diameters.
        fov_margin: extra field of view so the whole object always fits.
        crop_pad: crop side / silhouette bbox side (1.0 = tight).
    """

    size: int = 128
    render_size: int = 160
    distance_diameters: float = 2.5
    fov_margin: float = 1.08
    crop_pad: float = 1.0

    def __post_init__(self) -> None:
        for k in ("size", "render_size"):
            v = getattr(self, k)
            if not isinstance(v, int) or v < 16:
                raise ValueError(f"RenderConfig.{k} must be an int >= 16, got {v!r}")
        if self.distance_diameters <= 0.6:
            raise ValueError("RenderConfig.distance_diameters must exceed 0.6 (camera outside the object)")

    def intrinsics(self) -> np.ndarray:
        """3x3 K of the internal render (OpenCV, pixel centres at +0.5)."""
        half = math.asin(0.5 / self.distance_diameters) * self.fov_margin
        f = (self.render_size / 2) / math.tan(half)
        c = self.render_size / 2
        return np.array([[f, 0, c], [0, f, c], [0, 0, 1.0]])


@dataclass(frozen=True)
class QueryStyle:
    """How real-like query views are made (ranges sampled uniformly).

    Two scenes: ``"tabletop"`` (the default benchmark, LineMOD-like: the object
    resting on a photo-textured table among clutter, camera on the upper
    hemisphere, see :mod:`helpers.data.tabletop`) and ``"photo"`` (the ``hard``
    variant: any rotation of SO(3), crop rotated in-plane by up to
    ``inplane_deg``, pasted over a random patch of a full-frame photograph).
    :func:`query_style` gives the named presets.

    Attributes:
        scene: ``"tabletop"`` or ``"photo"``.
        light_intensity: directional light intensity range.
        ambient: ambient light range (0..1).
        light_cone_deg: photo scene: max angle of the light direction from the viewing axis.
        color_scale: per-channel multiplicative material colour jitter (+-).
        crop_shift: max crop-centre shift as a fraction of the crop side.
        crop_scale: max relative change of the crop side (+-).
        inplane_deg: photo scene: max in-plane rotation of the crop (+-), degrees.
        blur_sigma: max Gaussian blur sigma, pixels of the output.
        noise_sigma: max Gaussian noise sigma, grey levels (0..255).
        occlusion: probability a query gets an occluder.
        occlusion_fraction: (min, max) fraction of the silhouette to cover.
        elevation_deg: tabletop: camera elevation range above the table plane, degrees.
        roll_deg: tabletop: max camera roll (+-), degrees.
        n_clutter: tabletop: (min, max) clutter objects on the table.
        clutter_size: tabletop: clutter height range, object diameters.
        clutter_distance: tabletop: clutter distance from the object, object diameters.
        table_contrast: tabletop: contrast of the table photo about its mean colour
            (1 = the photograph as is).
        context: stored crop side / crop side: > 1 keeps a margin of real
            surroundings (training queries, so the in-plane augmentation can
            rotate the whole view and re-take the box without padding).
    """

    scene: str = "photo"
    light_intensity: tuple[float, float] = (1.5, 6.0)
    ambient: tuple[float, float] = (0.1, 0.5)
    light_cone_deg: float = 70.0
    color_scale: float = 0.25
    crop_shift: float = 0.08
    crop_scale: float = 0.12
    inplane_deg: float = 30.0
    blur_sigma: float = 1.2
    noise_sigma: float = 8.0
    occlusion: float = 0.0
    occlusion_fraction: tuple[float, float] = (0.1, 0.4)
    elevation_deg: tuple[float, float] = (15.0, 75.0)
    roll_deg: float = 10.0
    n_clutter: tuple[int, int] = (2, 5)
    clutter_size: tuple[float, float] = (0.3, 0.8)
    clutter_distance: tuple[float, float] = (0.6, 1.4)
    table_contrast: float = 1.0
    context: float = 1.0

    def __post_init__(self) -> None:
        if self.scene not in SCENES:
            raise ValueError(f"QueryStyle.scene must be one of {SCENES}, got {self.scene!r}")
        lo, hi = self.elevation_deg
        if not -90 <= lo <= hi <= 90:
            raise ValueError(f"QueryStyle.elevation_deg must be (lo, hi) within [-90, 90], got {self.elevation_deg!r}")
        if not 1.0 <= self.context <= 2.0:
            raise ValueError(f"QueryStyle.context must be in [1, 2], got {self.context!r}")
        if not 0 <= self.n_clutter[0] <= self.n_clutter[1]:
            raise ValueError(f"QueryStyle.n_clutter must be (min, max) with 0 <= min <= max, got {self.n_clutter!r}")


SCENES = ("tabletop", "photo")

#: Names of the query styles (their settings: :data:`helpers.data.render.STYLES`).
QUERY_STYLES = ("linemod", "hard")


# ---------------------------------------------------------------- benchmark data

@dataclass(frozen=True)
class DataConfig:
    """Sizes of the rendered benchmark.

    Attributes:
        image_size: crop side fed to the network, pixels.
        render_size: internal render side, pixels.
        n_references: references per object (shared Haar-uniform rotations).
        n_train_queries: real-like training queries per benchmark object.
        n_val_queries: held-out real-like views per benchmark object (model selection
            on SEEN objects only).
        n_test_queries: test queries per object (test background photos).
        occlusion_fraction: (min, max) silhouette fraction hidden in the occluded
            (LM-O-like) test set, where every query is occluded.
        query_style: ``"linemod"`` (default benchmark: tabletop scenes from the upper
            hemisphere, see :mod:`helpers.data.tabletop`) or ``"hard"`` (any rotation over
            full-frame photographs, in-plane rotated crops).
        train_context: stored side / crop side of TRAINING queries (> 1 keeps real
            surroundings for the in-plane augmentation, which rotates the whole view).
        seed: base seed.
        workers: rendering processes.
        cache_dir: cache root ("" = default).
    """

    image_size: int = 64
    render_size: int = 96
    n_references: int = 48
    n_train_queries: int = 16
    n_val_queries: int = 4
    n_test_queries: int = 4
    occlusion_fraction: tuple[float, float] = (0.2, 0.5)
    query_style: str = "linemod"
    train_context: float = 1.5
    seed: int = 0
    workers: int = 2
    cache_dir: str = ""

    def __post_init__(self) -> None:
        _choice(self, "query_style", QUERY_STYLES)
        if not 1.0 <= float(self.train_context) <= 2.0:
            raise ValueError(f"train_context: expected a crop-side multiple in [1, 2], got {self.train_context!r}")

    def render_config(self) -> RenderConfig:
        """The renderer's settings for these crop and render sides (pixels); the other defaults as set."""
        return RenderConfig(size=self.image_size, render_size=self.render_size)


@dataclass(frozen=True)
class TlessConfig:
    """Sizes of the T-LESS-like set.

    Attributes:
        image_size, render_size: crop and internal render sides, pixels (as the LineMOD-like benchmark's).
        n_references: references per part (Haar-uniform rotations shared by all parts).
        n_queries: test queries per part.
        min_visible: least visible share of a query part's silhouette.
        seed: rotations, scenes and sensor noise.
    """

    image_size: int = 64
    render_size: int = 96
    n_references: int = 512
    n_queries: int = 50
    min_visible: float = 0.5
    seed: int = 0

    def render_config(self) -> RenderConfig:
        """The renderer's settings for these crop and render sides (pixels); the other defaults as set."""
        return RenderConfig(size=self.image_size, render_size=self.render_size)


# ---------------------------------------------------------------- network

LEVELS = (32, 16, 13)
"""Decoder levels, named by their side length at a 128 px input, in feature order."""

FUSIONS = ("adaptive", "sigmoid", "softmax", "avg")


@dataclass
class ModelConfig:
    """Architecture switches (everything needed to rebuild the network).

    Attributes:
        image_size: input side S in px; multiple of 16, >= 64. Level maps are
            S/4 (level 32), S/8 (level 16) and S/8 - 3 (level 13).
        fusion: "adaptive" (softmax(g) x sigmoid(l), the full method),
            "sigmoid", "softmax", or "avg" (plain mean of local cosines, no
            learned head). Ignored when ``scales == "global"``.
        scales: non-empty subset of (32, 16, 13), or "global" (one descriptor
            per image: the level-13 map averaged over locations, cosine score).
        local_norm: locally normalise the grey input (else global per-image
            standardisation).
        norm_window: side r of the local-normalisation window in px (odd or
            even; authors' code 17, paper 32).
        channels: feature channels per location.
        dropout: dropout probability in the level heads.
    """

    image_size: int = 128
    fusion: str = "adaptive"
    scales: tuple | str = (32, 16, 13)
    local_norm: bool = True
    norm_window: int = 17
    channels: int = 128
    dropout: float = 0.1

    def __post_init__(self) -> None:
        if isinstance(self.image_size, bool) or not isinstance(self.image_size, (int, np.integer)) \
                or self.image_size < 64 or self.image_size % 16:
            raise ValueError(f"ModelConfig.image_size: expected an int multiple of 16 and >= 64, "
                             f"got {self.image_size!r}")
        self.image_size = int(self.image_size)
        _choice(self, "fusion", FUSIONS)
        if isinstance(self.scales, str):
            if self.scales != "global":
                raise ValueError(f"ModelConfig.scales: expected a subset of {LEVELS} or 'global', "
                                 f"got {self.scales!r}")
        else:
            try:
                given = [int(s) for s in self.scales]
            except (TypeError, ValueError):
                raise ValueError(f"ModelConfig.scales: expected a subset of {LEVELS} or 'global', "
                                 f"got {self.scales!r}") from None
            if not given or len(set(given)) != len(given) or not set(given) <= set(LEVELS):
                raise ValueError(f"ModelConfig.scales: expected a non-empty subset of {LEVELS} without "
                                 f"repeats, or 'global', got {self.scales!r}")
            # Canonical order so that feature layout never depends on how the user listed them.
            self.scales = tuple(s for s in LEVELS if s in given)
        _bools(self, ("local_norm",))
        _ints(self, ("norm_window",), lo=2)
        if self.norm_window > self.image_size // 2:
            raise ValueError(f"ModelConfig.norm_window: expected an int in [2, image_size/2="
                             f"{self.image_size // 2}], got {self.norm_window!r}")
        _ints(self, ("channels",))
        if not 0.0 <= float(self.dropout) < 1.0:
            raise ValueError(f"ModelConfig.dropout: expected a float in [0, 1), got {self.dropout!r}")
        self.dropout = float(self.dropout)

    @property
    def is_global(self) -> bool:
        return self.scales == "global"

    @property
    def levels(self) -> tuple[int, ...]:
        """Levels whose maps are returned (``(13,)`` for "global")."""
        return (13,) if self.is_global else tuple(self.scales)

    def to_dict(self) -> dict:
        """Plain JSON/checkpoint-safe dict (tuples become lists)."""
        d = asdict(self)
        if not isinstance(d["scales"], str):
            d["scales"] = list(d["scales"])
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        d = dict(d)
        if "scales" in d and not isinstance(d["scales"], str):
            d["scales"] = tuple(d["scales"])
        return _from_dict(cls, d)


def parse_scales(scales: str) -> tuple[int, ...] | str:
    """Notebook form of the scales -> ModelConfig form: "global" or "32,16,13" -> (32, 16, 13)."""
    if scales == "global":
        return "global"
    try:
        out = tuple(int(s) for s in str(scales).split(","))
    except ValueError:
        out = ()
    if not out or not set(out) <= set(LEVELS):
        raise ValueError(f"scales: expected 'global' or a comma list of 32/16/13, got {scales!r}")
    return out


def level_shapes(image_size: int) -> dict[int, tuple[int, int]]:
    """Map side lengths (h, w) of each level for a square input of ``image_size`` px."""
    s4, s8 = image_size // 4, image_size // 8
    return {32: (s4, s4), 16: (s8, s8), 13: (s8 - 3, s8 - 3)}


# ---------------------------------------------------------------- training

@dataclass
class AugmentConfig:
    """Switches and magnitudes (angles in degrees, intensities in 0-255 grey levels).

    Attributes:
        enabled: master switch.
        hsv: hue shift uniform in +-hue_deg, saturation and value scaled by
            factors uniform in [1 - sat, 1 + sat] and [1 - val, 1 + val].
        noise: additive Gaussian noise with sigma uniform in [0, noise_std].
        blur: with probability blur_p, Gaussian blur with sigma uniform in
            [0.1, blur_sigma] px.
        inplane: with probability inplane_p, rotate the whole view by an
            angle ~ N(0, inplane_deg) clipped to +-inplane_max (positive =
            counter-clockwise on screen, as cv2.getRotationMatrix2D) with the
            canvas enlarged, and re-take the tight box from the rotated mask
            (authors' code: p 0.5, 30 deg, clipped at 60); the rotation label
            is updated with :func:`helpers.core.rotations.inplane_rotate_label`.
        occlusion: with probability occlusion_p, paint one axis-aligned
            rectangle covering a fraction uniform in [occlusion_min,
            occlusion_max] of the image, aspect ratio log-uniform in [1/2, 2],
            filled with a random colour plus noise.
    """

    enabled: bool = True
    hsv: bool = True
    hue_deg: float = 10.0
    sat: float = 0.3
    val: float = 0.3
    noise: bool = True
    noise_std: float = 8.0
    blur: bool = True
    blur_p: float = 0.5
    blur_sigma: float = 1.5
    inplane: bool = True
    inplane_p: float = 0.5
    inplane_deg: float = 30.0
    inplane_max: float = 60.0
    occlusion: bool = False
    occlusion_p: float = 0.5
    occlusion_min: float = 0.05
    occlusion_max: float = 0.3

    def __post_init__(self) -> None:
        _bools(self, ("enabled", "hsv", "noise", "blur", "inplane", "occlusion"))
        for name in ("blur_p", "inplane_p", "occlusion_p", "sat", "val"):
            if not 0.0 <= float(getattr(self, name)) <= 1.0:
                raise ValueError(f"AugmentConfig.{name}: expected a value in [0, 1], got {getattr(self, name)!r}")
        for name in ("hue_deg", "noise_std", "inplane_deg", "inplane_max"):
            if float(getattr(self, name)) < 0:
                raise ValueError(f"AugmentConfig.{name}: expected >= 0, got {getattr(self, name)!r}")
        if not 0.1 <= float(self.blur_sigma):
            raise ValueError(f"AugmentConfig.blur_sigma: expected >= 0.1 px, got {self.blur_sigma!r}")
        if not 0.0 < self.occlusion_min <= self.occlusion_max < 1.0:
            raise ValueError(f"AugmentConfig.occlusion_min/max: expected 0 < min <= max < 1, got "
                             f"{self.occlusion_min!r}, {self.occlusion_max!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "AugmentConfig":
        return _from_dict(cls, d)


SELECT_ON = ("mean_acc", "rot_acc")
RANDOM_REF = ("own", "any")
LR_SCHEDULES = ("step", "cosine")


@dataclass
class TrainConfig:
    """Training hyper-parameters (epochs and milestones count epochs).

    Attributes:
        epochs: total epochs (a resumed run continues up to this number).
        steps_per_epoch: optimiser steps per epoch; None = one pass over the
            training queries, ceil(N / batch_size).
        batch_size: queries per step (each adds 2 references to encode).
        lr, lr_milestones, lr_gamma: Adam learning rate, divided by
            1/lr_gamma at each milestone epoch (``lr_schedule="step"``, the paper's).
        lr_schedule: ``"step"`` (milestones) or ``"cosine"`` (cosine decay to 0
            over all steps, milestones ignored).
        warmup_steps: linear learning-rate warm-up from lr/warmup_steps over this
            many optimiser steps (0: none), before either schedule.
        clean_steps: curriculum from clean to real-like queries: at optimiser step t
            each query is replaced, with probability max(0, 1 - t / clean_steps),
            by a clean render (reference style, object on black) of its object at
            another rotation (``clean_queries`` of :func:`train`); 0 = no curriculum.
        random_ref: where each query's extra random reference comes from:
            ``"own"`` (its own object, as the authors' code) or ``"any"``
            (a random training object).
        tau: infoNCE temperature.
        weighted_loss: geodesic weights (True) or plain infoNCE (False).
        seed: seeds torch (init, dropout) and the numpy Generator (sampling,
            augmentation).
        device: "auto", "cpu", "cuda", ... (see helpers.core.device).
        augment: query augmentation.
        occlusion: convenience switch that turns on ``augment.occlusion``
            (training for the occluded benchmark).
        val_every: validate every this many epochs (and at the last epoch).
        num_threads: torch CPU threads during training (None = leave as is).
        model: network configuration, embedded in checkpoints.
        progress: show tqdm bars.
        val_batch_size: images per forward pass during validation.
        precision: ``"auto"`` (bf16 autocast where the device has native bf16, else fp32;
            see :mod:`helpers.core.precision`), ``"fp32"`` or ``"bf16"``. :func:`train` resolves
            ``"auto"`` first, so checkpoints record the precision that was used.
        select_on: validation metric that picks ``best.pt``: ``"mean_acc"``
            (mean of class and rotation accuracy; steadier with few
            validation queries, where rotation accuracy alone moves by single
            queries) or ``"rot_acc"``. Ties go to the later epoch.
    """

    epochs: int = 200
    steps_per_epoch: int | None = None
    batch_size: int = 16
    lr: float = 1e-4
    lr_milestones: tuple = (50, 150)
    lr_gamma: float = 0.1
    lr_schedule: str = "step"
    warmup_steps: int = 0
    clean_steps: int = 0
    random_ref: str = "own"
    tau: float = 0.1
    weighted_loss: bool = True
    seed: int = 0
    device: str = "auto"
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    occlusion: bool = False
    val_every: int = 1
    num_threads: int | None = None
    model: ModelConfig = field(default_factory=ModelConfig)
    progress: bool = True
    val_batch_size: int = 32
    select_on: str = "mean_acc"
    precision: str = "auto"

    def __post_init__(self) -> None:
        _ints(self, ("epochs", "batch_size", "val_every", "val_batch_size"))
        _ints(self, ("steps_per_epoch", "num_threads"), none_ok=True)
        _ints(self, ("warmup_steps", "clean_steps", "seed"), lo=0)
        _bools(self, ("weighted_loss", "occlusion", "progress"))
        if not float(self.lr) > 0:
            raise ValueError(f"TrainConfig.lr: expected > 0, got {self.lr!r}")
        try:
            self.lr_milestones = tuple(int(m) for m in self.lr_milestones)
        except (TypeError, ValueError):
            raise ValueError(f"TrainConfig.lr_milestones: expected a sequence of ints, "
                             f"got {self.lr_milestones!r}") from None
        if list(self.lr_milestones) != sorted(set(self.lr_milestones)) or any(m < 1 for m in self.lr_milestones):
            raise ValueError(f"TrainConfig.lr_milestones: expected increasing positive epochs, "
                             f"got {self.lr_milestones!r}")
        if not 0 < float(self.lr_gamma) <= 1:
            raise ValueError(f"TrainConfig.lr_gamma: expected in (0, 1], got {self.lr_gamma!r}")
        if not float(self.tau) > 0:
            raise ValueError(f"TrainConfig.tau: expected > 0, got {self.tau!r}")
        for name, options in (("random_ref", RANDOM_REF), ("lr_schedule", LR_SCHEDULES), ("precision", PRECISIONS),
                              ("select_on", SELECT_ON)):
            _choice(self, name, options)
        if not isinstance(self.device, str):
            raise ValueError(f"TrainConfig.device: expected a string, got {self.device!r}")
        if isinstance(self.augment, dict):
            self.augment = AugmentConfig.from_dict(self.augment)
        if not isinstance(self.augment, AugmentConfig):
            raise ValueError(f"TrainConfig.augment: expected an AugmentConfig, got {type(self.augment).__name__}")
        if isinstance(self.model, dict):
            self.model = ModelConfig.from_dict(self.model)
        if not isinstance(self.model, ModelConfig):
            raise ValueError(f"TrainConfig.model: expected a ModelConfig, got {type(self.model).__name__}")

    def resolved(self) -> "TrainConfig":
        """This config with ``precision="auto"`` replaced by what it means on its device."""
        return replace(self, precision=resolve_precision(self.precision, resolve_device(self.device)))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["lr_milestones"] = list(self.lr_milestones)
        d["augment"] = self.augment.to_dict()
        d["model"] = self.model.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        return _from_dict(cls, d)


# ---------------------------------------------------------------- retrieval

SEARCH_METHODS = ("greedy", "fast", "c2f")
SCHEDULES = ("converge", "authors")


@dataclass(frozen=True)
class SearchConfig:
    """How a query is retrieved in a reference bank (:mod:`helpers.search.retrieval`).

    Attributes:
        method: ``"greedy"`` (every reference of every object), ``"fast"`` (the paper's
            Algorithm 1: FPS anchors pick the object, then refinement in shrinking
            neighbourhoods) or ``"c2f"`` (fast retrieval with our coarse-to-fine category
            stage, not the authors').
        k_ac: anchors per object (fast, c2f); at most the bank's references are used.
        fps_k: references scored per refinement step (farthest-point samples of the
            neighbourhood of the current best).
        schedule: neighbourhood sizes: ``"converge"`` (the paper's text: halve when the best
            stops moving) or ``"authors"`` (their code: 4096/2048/1024/512 scaled to R).
        top_anchors: the object is the one with the best mean of its ``top_anchors`` best
            anchor scores.
        max_moves_per_level: ``"converge"``: moves at one neighbourhood size before halving.
        coarse_k: c2f: anchors per object scored in the coarse round (>= k_ac: no coarse round).
        refine_objects: c2f: objects that score all ``k_ac`` anchors.
        halving: c2f: successive halving of the objects instead of one cut.
        group: references per scorer call.
        query_batch: fast: queries whose anchor stage is scored in one batched call (each
            query's seconds then hold its share of it); greedy and c2f run one query at a time.
    """

    method: str = "fast"
    k_ac: int = 1024
    fps_k: int = 256
    schedule: str = "converge"
    top_anchors: int = 3
    max_moves_per_level: int = 20
    coarse_k: int = 64
    refine_objects: int = 3
    halving: bool = False
    group: int = 1024
    query_batch: int = 1

    def __post_init__(self) -> None:
        _choice(self, "method", SEARCH_METHODS)
        _choice(self, "schedule", SCHEDULES)
        _ints(self, ("k_ac", "fps_k", "top_anchors", "max_moves_per_level", "coarse_k", "refine_objects", "group",
                     "query_batch"))
        _bools(self, ("halving",))

    def to_dict(self) -> dict:
        return asdict(self)


#: Exhaustive search (every reference of every object): what the HOG baseline and the ablations use.
GREEDY = SearchConfig(method="greedy")


# ---------------------------------------------------------------- baseline

@dataclass(frozen=True)
class HogConfig:
    """HOG parameters (Dalal-Triggs defaults).

    Attributes:
        orientations: unsigned gradient orientation bins.
        cell: cell side, pixels.
        block: block side, cells.
    """

    orientations: int = 9
    cell: int = 8
    block: int = 2
