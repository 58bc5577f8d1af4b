"""Training: query augmentation (:class:`AugmentConfig`) and the optimisation (:class:`TrainConfig`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

from ..device import resolve_device
from ..precision import PRECISIONS, resolve_precision
from ._checks import _bools, _choice, _from_dict, _ints
from .model import ModelConfig


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
#: TrainConfig fields added after checkpoints, zoo entries and run folders were written, with the default those
#: were trained with: a record without the field means this value, and a run at it keeps its earlier folder key.
LATER_DEFAULTS = {"symmetry_aware": False}


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
        symmetry_aware: use the objects' declared symmetries (``ObjectViews.symmetries`` of the
            references, from the manifest) in training: each query's positive is its nearest reference
            under the symmetry group, and the loss weights use the symmetric geodesic, so a view that is
            indistinguishable from the query is no longer pushed away as a negative. False: the plain
            geodesic, as the authors' code (run folders of earlier runs keep their keys).
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
    symmetry_aware: bool = False
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
        _bools(self, ("weighted_loss", "symmetry_aware", "occlusion", "progress"))
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
