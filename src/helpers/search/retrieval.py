"""Retrieve the category and rotation of a query from cached reference features.

Two searches over a :class:`ReferenceBank` (K objects x R references that
share one set of rotations):

* :func:`greedy_search` scores the query against every reference (K*R pairs).
* :func:`fast_search` is the method's Algorithm 1: score K*k_ac anchors to pick
  the category and a start, then refine in shrinking rotation neighbourhoods,
  scoring only fps_k farthest-point samples of each.

:func:`search_all` runs either over many queries, as a
:class:`helpers.core.configs.SearchConfig` says.

A *scorer* is any callable ``(query (1,C,L) float32 tensor, refs (M,C,L)
tensor) -> (M,) or (1, M) tensor`` of similarities (higher = more similar).
References reach it in the bank's dtype (float16 for a feature cache: the
model promotes them block by block, which is cheaper than a separate float32
copy), one chunk at a time, so the bank may be memory-mapped and much larger
than RAM. A scorer with the attribute ``batched = True`` (as
:func:`model_scorer` makes) also takes Q queries at once and returns (Q, M);
:func:`search_all` then scores the anchors of a batch of queries in one call,
which amortises reading the anchors and lets the model use its many-query path.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from ..core.configs import SearchConfig
from .bank import ReferenceBank
from .fps import farthest_point_sampling

Scorer = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]

#: Neighbourhood sizes of the authors' schedule, for R = 10,000 references.
AUTHORS_SIZES = (4096, 2048, 1024, 512)
AUTHORS_R = 10_000


@dataclass
class Prediction:
    """Result of one search.

    Attributes:
        obj_index: index of the predicted object in the bank.
        ref_index: index of the retrieved reference (into the shared rotations).
        score: its similarity.
        n_comparisons: query-reference scores computed (each pair counted once).
        R_est: (3, 3) float64 rotation of the retrieved reference (``R_m2c``).
        obj_name: name of the predicted object.
        seconds: wall seconds spent on this query (its share of a batched
            anchor stage included); NaN when not measured.
    """

    obj_index: int
    ref_index: int
    score: float
    n_comparisons: int
    R_est: np.ndarray
    obj_name: str = ""
    seconds: float = float("nan")


def model_scorer(model: Any, device: str | torch.device = "cpu", chunk: int = 1024) -> Scorer:
    """Scorer from an object with ``score(q (Q,C,L), r (R,C,L), chunk) -> (Q,R)``.

    Puts the model in eval mode (if it has ``eval``) since scores must be
    deterministic; runs under ``torch.inference_mode``; returns (Q, M) CPU
    scores. Marked ``batched`` (takes several queries at once) and, if
    ``model.score`` takes ``rows``, ``rows`` (``scorer(q, r, rows=idx)`` scores
    r[idx]; with a CPU model the fused kernel reads those rows of a
    memory-mapped bank in place).
    """
    if hasattr(model, "eval"):
        model.eval()

    def scorer(q: torch.Tensor, r: torch.Tensor, rows: torch.Tensor | None = None) -> torch.Tensor:
        with torch.inference_mode():
            if rows is not None:
                # r stays where it is (a whole bank): only the chosen rows move, chunk by chunk.
                return model.score(q.to(device), r, chunk=chunk, rows=rows).float().cpu()
            return model.score(q.to(device), r.to(device), chunk=chunk).float().cpu()

    scorer.batched = True  # type: ignore[attr-defined]
    # Duck-typed models whose score() has no ``rows`` get gathered references instead.
    scorer.rows = "rows" in inspect.signature(model.score).parameters  # type: ignore[attr-defined]
    return scorer


def _as_query(query_feat: Any) -> torch.Tensor:
    q = torch.as_tensor(np.asarray(query_feat) if not torch.is_tensor(query_feat) else query_feat)
    if q.ndim == 2:
        q = q[None]
    if q.ndim != 3 or q.shape[0] != 1:
        raise ValueError(f"query_feat: expected (C,L) or (1,C,L), got {tuple(q.shape)}")
    return q.float()


def _check_query(q: torch.Tensor, bank: ReferenceBank) -> None:
    if tuple(q.shape[1:]) != tuple(bank.feats[0].shape[1:]):
        raise ValueError(f"query_feat: shape (C,L)={tuple(q.shape[1:])} does not match the bank's "
                         f"{tuple(bank.feats[0].shape[1:])}")


def _run_scorer(scorer: Scorer, q: torch.Tensor, refs: torch.Tensor, rows: torch.Tensor | None = None) -> np.ndarray:
    s = scorer(q, refs) if rows is None else scorer(q, refs, rows=rows)
    s = s.detach().cpu().numpy() if torch.is_tensor(s) else np.asarray(s)
    s = s.reshape(-1).astype(np.float64)
    n = len(refs) if rows is None else len(rows)
    if len(s) != n:
        raise ValueError(f"scorer returned {len(s)} scores for {n} references")
    return s


def greedy_search(query_feat: Any, bank: ReferenceBank, scorer: Scorer, group: int = 1024) -> Prediction:
    """Score the query against all K*R references, in groups of ``group``; return the best.

    Ties go to the lowest (object, reference) index.
    """
    return greedy_search_batch([query_feat], bank, scorer, group)[0]


def greedy_search_batch(query_feats: Any, bank: ReferenceBank, scorer: Scorer, group: int = 1024) -> list[Prediction]:
    """:func:`greedy_search` of each of B queries (B, C, L), the queries sharing each reference tile (ties go to the
    lowest (object, reference) index).

    Each tile of ``group`` references is taken from the bank once and scored against every query in turn, one
    query per scorer call as :func:`greedy_search` makes them, so every score and answer is the same as one query
    at a time; what changes is memory traffic: a tile that fits in the CPU's cache is read from memory once per
    batch instead of once per query (a 64 px reference is 88 KB in float16, so 128 of them are 11 MB).
    """
    if group < 1:
        raise ValueError(f"greedy search: group must be >= 1, got {group}")
    qs = [_as_query(q) for q in query_feats]
    for q in qs:
        _check_query(q, bank)
    best = [(-np.inf, 0, 0)] * len(qs)
    for o in range(bank.n_objects):
        for s in range(0, bank.n_refs, group):
            refs = bank.chunk(o, s, s + group)
            for i, q in enumerate(qs):
                sc = _run_scorer(scorer, q, refs)
                j = int(np.argmax(sc))
                if sc[j] > best[i][0]:
                    best[i] = (float(sc[j]), o, s + j)
    return [Prediction(o, r, score, bank.n_objects * bank.n_refs, bank.rotations[r].copy(), bank.names[o])
            for score, o, r in best]


class _ScoreCache:
    """Scores of one query, each (object, reference) pair computed at most once.

    One (R,) float64 array per object, NaN = not scored yet (allocated on first use).
    """

    def __init__(self, q: torch.Tensor, bank: ReferenceBank, scorer: Scorer, group: int):
        self.q, self.bank, self.scorer, self.group = q, bank, scorer, group
        self.scores: list[np.ndarray | None] = [None] * bank.n_objects
        self.n_comparisons = 0

    def _row(self, obj: int) -> np.ndarray:
        if self.scores[obj] is None:
            self.scores[obj] = np.full(self.bank.n_refs, np.nan)
        return self.scores[obj]

    def put(self, obj: int, idx: np.ndarray, values: np.ndarray) -> None:
        """Record scores computed elsewhere (a batched anchor stage); counted as comparisons."""
        d = self._row(obj)
        new = np.isnan(d[idx])
        d[idx] = values
        self.n_comparisons += int(new.sum())

    def __call__(self, obj: int, idx: np.ndarray) -> np.ndarray:
        d = self._row(obj)
        new = np.unique(idx[np.isnan(d[idx])])
        src = self.bank.ref_source(obj) if getattr(self.scorer, "rows", False) else None
        for s in range(0, len(new), self.group):
            part = new[s:s + self.group]
            if src is not None:  # the scorer reads the rows in place: no gathered copy
                d[part] = _run_scorer(self.scorer, self.q, src, rows=torch.from_numpy(part))
            else:
                d[part] = _run_scorer(self.scorer, self.q, self.bank.ref_feats(obj, part))
        if np.isnan(d[new]).any():
            raise ValueError("scorer returned NaN scores")
        self.n_comparisons += len(new)
        return d[idx]


def authors_sizes(n_refs: int) -> list[int]:
    """Neighbourhood sizes of the authors' schedule for ``n_refs`` references.

    4096, 2048, 1024, 512 at R = 10,000. For smaller R they are scaled by
    R / 10,000 (so each neighbourhood covers the same fraction of SO(3)), and
    always clamped to [1, R].
    """
    scale = min(1.0, n_refs / AUTHORS_R)
    return [int(min(n_refs, max(1, round(s * scale)))) for s in AUTHORS_SIZES]


def fast_search(query_feat: Any, bank: ReferenceBank, scorer: Scorer, cfg: SearchConfig = SearchConfig(),
                anchor_scores: np.ndarray | None = None) -> Prediction:
    """Algorithm 1 of the method: anchors pick the category, then local refinement.

    1. :func:`_pick_category`: score the ``cfg.k_ac`` FPS anchors of every object; the
       category is the object with the best mean of its ``cfg.top_anchors`` best anchor
       scores; start at that object's best anchor.
    2. :func:`_refine_rotation`: within that object, sample, score and move to the best
       reference of shrinking neighbourhoods (``cfg.schedule``).

    Scores are cached per query, so a reference is never scored twice and
    ``n_comparisons`` counts distinct pairs. ``anchor_scores`` (K, A), if given, are this
    query's scores of ``bank.anchors(cfg.k_ac)`` computed elsewhere (see
    :func:`anchor_scores_batch`); they count as comparisons. ``cfg.method == "c2f"`` replaces
    step 1's scoring by our coarse-to-fine category stage (:func:`_coarse_to_fine_anchors`).
    """
    if cfg.method == "greedy":
        raise ValueError("fast_search: cfg.method is 'greedy'; use greedy_search or search_all")
    q = _as_query(query_feat)
    _check_query(q, bank)
    score = _ScoreCache(q, bank, scorer, cfg.group)
    obj, start, start_score = _pick_category(q, bank, scorer, cfg, score, anchor_scores)
    best, best_score = _refine_rotation(bank, score, cfg, obj, start, start_score)
    return Prediction(obj, best, best_score, score.n_comparisons, bank.rotations[best].copy(), bank.names[obj])


def _pick_category(q: torch.Tensor, bank: ReferenceBank, scorer: Scorer, cfg: SearchConfig, score: _ScoreCache,
                   anchor_scores: np.ndarray | None) -> tuple[int, int, float]:
    """Step 1: (object index, its best anchor's reference index, that anchor's score).

    Every anchor score is recorded in ``score``. With the coarse-to-fine stage, objects whose
    anchors were not all scored get -inf and are never chosen."""
    anchors = bank.anchors(cfg.k_ac)
    top = min(cfg.top_anchors, len(anchors))
    if anchor_scores is not None:
        anchor_scores = np.asarray(anchor_scores, dtype=np.float64)
        if anchor_scores.shape != (bank.n_objects, len(anchors)):
            raise ValueError(f"fast_search: anchor_scores must be (K, A)=({bank.n_objects}, {len(anchors)}), "
                             f"got {anchor_scores.shape}")
    elif cfg.method == "c2f" and cfg.coarse_k < len(anchors):
        anchor_scores = _coarse_to_fine_anchors(q, bank, scorer, cfg, top)
    else:
        feats = bank.anchor_feats(cfg.k_ac)
        anchor_scores = np.stack([_run_scorer(scorer, q, feats[o]) for o in range(bank.n_objects)])  # (K, A)
    # Only the coarse-to-fine stage leaves -inf (anchors it did not score); anything else non-finite is an error.
    if np.isnan(anchor_scores).any() or np.isposinf(anchor_scores).any() or \
            (cfg.method != "c2f" and np.isneginf(anchor_scores).any()):
        raise ValueError("fast_search: anchor_scores hold non-finite values")
    for o in range(bank.n_objects):
        seen = np.isfinite(anchor_scores[o])
        score.put(o, anchors[seen], anchor_scores[o, seen])
    complete = np.isfinite(anchor_scores).all(axis=1)
    best_top = -np.sort(-np.nan_to_num(anchor_scores, neginf=-1e300), axis=1)[:, :top].mean(axis=1)
    obj = int(np.argmax(np.where(complete, best_top, -np.inf)))
    j0 = int(np.argmax(anchor_scores[obj]))
    return obj, int(anchors[j0]), float(anchor_scores[obj, j0])


def _refine_rotation(bank: ReferenceBank, score: _ScoreCache, cfg: SearchConfig, obj: int, best: int,
                     best_score: float) -> tuple[int, float]:
    """Step 2: (reference index, score) after refinement within object ``obj``, always keeping
    the best reference seen.

    * ``"authors"`` (the published code): for k in :func:`authors_sizes` (4096, 2048, 1024,
      512 at R=10,000), take the k references nearest to the current best, pick ``fps_k`` of
      them by FPS starting from the current best (all of them if k <= fps_k), score, move to
      the best.
    * ``"converge"`` (the paper's text): neighbourhood sizes floor(R/2^j), j = 1, 2, ...; at
      each size, sample/score/move repeatedly until the best stops changing (at most
      ``max_moves_per_level`` moves), then halve. Once the neighbourhood has at most
      ``fps_k`` references, all of it is scored (again until the best stops moving) and the
      search stops.
    """
    def step(k: int) -> bool:
        """Sample the k-neighbourhood of the best, score, move; True if the best moved."""
        nonlocal best, best_score
        pool = bank.nearest_refs(best, k)
        cand = pool if len(pool) <= cfg.fps_k else farthest_point_sampling(bank.rotations, cfg.fps_k, start=0,
                                                                           candidates=pool)
        s = score(obj, cand)
        j = int(np.argmax(s))
        if s[j] > best_score:
            best, best_score = int(cand[j]), float(s[j])
            return True
        return False

    if cfg.schedule == "authors":
        for k in authors_sizes(bank.n_refs):
            step(k)
        return best, best_score
    j = 1
    while True:
        k = max(1, bank.n_refs >> j)
        for _ in range(cfg.max_moves_per_level):
            if not step(k):
                break
        if k <= cfg.fps_k:
            return best, best_score
        j += 1


def _coarse_to_fine_anchors(q: torch.Tensor, bank: ReferenceBank, scorer: Scorer, cfg: SearchConfig,
                            top: int) -> np.ndarray:
    """(K, A) anchor scores, -inf where not scored: our coarse-to-fine category stage, not the
    authors' procedure.

    Round 1 scores the first ``coarse_k`` anchors of every object (FPS is greedy, so they are
    the ``coarse_k``-point FPS set, spread over SO(3); one scorer call over
    :meth:`ReferenceBank.anchor_head_feats`). Each round then ranks the objects still in play
    by the mean of their ``top`` best scored anchors and keeps the ``refine_objects`` best
    (``halving=False``: K*k_ac anchor pairs become K*coarse_k + refine_objects*(k_ac -
    coarse_k)) or the better half, at least ``refine_objects`` (``halving=True``, successive
    halving: the survivors' scored anchors double each round; at K=13, k_ac=1024,
    coarse_k=64, refine_objects=1: 13x64 + 7x64 + 4x128 + 2x256 + 1x512 = 2,816 pairs
    instead of 13,312); once ``refine_objects`` remain they score all A, and the category
    is picked among them by the authors' rule.
    """
    k_ac, coarse_k, refine_objects, halving = cfg.k_ac, cfg.coarse_k, cfg.refine_objects, cfg.halving
    feats = bank.anchor_feats(k_ac)
    n_anchor = len(feats[0])
    out = np.full((bank.n_objects, n_anchor), -np.inf)
    out[:, :coarse_k] = _run_scorer(scorer, q, bank.anchor_head_feats(k_ac, coarse_k)).reshape(bank.n_objects,
                                                                                                coarse_k)
    alive, scored = np.arange(bank.n_objects), coarse_k
    while scored < n_anchor:
        t = min(top, scored)
        rank = -np.sort(-out[alive, :scored], axis=1)[:, :t].mean(axis=1)
        keep = max(refine_objects, -(-len(alive) // 2)) if halving else refine_objects
        alive = alive[np.argsort(-rank, kind="stable")[:keep]]
        nxt = min(n_anchor, 2 * scored) if halving and len(alive) > refine_objects else n_anchor
        for o in alive:
            out[o, scored:nxt] = _run_scorer(scorer, q, feats[o][scored:nxt])
        scored = nxt
    return out


def anchor_scores_batch(query_feats: torch.Tensor, bank: ReferenceBank, scorer: Scorer,
                        k_ac: int = 1024) -> np.ndarray:
    """(Q, K, A) scores of Q queries (Q, C, L) against every object's anchors.

    One scorer call per object with all Q queries, if the scorer is
    ``batched``; otherwise one call per query.
    """
    q = torch.as_tensor(query_feats).float()
    if q.ndim != 3:
        raise ValueError(f"anchor_scores_batch: query_feats must be (Q,C,L), got {tuple(q.shape)}")
    _check_query(q[:1], bank)
    feats = bank.anchor_feats(k_ac)
    out = np.empty((len(q), bank.n_objects, len(feats[0])), dtype=np.float64)
    for o, f in enumerate(feats):
        if getattr(scorer, "batched", False):
            s = scorer(q, f)
            s = (s.detach().cpu().numpy() if torch.is_tensor(s) else np.asarray(s)).astype(np.float64)
            if s.shape != (len(q), len(f)):
                raise ValueError(f"batched scorer returned shape {s.shape}, expected {(len(q), len(f))}")
            out[:, o] = s
        else:
            for i in range(len(q)):
                out[i, o] = _run_scorer(scorer, q[i:i + 1], f)
    return out


def search_all(query_feats: Any, bank: ReferenceBank, scorer: Scorer, cfg: SearchConfig,
               progress: bool = True) -> list[Prediction]:
    """Retrieve each of N queries (N, C, L) with ``cfg``: :func:`greedy_search` or :func:`fast_search`.

    For ``"fast"``, the anchor stage of ``cfg.query_batch`` queries at a time is one batched
    scoring pass (:func:`anchor_scores_batch`); each prediction's ``seconds`` is its
    refinement plus an equal share of its batch's anchor stage, so their mean is the
    throughput cost per query. For ``"greedy"``, ``cfg.query_batch`` queries share each
    reference tile (:func:`greedy_search_batch`: the same answers) and each gets an equal
    share of the batch's seconds. ``query_batch=1`` gives single-query latency; on 2 CPU cores
    batching did not pay (benchmarks/README.md), on a GPU it is the way to fill the device.
    ``"c2f"`` runs one query at a time (its category stage depends on each query's coarse scores).
    """
    if getattr(query_feats, "ndim", None) != 3:
        raise ValueError(f"search_all: query_feats must be (N,C,L), got shape {getattr(query_feats, 'shape', None)}")
    batch = cfg.query_batch if cfg.method in ("fast", "greedy") else 1
    preds: list[Prediction] = []
    bar = tqdm(total=len(query_feats), desc=f"{cfg.method} search", unit="query", disable=not progress)
    for s in range(0, len(query_feats), batch):
        part = query_feats[s:s + batch]
        if cfg.method == "greedy" and len(part) > 1:
            t0 = time.perf_counter()
            got = greedy_search_batch(part, bank, scorer, cfg.group)
            share = (time.perf_counter() - t0) / len(part)
            for p in got:
                p.seconds = share
            preds += got
            bar.update(len(part))
            continue
        share, pre = 0.0, [None] * len(part)
        if len(part) > 1:
            t0 = time.perf_counter()
            pre = list(anchor_scores_batch(_as_queries(part), bank, scorer, cfg.k_ac))
            share = (time.perf_counter() - t0) / len(part)
        for i in range(len(part)):
            t0 = time.perf_counter()
            p = greedy_search(part[i], bank, scorer, cfg.group) if cfg.method == "greedy" else \
                fast_search(part[i], bank, scorer, cfg, anchor_scores=pre[i])
            p.seconds = share + time.perf_counter() - t0
            preds.append(p)
            bar.update(1)
    bar.close()
    return preds


def _as_queries(query_feats: Any) -> torch.Tensor:
    q = query_feats if torch.is_tensor(query_feats) else torch.from_numpy(np.asarray(query_feats))
    return q.float()
