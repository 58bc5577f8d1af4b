"""What is rendered: :class:`RenderConfig`, :class:`QueryStyle`, :class:`DataConfig` (the LineMOD-like
benchmark) and :class:`TlessConfig` (the T-LESS-like set)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._checks import _choice, _ints


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
class ExtraConfig:
    """Extra training objects (issue #44, screen e; :mod:`helpers.data.extra_objects`): fewer views per object than
    a benchmark object gets, so that a thousand of them stay affordable to render.

    Attributes:
        n: extra training objects, the first ``n`` of the extras' training order (0: none).
        n_references: references per extra object: the pool its positives come from (Haar-uniform, the
            benchmark's reference seed).
        n_train_queries: real-like training queries per extra object (with context, as the benchmark's), and as
            many clean views for the curriculum.
    """

    n: int = 0
    n_references: int = 256
    n_train_queries: int = 32

    def __post_init__(self) -> None:
        _ints(self, ("n",), lo=0)
        _ints(self, ("n_references", "n_train_queries"))


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
