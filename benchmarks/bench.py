#!/usr/bin/env python
"""Speed, memory and fast-vs-greedy benchmark of the retrieval pipeline on this machine.

Run from the repository root::

    .venv/bin/python benchmarks/bench.py            # full run, ~10-15 min on 2 cores
    .venv/bin/python benchmarks/bench.py --quick    # ~3 min, smaller sizes

and read ``benchmarks/README.md`` for what every number means. Everything is
written to ONE JSON file (atomically). Every timing is the median over
``repeats`` runs taken after ``warmup`` untimed runs (``time.perf_counter``).

This file holds the section runner, the targets, the
summary and the command line; the sections live next to it, over one shared
measurement module:

* ``bench_config.py``: the sizes of a run (``BenchConfig``, ``FULL``, ``QUICK``), below every section;
* ``timing.py``: Probe, measure, background load and the quiet gate, memory
  sampling, logging, source hashes;
* ``bench_render.py``: rendering (``render``);
* ``bench_train.py``: training step, encoding, training A/B (``train``,
  ``encode``, ``train_ab``);
* ``bench_fusion.py``: GEMM, fusion kernel, FLOP counts (``gemm``, ``fusion``);
* ``bench_retrieval.py``: synthetic bank and retrieval, cache bytes
  (``retrieval_synthetic``, ``cache_bytes_13x10000``);
* ``bench_retrieval_real.py``: real-set agreement (``retrieval_real``);
* ``bench_precision.py``: bf16 against float32 training, speed and fidelity
  (``precision``; opt-in, run only when named in ``--sections``);
* ``bench_profile.py``: one training step phase by phase, and validation's share
  (``train_profile``; opt-in).

Only the standard library and numpy are imported at module level (here and in
those modules): rendering workers are *spawned*, and a spawned worker
re-imports this file as ``__mp_main__``, so heavy imports here would inflate
the measured worker start-up. Everything else is imported inside the functions.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

# The section modules are siblings of this file; it is also loaded by path (tests), so put its folder on the
# path either way.
_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)

import timing  # noqa: E402
from bench_fusion import _unit_features, bench_fusion, bench_gemm, fusion_flops_per_pair  # noqa: E402,F401
from bench_render import bench_render  # noqa: E402
from bench_retrieval import (  # noqa: E402,F401
    C2F_COARSE_K,
    C2F_REFINE_OBJECTS,
    PAPER_FPS_K,
    PAPER_K_AC,
    PAPER_OBJECTS,
    PAPER_REFS,
    _smooth_bases,
    _smooth_features,
    bench_retrieval_synthetic,
    cache_bytes,
    write_synthetic_bank,
)
from bench_retrieval_real import bench_real_agreement, scaled_c2f_params, scaled_fast_params  # noqa: E402,F401
from bench_config import FULL, QUICK, BenchConfig  # noqa: E402,F401
from bench_precision import bench_precision  # noqa: E402
from bench_profile import bench_train_profile  # noqa: E402
from bench_train import _model, bench_encode, bench_train, bench_train_ab, monotone_readout  # noqa: E402,F401
from timing import PeakSampler, Probe, background_load, log, measure, memory_snapshot, source_hashes  # noqa: E402,F401

# Names above that this file does not use are re-exported, so ``import bench`` offers every section's helpers.

#: Sections of a plain run, in order; OPT_IN ones run only when named (``--sections``).
DEFAULT_SECTIONS = ("render", "train", "train_ab", "encode", "fusion", "retrieval_synthetic", "retrieval_real")
OPT_IN_SECTIONS = ("precision", "train_profile")

REPO = Path(__file__).resolve().parents[1]
SCHEMA_VERSION = 1

# Targets (section 7 of the brief / the paper's claims, scaled to this machine).
TARGET_FAST_S_PER_QUERY = 0.5
TARGET_SPEEDUP = 150.0
TARGET_CACHE_BYTES = 12_000_000_000  # 12 GB (decimal)
# Coarse-to-fine fast search (coarse_k 64, refine_objects 3) over 13 x 10,000.
TARGET_C2F_S_PER_QUERY = 0.12
TARGET_C2F_SPEEDUP = 25.0

# =========================================================================== 7. targets

def _target(value: float, bound: float, at_most: bool, reason: str) -> dict:
    """One target entry: value, "<= bound" or ">= bound", met, and ``reason`` (None when met)."""
    met = value <= bound if at_most else value >= bound
    return {"value": value, "target": f"{'<=' if at_most else '>='} {bound}", "met": met,
            "reason": None if met else reason}


def evaluate_targets(res: dict) -> dict:
    """Targets of the brief and whether this run met them (value, target, met, reason)."""
    key = f"{PAPER_OBJECTS}x{PAPER_REFS}"
    bank = res.get("retrieval_synthetic", {}).get("banks", {}).get(key)
    out = {}
    if bank and bank.get("skipped"):  # a full run whose headline bank did not fit: an unmet target, not a gap
        out["bank_13x10000_measured"] = {"value": None, "target": "measured", "met": False,
                                         "reason": f"skipped: {bank.get('reason')}"}
    if bank and not bank.get("skipped"):
        fast = bank["fast"]
        comps = fast["comparisons_per_query_median"]
        out["fast_s_per_query_13x10000"] = _target(
            fast["s_per_query_median"], TARGET_FAST_S_PER_QUERY, True,
            f"the fast search scores {comps:.0f} pairs/query (13 x 1024 anchors alone are 13,312) at "
            f"{fast['pair_scores_per_s']:.0f} pair-scores/s on 2 CPU cores; {TARGET_FAST_S_PER_QUERY} s would "
            f"need ~{comps / TARGET_FAST_S_PER_QUERY:.0f} pair-scores/s")
        out["speedup_fast_vs_greedy"] = _target(
            bank["speedup_greedy_over_fast"], TARGET_SPEEDUP, False,
            f"bounded by the comparison ratio {bank['comparison_ratio_greedy_over_fast']:.1f} (130,000 pairs vs "
            f"{comps:.0f}): with k_ac=1024 anchors per object the fast search cannot be more than "
            f"130000/13312 = 9.8x cheaper in pair scores")
        fb = bank.get("fast_batched")
        if fb:
            out["fast_s_per_query_13x10000_batched"] = _target(
                fb["s_per_query_mean"], TARGET_FAST_S_PER_QUERY, True,
                f"throughput cost per query with the anchor stage of {fb['query_batch']} queries shared; "
                f"each query still scores ~{fb['comparisons_per_query_median']:.0f} pairs")
            out["speedup_fast_batched_vs_greedy"] = _target(
                bank["speedup_greedy_over_fast_batched"], TARGET_SPEEDUP, False,
                "greedy is single-query; the batched anchor pass is cheaper per pair than greedy's "
                "single-query pass, so this can exceed the comparison ratio, but not by the factor needed")
        c2f = bank.get("c2f")
        if c2f:
            comps = c2f["comparisons_per_query_median"]
            anchor_pairs = PAPER_OBJECTS * C2F_COARSE_K + C2F_REFINE_OBJECTS * (PAPER_K_AC - C2F_COARSE_K)
            out["c2f_s_per_query_13x10000"] = _target(
                c2f["s_per_query_median"], TARGET_C2F_S_PER_QUERY, True,
                f"c2f scores {comps:.0f} pairs/query at {c2f['pair_scores_per_s']:.0f} pair-scores/s; "
                f"{TARGET_C2F_S_PER_QUERY} s would need ~{comps / TARGET_C2F_S_PER_QUERY:.0f} pair-scores/s")
            out["speedup_c2f_vs_greedy_13x10000"] = _target(
                bank["speedup_greedy_over_c2f"], TARGET_C2F_SPEEDUP, False,
                f"bounded by the comparison ratio {bank['comparison_ratio_greedy_over_c2f']:.1f} "
                f"({PAPER_OBJECTS * PAPER_REFS:,} pairs vs {comps:.0f}); the c2f anchor stage alone is "
                f"{PAPER_OBJECTS} x {C2F_COARSE_K} + {C2F_REFINE_OBJECTS} x {PAPER_K_AC - C2F_COARSE_K} = "
                f"{anchor_pairs:,} pairs (at most {PAPER_OBJECTS * PAPER_REFS / anchor_pairs:.1f}x), the "
                f"rotation stage adds the rest")
        c2fh = bank.get("c2f_halving")
        if c2fh:
            out["c2f_halving_s_per_query_13x10000"] = _target(
                c2fh["s_per_query_median"], TARGET_C2F_S_PER_QUERY, True,
                f"c2f halving scores {c2fh['comparisons_per_query_median']:.0f} pairs/query at "
                f"{c2fh['pair_scores_per_s']:.0f} pair-scores/s")
            out["speedup_c2f_halving_vs_greedy_13x10000"] = _target(
                bank["speedup_greedy_over_c2f_halving"], TARGET_C2F_SPEEDUP, False,
                f"bounded by the comparison ratio {bank['comparison_ratio_greedy_over_c2f_halving']:.1f}")
    else:
        reason = (bank or {}).get("reason") or f"{key} not run in this mode ({res.get('mode')})"
        for k, t in (("fast_s_per_query_13x10000", f"<= {TARGET_FAST_S_PER_QUERY}"),
                     ("speedup_fast_vs_greedy", f">= {TARGET_SPEEDUP}"),
                     ("c2f_s_per_query_13x10000", f"<= {TARGET_C2F_S_PER_QUERY}"),
                     ("speedup_c2f_vs_greedy_13x10000", f">= {TARGET_C2F_SPEEDUP}"),
                     ("c2f_halving_s_per_query_13x10000", f"<= {TARGET_C2F_S_PER_QUERY}"),
                     ("speedup_c2f_halving_vs_greedy_13x10000", f">= {TARGET_C2F_SPEEDUP}")):
            out[k] = {"value": None, "target": t, "met": None, "reason": reason}
    for s, v in res["cache_bytes_13x10000"].items():
        out[f"cache_bytes_13x10000_{s}px"] = _target(
            v["bytes"], TARGET_CACHE_BYTES, True,
            f"L={v['L']} locations x 128 channels x 2 bytes = {v['per_reference_bytes']} bytes per reference")
    return out


# =========================================================================== driver

_MEMORY_NOTE = (
    "maxrss_bytes (= VmHWM) is ru_maxrss of this process: it includes file-backed pages of the "
    "memory-mapped reference files touched by the searches. section_peak_RssAnon / RssFile are sampled "
    "every 0.1 s: RssAnon is the process's own heap (model, buffers, float32 reference chunks), RssFile "
    "the mapped reference pages (reclaimable page cache). children_maxrss_bytes is NOT the render "
    "workers' own peak: on Linux a spawned child inherits the parent's high-water mark at fork/exec")


def _check_sections(sections: tuple[str, ...] | None) -> tuple[str, ...]:
    """The sections to run (``DEFAULT_SECTIONS`` when none are named); ValueError names any unknown one."""
    sections = sections or DEFAULT_SECTIONS
    unknown = sorted(set(sections) - set(DEFAULT_SECTIONS) - set(OPT_IN_SECTIONS))
    if unknown:
        raise ValueError(f"--sections: unknown {unknown}; expected a subset of "
                         f"{', '.join(DEFAULT_SECTIONS + OPT_IN_SECTIONS)}")
    return sections


def _run_header(cfg: BenchConfig, checkpoint: str | None) -> dict:
    """The result's opening fields: schema, mode, config, how timings are taken, the machine's load at the
    start, provenance, hashes of the measured sources and the fusion kernel's status; empty
    ``section_seconds`` and ``memory``."""
    from helpers.study.provenance import run_record

    res: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION, "mode": cfg.mode, "config": cfg.to_dict(),
        "timing": "medians over `repeats` timed runs after `warmup` untimed runs, time.perf_counter; "
                  "cpu_s_per_wall_s = own CPU seconds (all threads, reaped children) per wall second; "
                  "others_cpu_fraction = share of all CPUs used by OTHER processes during the timed run "
                  "(from /proc/stat); repeats with others_cpu_fraction >= quiet_threshold were re-run "
                  "up to retry_contended times",
        "torch_threads": cfg.threads, "loadavg_start": list(os.getloadavg()),
        "background_load_start": background_load(1.0), "section_seconds": {}, "memory": {}}
    res["provenance"] = run_record("bench", {**cfg.to_dict(), "checkpoint": checkpoint})
    res["measured_sources"] = source_hashes()
    # Build (or load) the fused fusion kernel before anything is timed, and say whether it is used.
    from helpers.net import fusion_kernel
    fusion_kernel.get()
    res["fusion_kernel"] = fusion_kernel.status()
    return res


def _run_sections(cfg: BenchConfig, res: dict, sections: tuple[str, ...], checkpoint: str | None,
                  tmp_root: str | None) -> PeakSampler:
    """Run the chosen sections in their fixed order into ``res`` (with each one's seconds and memory);
    returns the still-running peak-memory sampler, for the caller to stop."""
    sampler = PeakSampler().start()

    def section(name: str, fn: Callable[[], Any]) -> None:
        if name not in sections and not (name == "gemm" and "fusion" in sections):
            return
        log(f"section {name}")
        t = time.perf_counter()
        sampler.reset()
        res[name] = fn()
        res["section_seconds"][name] = time.perf_counter() - t
        res["memory"][f"after_{name}"] = {**memory_snapshot(),
                                          **{f"section_peak_{k}": v for k, v in sampler.reset().items()}}

    section("render", lambda: bench_render(cfg, tmp_root))
    section("train", lambda: {str(s): bench_train(cfg, s) for s in cfg.sizes})
    section("train_ab", lambda: bench_train_ab(cfg))
    section("encode", lambda: {str(s): bench_encode(cfg, s) for s in cfg.sizes})
    if "fusion" in sections:
        section("gemm", lambda: bench_gemm(cfg))
        section("fusion", lambda: {str(s): bench_fusion(cfg, s, res["gemm"]["gflops_per_s"]) for s in cfg.sizes})
    section("retrieval_synthetic", lambda: bench_retrieval_synthetic(cfg, tmp_root))
    section("retrieval_real", lambda: bench_real_agreement(cfg, checkpoint, tmp_root))
    section("precision", lambda: bench_precision(cfg))
    section("train_profile", lambda: bench_train_profile(cfg))
    return sampler


def _memory_peak(memory: dict) -> dict:
    """A memory snapshot now plus the largest sampled anonymous and file-backed RSS (bytes) over the sections'
    ``after_<name>`` entries of ``memory`` (0 when no section ran)."""
    peak = memory_snapshot()
    peak["peak_RssAnon_bytes"] = max(v.get("section_peak_RssAnon", 0) for v in memory.values()) \
        if memory else 0
    peak["peak_RssFile_bytes"] = max(v.get("section_peak_RssFile", 0) for v in memory.values()) \
        if memory else 0
    return peak


def run(cfg: BenchConfig, out_path: str | os.PathLike, checkpoint: str | None = None, tmp_root: str | None = None,
        sections: tuple[str, ...] | None = None) -> dict:
    """Run every section and write the JSON atomically; returns the result dict."""
    import torch

    from helpers.core.fileio import atomic_write_json
    from helpers.core.paths import portable_obj
    # Loaded before t_start, so its import time stays outside total_seconds; _run_header uses it.
    from helpers.study.provenance import run_record  # noqa: F401

    gate = timing.configure(cfg.quiet_threshold, cfg.wait_quiet_s, cfg.retry_contended)
    torch.set_num_threads(cfg.threads)
    sections = _check_sections(sections)
    t_start = time.perf_counter()
    res = _run_header(cfg, checkpoint)
    sampler = _run_sections(cfg, res, sections, checkpoint, tmp_root)

    res["cache_bytes_13x10000"] = cache_bytes(sizes=(64, 128))
    written = res.get("retrieval_synthetic", {}).get("write")
    if written:
        res["cache_bytes_written"] = written
    sampler.stop()
    res["memory"]["peak"] = _memory_peak(res["memory"])
    res["memory"]["note"] = _MEMORY_NOTE
    res["targets"] = evaluate_targets(res)
    res["summary"] = summarise(res)
    res["loadavg_end"] = list(os.getloadavg())
    res["quiet_wait_s"] = gate.waited_s
    res["total_seconds"] = time.perf_counter() - t_start
    atomic_write_json(out_path, portable_obj(res))
    return res


def summarise(res: dict) -> dict:
    """The headline numbers, flat."""
    s: dict[str, Any] = {}
    r = res.get("render")
    if r:
        for k, v in r.items():
            if isinstance(v, dict) and "renders_per_s" in v:
                s[f"{k}_per_s"] = v["renders_per_s"]
    for sz, v in res.get("train", {}).items():
        s[f"train_images_per_s_{sz}"] = v["images_per_s"]
    ab = res.get("train_ab")
    if ab:
        s["train_ab_images_per_s_A"] = ab["A"]["images_per_s"]
        s["train_ab_images_per_s_B"] = ab["B"]["images_per_s"]
        s["train_ab_ratio_B_over_A"] = ab["ratio_images_per_s_B_over_A"]
        s["train_ab_loss_max_abs_diff"] = ab["loss_max_abs_diff_A_vs_B"]
        s["train_ab_preprocess_speedup"] = ab["preprocess"]["speedup_A_over_B"]
        s["train_ab_data_s_per_step"] = ab["breakdown"]["data_s_per_step"]
        s["train_ab_compute_s_per_step"] = ab["breakdown"]["compute_s_per_step"]
        s["train_ab_data_fraction"] = ab["breakdown"]["data_fraction"]
    for sz, v in res.get("encode", {}).items():
        s[f"encode_refs_per_s_{sz}"] = v["refs_per_s"]
    if "gemm" in res:
        s["gemm_gflops_per_s"] = res["gemm"]["gflops_per_s"]
    for sz, v in res.get("fusion", {}).items():
        for qk in [k for k in v if k.startswith("Q") and isinstance(v[k], dict)]:
            s[f"fusion_pair_scores_per_s_{sz}_{qk}"] = v[qk]["pair_scores_per_s"]
            s[f"fusion_fraction_of_gemm_{sz}_{qk}"] = v[qk]["fraction_of_gemm"]
    for key, b in res.get("retrieval_synthetic", {}).get("banks", {}).items():
        if not b.get("skipped"):
            s[f"fast_s_per_query_{key}"] = b["fast"]["s_per_query_median"]
            s[f"greedy_s_per_query_{key}"] = b["greedy"]["s_per_query_median"]
            s[f"speedup_{key}"] = b["speedup_greedy_over_fast"]
            if "fast_batched" in b:
                s[f"fast_batched_s_per_query_{key}"] = b["fast_batched"]["s_per_query_mean"]
                s[f"speedup_batched_{key}"] = b["speedup_greedy_over_fast_batched"]
            s[f"fast_comparisons_{key}"] = b["fast"]["comparisons_per_query_median"]
            if "c2f" in b:
                s[f"c2f_s_per_query_{key}"] = b["c2f"]["s_per_query_median"]
                s[f"speedup_c2f_{key}"] = b["speedup_greedy_over_c2f"]
                s[f"c2f_comparisons_{key}"] = b["c2f"]["comparisons_per_query_median"]
                s[f"c2f_agreement_fast_{key}"] = b["synthetic_agreement_c2f_fast"]
                s[f"c2f_agreement_greedy_{key}"] = b["synthetic_agreement_c2f_greedy"]
            if "c2f_halving" in b:
                s[f"c2f_halving_s_per_query_{key}"] = b["c2f_halving"]["s_per_query_median"]
                s[f"speedup_c2f_halving_{key}"] = b["speedup_greedy_over_c2f_halving"]
                s[f"c2f_halving_comparisons_{key}"] = b["c2f_halving"]["comparisons_per_query_median"]
                s[f"c2f_halving_agreement_fast_{key}"] = b["synthetic_agreement_c2f_halving_fast"]
                s[f"c2f_halving_agreement_greedy_{key}"] = b["synthetic_agreement_c2f_halving_greedy"]
    rr = res.get("retrieval_real")
    if rr:
        s["real_agreement_same_reference"] = rr["agreement_same_reference"]
        s["real_rot_acc_greedy_pct"] = rr["greedy"]["rot_acc_pct"]
        s["real_rot_acc_fast_pct"] = rr["fast"]["rot_acc_pct"]
        if "c2f" in rr:
            s["real_rot_acc_c2f_pct"] = rr["c2f"]["rot_acc_pct"]
            s["real_agreement_c2f_greedy_same_reference"] = rr["agreement_c2f_greedy_same_reference"]
            s["real_agreement_c2f_fast_same_reference"] = rr["agreement_c2f_fast_same_reference"]
    for sz, v in res.get("train_profile", {}).get("sizes", {}).items():
        s[f"train_profile_encode_share_{sz}"] = v["share"]["encode"]
        s[f"train_profile_not_encoder_share_{sz}"] = v["not_encoder_share"]
        s[f"train_profile_validation_share_zoo_{sz}"] = v["validation_share_per_step"]["zoo"]
    pr = res.get("precision")
    if pr:
        s["precision_ratio_bf16_over_fp32"] = pr["speed"]["ratio_bf16_over_fp32"]
        s["precision_max_epoch_loss_diff"] = pr["fidelity"]["max_epoch_loss_diff"]
        s["precision_within_tolerance"] = pr["fidelity"]["within_tolerance"]
    for sz, v in res.get("cache_bytes_13x10000", {}).items():
        s[f"cache_bytes_13x10000_{sz}px"] = v["bytes"]
    s["peak_maxrss_bytes"] = res["memory"]["peak"]["maxrss_bytes"]
    return s


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes (~3 min)")
    ap.add_argument("--out", default=None, help="JSON output (default benchmarks/results/bench[_quick].json)")
    ap.add_argument("--checkpoint", default=None, help="model checkpoint for the real-set agreement "
                                                       "(helpers.training.train.load_model); default: random init")
    ap.add_argument("--tmp", default=None, help="folder for temporary caches (default: system temp)")
    ap.add_argument("--wait-quiet", type=float, default=None,
                    help="total seconds the run may wait for other processes to leave the CPUs "
                         "(default 0 = never wait; contended repeats are still flagged and retried)")
    ap.add_argument("--sections", default=None,
                    help=f"comma-separated sections to run (default: {','.join(DEFAULT_SECTIONS)}; opt-in: "
                         f"{','.join(OPT_IN_SECTIONS)})")
    args = ap.parse_args(argv)
    cfg = QUICK if args.quick else FULL
    if args.wait_quiet is not None:
        cfg = BenchConfig(**{**cfg.to_dict(), "wait_quiet_s": args.wait_quiet})
    out = args.out or REPO / "benchmarks" / "results" / ("bench_quick.json" if args.quick else "bench.json")
    sections = tuple(args.sections.split(",")) if args.sections else None
    try:
        res = run(cfg, out, args.checkpoint, args.tmp, sections)
    except ValueError as e:
        ap.error(str(e))
    log(f"wrote {out} in {res['total_seconds']:.0f} s")
    for k, v in res["summary"].items():
        print(f"{k:48s} {v:.4g}" if isinstance(v, float) else f"{k:48s} {v}")
    skipped = res.get("targets", {}).get("bank_13x10000_measured")
    if skipped:  # the run's headline numbers are missing: fail loudly (free space, then run again)
        print(f"ERROR: the {PAPER_OBJECTS} x {PAPER_REFS} bank was not measured ({skipped['reason']}); "
              f"free disk space under --tmp and run again", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
