"""Retrieval (:class:`SearchConfig`) and the HOG baseline (:class:`HogConfig`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from ._checks import _bools, _choice, _ints

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
        query_batch: fast: queries whose anchor stage is scored in one batched call; greedy: queries
            that share each tile of ``group`` references (same answers, less memory traffic); each
            query's seconds then hold its share of the batch. c2f runs one query at a time.
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
#: Sixteen queries share each tile of 128 references: the same answers as one query at a time, 2.6x faster for
#: "avg" fusion models (their scoring converts each tile to float32, cheaply while it sits in the cache) and
#: neutral for the learned fusion's kernel (benchmarks/results/greedy_tiles.json).
GREEDY = SearchConfig(method="greedy", group=128, query_batch=16)

#: The paper's fast-retrieval budget as ratios: 1,024 anchors of 10,000 references per object, and 256
#: references scored per refinement step out of 1,024 anchors.
PAPER_ANCHOR_RATIO = 1024 / 10000
#: The paper's references per object and fast search's anchors among them.
PAPER_N_REFS, PAPER_K_AC = 10000, 1024
PAPER_FPS_RATIO = 256 / 1024


def paper_ratio_search(n_refs: int, k_ac: int = 0, fps_k: int = 0, method: str = "fast", **kw) -> SearchConfig:
    """A :class:`SearchConfig` whose ``k_ac`` / ``fps_k`` default (0) to the paper's ratios for ``n_refs``
    references per object: k_ac = round(n_refs x 0.1024), fps_k = round(k_ac / 4), each at least 1.
    A positive ``k_ac`` or ``fps_k`` is taken as given (a named variant)."""
    if not isinstance(n_refs, int) or n_refs < 1:
        raise ValueError(f"paper_ratio_search: n_refs must be a positive int, got {n_refs!r}")
    k = k_ac if k_ac > 0 else max(1, round(n_refs * PAPER_ANCHOR_RATIO))
    f = fps_k if fps_k > 0 else max(1, round(k * PAPER_FPS_RATIO))
    return SearchConfig(method=method, k_ac=k, fps_k=f, **kw)


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
