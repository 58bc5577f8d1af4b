"""Every typed configuration of the study, in one place, validated on construction.

Notebooks build these from their parameters (:func:`helpers.study.parameters.configs_from`); every
step below takes them, never the parameter dict. All are plain dataclasses that serialise with
``to_dict``/``asdict`` (checkpoints, run folders, presets).

* :class:`RenderConfig`, :class:`QueryStyle` (+ the named styles): how views are rendered and cropped.
* :class:`DataConfig`: sizes of the rendered benchmark; :class:`ExtraConfig`: extra training objects.
* :class:`ModelConfig` (+ level geometry): the network's architecture switches.
* :class:`AugmentConfig`, :class:`TrainConfig`: query augmentation and training.
* :class:`SearchConfig` (+ :func:`paper_ratio_search`, the paper's budget ratios): retrieval;
  :class:`HogConfig`: the HOG baseline.
* :class:`TlessConfig`: sizes of the T-LESS-like set.
"""

from .data import QUERY_STYLES, SCENES, DataConfig, ExtraConfig, QueryStyle, RenderConfig, TlessConfig
from .model import FUSIONS, LEVELS, ModelConfig, level_shapes, parse_scales
from .search import (GREEDY, PAPER_ANCHOR_RATIO, PAPER_FPS_RATIO, PAPER_K_AC, PAPER_N_REFS, SCHEDULES, SEARCH_METHODS, HogConfig, SearchConfig,
                     paper_ratio_search)
from .train import LATER_DEFAULTS, LR_SCHEDULES, RANDOM_REF, SELECT_ON, AugmentConfig, TrainConfig

__all__ = ["QUERY_STYLES", "SCENES", "DataConfig", "ExtraConfig", "QueryStyle", "RenderConfig", "TlessConfig",
           "FUSIONS", "LEVELS", "ModelConfig", "level_shapes", "parse_scales",
           "GREEDY", "PAPER_ANCHOR_RATIO", "PAPER_FPS_RATIO", "SCHEDULES", "SEARCH_METHODS", "HogConfig",
           "SearchConfig", "paper_ratio_search", "LATER_DEFAULTS", "PAPER_N_REFS", "PAPER_K_AC",
           "LR_SCHEDULES", "RANDOM_REF", "SELECT_ON", "AugmentConfig", "TrainConfig"]
