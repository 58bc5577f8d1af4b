"""Stages 4-8: ablations (scales, fusion, components), reference count, fast vs greedy.

Each ablation trains every variant with the same data, seed and training
budget on the seen objects of one split, and evaluates the unseen objects of
that split with greedy search among the 13 benchmark objects.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import torch

from . import paper
from .fileio import atomic_write_json
from .figures import _plt, save
from .metrics import paired_difference
from .stage_train import data_config, train_model
from .study import StudyData, encode_queries, evaluate, prepare_data, reference_bank
from .tables import write_table


def _unseen_result(P: dict, data: StudyData, split: int, **overrides) -> dict:
    model, run, info = train_model(P, data, split, **overrides)
    bench = data.manifest.object_names("train")
    bank = reference_bank(model, data, bench, device=P["device"], n_refs=P["eval_refs"] or None)
    res = evaluate(model, bank, {n: data.test_q[n] for n in data.manifest.split_objects(split)}, "greedy", P["device"])
    return {"model": model, "run": run, "res": res, "info": info}


def _row(label: str, r: dict, **extra) -> dict:
    m = r["res"]["means"]
    return {"variant": label, "unseen rot_acc": m["rot_acc"], "unseen class_acc": m["class_acc"],
            "unseen median_err_deg": m["median_err_deg"], "n_queries": m["n_queries"],
            "run": Path(r["run"]).name, **extra}


def bars(df: pd.DataFrame, label_col: str, value_col: str, path: Path, title: str,
         paper_col: str | None = None) -> Path:
    """Bar chart of one metric per variant (with the paper's values hatched beside, if given)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(max(4, 0.9 * len(df) + 1.5), 3.2))
    x = np.arange(len(df))
    w = 0.38 if paper_col else 0.6
    ax.bar(x - (w / 2 if paper_col else 0), df[value_col], w, label="ours")
    if paper_col:
        pv = pd.to_numeric(df[paper_col], errors="coerce")
        ax.bar(x + w / 2, pv.fillna(0), w, label="paper (LineMOD)", color="lightgrey", edgecolor="k", hatch="//")
        ax.legend(fontsize=7)
    ax.set_xticks(x, df[label_col], rotation=20, fontsize=8)
    ax.set_ylabel(value_col)
    ax.set_title(title, fontsize=9)
    return save(fig, path)


def trend_holds(values: dict[str, float], order: list[str]) -> bool:
    """True if ``values`` increase (non-strictly) along ``order``."""
    v = [values[k] for k in order if k in values]
    return all(a <= b for a, b in zip(v, v[1:]))


def claim(per_query: dict[str, pd.DataFrame], worse: str, better: str) -> dict | None:
    """Paper claim "``better`` beats ``worse``" on our queries: point estimate and paired 95 % interval.

    ``holds`` is the point estimate (better > worse); ``verdict`` says whether
    the paired bootstrap interval of the difference excludes 0. None when a
    variant was not run.
    """
    if worse not in per_query or better not in per_query:
        return None
    c = paired_difference(per_query[worse], per_query[better])
    return {"holds": bool(c["diff_pts"] > 0), "compare": f"{better} vs {worse}", **c,
            "verdict": {"b > a": "significant", "b < a": "significantly reversed"}.get(c["verdict"], "within noise")}


def chain(per_query: dict[str, pd.DataFrame], order: list[str]) -> dict | None:
    """Claim that accuracy rises along ``order``: every consecutive pair as in :func:`claim`."""
    present = [k for k in order if k in per_query]
    if len(present) < 2:
        return None
    pairs = [claim(per_query, a, b) for a, b in zip(present, present[1:])]
    verdicts = {p["verdict"] for p in pairs}
    return {"holds": all(p["holds"] for p in pairs), "pairs": pairs,
            "verdict": "significant" if verdicts == {"significant"} else
            "partly reversed beyond noise" if "significantly reversed" in verdicts else "within noise"}


def variant_study(P: dict, out_dir: Path, data: StudyData, variants: list[tuple[str, dict, dict]], stem: str,
                  title: str, paper_col: str | None = None) -> tuple[pd.DataFrame, dict[str, pd.DataFrame]]:
    """Train (or load) one model per variant on split ``P["split"]`` and evaluate its unseen objects.

    Args:
        variants: (label, :func:`train_config` overrides, extra table columns).
        stem: file stem of the table and figure in ``out_dir``.

    Returns:
        (table with one row per variant, label -> per-query results for :func:`claim`).
    """
    rows, per_query = [], {}
    for label, overrides, extra in variants:
        r = _unseen_result(P, data, P["split"], **overrides)
        rows.append(_row(label, r, **extra))
        per_query[label] = r["res"]["per_query"]
    df = pd.DataFrame(rows)
    write_table(df, out_dir / stem)
    bars(df, "variant", "unseen rot_acc", out_dir / f"{stem}.png", f"{title}, split #{P['split']} unseen",
         paper_col=paper_col)
    return df, per_query


def _finish(out_dir: Path, df: pd.DataFrame, trend: dict) -> dict:
    out = {"table": df.to_dict(orient="records"), "trend": {k: v for k, v in trend.items() if v is not None},
           "noise": "claims compare object-averaged Rota. Acc. of two variants on the same queries; ci is a "
                    "paired bootstrap 95 % interval (queries resampled within objects)"}
    atomic_write_json(out_dir / "metrics.json", out)
    return out


# ------------------------------------------------------------------ 04 scales

SCALE_VARIANTS = ["global", "13", "16", "32", "16,13", "32,16,13"]


def run_scales(P: dict, out_dir: Path, data: StudyData | None = None) -> dict:
    """Paper Fig. 5a: global descriptor vs single scales vs combinations."""
    data = data or prepare_data(data_config(P))
    df, pq = variant_study(P, out_dir, data, [(v, {"scales": v}, {}) for v in P["variants"]], "scales",
                           "Scales (cf. paper Fig. 5a)")
    singles = [k for k in ("13", "16", "32") if k in pq]
    trend = {"multi_scale_beats_global": claim(pq, "global", "32,16,13"),
             **{f"multi_scale_beats_{k}": claim(pq, k, "32,16,13") for k in singles},
             "paper_claim": paper.SCALES_CLAIM}
    return _finish(out_dir, df, trend)


# ------------------------------------------------------------------ 05 fusion

def run_fusion(P: dict, out_dir: Path, data: StudyData | None = None) -> dict:
    """Paper Fig. 6a: Avg / Sigmoid / Softmax / adaptive (sigmoid x softmax)."""
    data = data or prepare_data(data_config(P))
    df, pq = variant_study(P, out_dir, data,
                           [(v, {"fusion": v}, {"paper split#1 rot_acc": paper.FUSION_SPLIT1.get(v)})
                            for v in P["variants"]],
                           "fusion", "Fusion (cf. paper Fig. 6a)", paper_col="paper split#1 rot_acc")
    order = ["avg", "sigmoid", "softmax", "adaptive"]
    trend = {"paper_order_avg<sigmoid<softmax<adaptive": chain(pq, order),
             **{f"adaptive_beats_{k}": claim(pq, k, "adaptive") for k in order[:-1]}}
    return _finish(out_dir, df, trend)


# ------------------------------------------------------------------ 08 components

def run_components(P: dict, out_dir: Path, data: StudyData | None = None) -> dict:
    """Paper Table 5: local normalisation and weighted infoNCE on/off."""
    data = data or prepare_data(data_config(P))

    def label(ln: bool, wl: bool) -> str:
        return f"LN={'on' if ln else 'off'}, wInfoNCE={'on' if wl else 'off'}"

    variants = [(label(ln, wl), {"local_norm": ln, "weighted_loss": wl},
                 {"local_norm": ln, "weighted_loss": wl, "paper split#1 rot_acc": paper.COMPONENTS_SPLIT1[(ln, wl)]})
                for ln in (False, True) for wl in (False, True)]
    df, pq = variant_study(P, out_dir, data, variants, "components", "Components (cf. paper Table 5)",
                           paper_col="paper split#1 rot_acc")
    trend = {"both_beats_neither": claim(pq, label(False, False), label(True, True)),
             "local_norm_helps": claim(pq, label(False, False), label(True, False)),
             "weighted_loss_helps": claim(pq, label(False, False), label(False, True))}
    return _finish(out_dir, df, trend)


# ------------------------------------------------------------------ 06 reference count

def run_reference_count(P: dict, out_dir: Path, data: StudyData | None = None) -> dict:
    """Paper Fig. 7: accuracy and queries/s against references per object.

    Uses the first n of the (Haar-uniform) references of every object, so
    each count is itself Haar-uniform.
    """
    data = data or prepare_data(data_config(P))
    model, run, _ = train_model(P, data)
    bench = data.manifest.object_names("train")
    unseen = data.manifest.split_objects(P["split"])
    counts = [c for c in P["reference_counts"] if c <= data.cfg.n_references]
    rows = []
    for c in counts:
        bank = reference_bank(model, data, bench, device=P["device"], n_refs=c)
        res = evaluate(model, bank, {n: data.test_q[n] for n in unseen}, "greedy", P["device"])
        s = float(np.median(res["seconds_per_query"]))
        rows.append({"refs_per_object": c, "unseen rot_acc": res["means"]["rot_acc"],
                     "unseen class_acc": res["means"]["class_acc"], "unseen median_err_deg": res["means"]["median_err_deg"],
                     "median s/query (greedy)": s, "queries/s": 1.0 / s})
    df = pd.DataFrame(rows)
    write_table(df, out_dir / "reference_count")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.plot(df["refs_per_object"], df["unseen rot_acc"], "o-", label="Rota. Acc. (%)")
    ax.set_xscale("log")
    ax.set_xlabel("references per object")
    ax.set_ylabel("unseen Rota. Acc. (%)")
    ax2 = ax.twinx()
    ax2.plot(df["refs_per_object"], df["queries/s"], "s--", color="tab:orange", label="queries/s")
    ax2.set_ylabel("queries/s (greedy)")
    ax.set_title(f"Reference count, split #{P['split']} unseen (cf. paper Fig. 7)", fontsize=9)
    save(fig, out_dir / "reference_count.png")
    acc = df["unseen rot_acc"].to_numpy()
    out = {"table": df.to_dict(orient="records"), "run": str(run),
           "trend": {"accuracy_rises_from_fewest_to_most": bool(len(acc) > 1 and acc[-1] > acc[0]),
                     "speed_falls": bool(len(df) > 1 and df["queries/s"].iloc[-1] < df["queries/s"].iloc[0]),
                     "paper_claim": paper.REFERENCE_COUNT_CLAIM}}
    atomic_write_json(out_dir / "metrics.json", out)
    return out


# ------------------------------------------------------------------ 07 fast vs greedy

def agreement_within(greedy: list, fast: list, threshold_deg: float = 30.0, n_boot: int = 2000,
                     seed: int = 0) -> dict:
    """Share of queries on which ``fast`` predicts greedy's object and a rotation within
    ``threshold_deg`` of greedy's (symmetry-aware), with a bootstrap 95 % interval over queries.

    Both are lists of :class:`helpers.metrics.Record` for the same queries, in order.
    """
    from .rotations import symmetric_geodesic_deg

    ok = np.array([a.pred_obj == b.pred_obj and
                   float(symmetric_geodesic_deg(a.R_est[None], b.R_est[None], a.symmetries if a.pred_obj == a.obj
                                                else None)[0]) < threshold_deg
                   for a, b in zip(greedy, fast)], dtype=float)
    rng = np.random.default_rng(seed)
    boots = ok[rng.integers(0, len(ok), size=(n_boot, len(ok)))].mean(axis=1) if len(ok) else np.zeros(1)
    return {"share": float(ok.mean()) if len(ok) else float("nan"),
            "ci95": [float(np.quantile(boots, 0.025)), float(np.quantile(boots, 0.975))], "n": int(len(ok))}


def run_fast_vs_greedy(P: dict, out_dir: Path, data: StudyData | None = None) -> dict:
    """Paper Table 4: the same queries through greedy search and fast retrieval.

    Queries: unseen test queries of the split, retrieved among all 13 benchmark
    objects. Reference features are cached before timing and one warm-up query
    runs per method first; timings are per query (encoding excluded, as the
    query is encoded once either way).
    """
    from .device import resolve_device
    from .metrics import Record, per_query_table, summarise_queries
    from .retrieval import model_scorer, search_all

    data = data or prepare_data(data_config(P))
    model, run, _ = train_model(P, data)
    dev = resolve_device(P["device"])
    bench = data.manifest.object_names("train")
    bank = reference_bank(model, data, bench, device=P["device"], k_ac=P["k_ac"])
    scorer = model_scorer(model, dev)
    unseen = data.manifest.split_objects(P["split"])
    feats, meta = [], []
    for n in unseen:
        q = encode_queries(model, data.test_q[n], P["device"])
        feats.append(q)
        meta += [(n, i) for i in range(len(q))]
    Q = torch.cat(feats)
    fast_kw = {"k_ac": P["k_ac"], "fps_k": P["fps_k"]}
    methods = {"greedy": dict(method="greedy", group=P["group"]),
               "fast (converge)": dict(method="fast", schedule="converge", query_batch=1, **fast_kw),
               "fast (authors)": dict(method="fast", schedule="authors", query_batch=1, **fast_kw),
               f"fast (converge, {P['query_batch']}-query batches)": dict(
                   method="fast", schedule="converge", query_batch=P["query_batch"], **fast_kw)}
    if P["coarse_k"]:
        methods["coarse-to-fine (converge)"] = dict(method="c2f", schedule="converge", coarse_k=P["coarse_k"],
                                                    refine_objects=P["refine_objects"], **fast_kw)
    bank.anchor_feats(P["k_ac"])  # gathered once per bank, before any timing
    rows, preds = [], {}
    for name, kw in methods.items():
        search_all(Q[:2], bank, scorer, progress=False, **kw)  # warm-up
        ps = search_all(Q, bank, scorer, progress=False, **kw)
        recs = []
        for p, (n, j) in zip(ps, meta):
            recs.append(Record(n, p.obj_name, data.test_q[n].rotations[j].astype(np.float64), p.R_est,
                               data.test_q[n].symmetries, f"{n}:{j}"))
        preds[name] = recs
        _, means = summarise_queries(per_query_table(recs))
        ref = paper.FAST_VS_GREEDY["greedy" if name == "greedy" else "fast"]
        rows.append({"method": name, "unseen rot_acc": means["rot_acc"], "unseen class_acc": means["class_acc"],
                     "median s/query": float(np.median([p.seconds for p in ps])),
                     "mean s/query": float(np.mean([p.seconds for p in ps])),
                     "mean comparisons/query": float(np.mean([p.n_comparisons for p in ps])),
                     "paper rot_acc": ref["rot_acc"], "paper s/query (V100, 13x10k)": ref["seconds_per_query"]})
    df = pd.DataFrame(rows)
    g = df.iloc[0]
    df["speedup vs greedy"] = g["median s/query"] / df["median s/query"]
    agree = {k: float(np.mean([a.pred_obj == b.pred_obj and np.allclose(a.R_est, b.R_est)
                               for a, b in zip(preds["greedy"], v)])) for k, v in preds.items() if k != "greedy"}
    agree30 = {k: agreement_within(preds["greedy"], v) for k, v in preds.items() if k != "greedy"}
    write_table(df, out_dir / "fast_vs_greedy")
    bars(df, "method", "median s/query", out_dir / "fast_vs_greedy.png", "Time per query (cf. paper Table 4)")
    out = {"table": df.to_dict(orient="records"), "agreement_with_greedy": agree,
           "agreement_30deg": agree30, "main_fast_method": "fast (converge)",
           "bank": {"objects": len(bench), "refs_per_object": bank.n_refs, "k_ac": min(P["k_ac"], bank.n_refs)},
           "device": str(dev), "n_queries": len(Q),
           "trend": {"fast_is_faster": bool(df["median s/query"].iloc[1] < g["median s/query"]),
                     "fast_accuracy_drop_pts": float(g["unseen rot_acc"] - df["unseen rot_acc"].iloc[1])}}
    atomic_write_json(out_dir / "metrics.json", out)
    return out
