"""Scoring a model (or HOG) on the T-LESS-like set (:mod:`helpers.data.tless`) as in the paper's Table 3.

Every query is retrieved by greedy search among the references of ALL parts (category retrieved, not given;
the same rule for every method). Per query: the predicted part, the rotation error under the true part's
symmetries, and err_vsd (estimated rotation, true translation; 1.0 when the predicted part is another one,
whose pose cannot be right). ``vsd_ok`` = right part and err_vsd <= 0.3 (the paper's T-LESS Rota. Acc.);
``rot_ok`` = right part and rotation error < 30 deg. Accuracies average per part, then over parts.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from ...core.configs import GREEDY
from ...core.device import resolve_device
from ...core.paths import cache_dir
from ...data.tless import TlessSet
from ...evaluation import paper
from ...evaluation.metrics import summarise_queries
from ...evaluation.stats import accuracy_ci
from ...evaluation.tless_scoring import VSD_THRESHOLD, vsd_errors
from ...search.bank import ReferenceBank
from ...search.features import FeatureCache, encode_batch, model_fingerprint
from ..figures import _plt, save
from ..pipeline import evaluate


def tless_bank(model: Any, tset: TlessSet, device: str = "auto", cache: str | os.PathLike | None = None,
               progress: bool = True) -> ReferenceBank:
    """Reference features of every part (cached float16, keyed by the set and the model's weights)."""
    dev = resolve_device(device)
    fc = FeatureCache(cache_dir(cache) / "features")
    mkey = model_fingerprint(model)
    feats = [fc.get_or_build(model, mkey, tset.refs[n], f"tless-{tset.key}-{n}", batch=encode_batch(dev),
                             device=dev, progress=progress) for n in tset.names]
    return ReferenceBank(feats, tset.refs[tset.names[0]].rotations, tset.names, k_ac=None)


def evaluate_tless(model: Any, tset: TlessSet, device: str = "auto", cache: str | os.PathLike | None = None,
                   progress: bool = True) -> dict[str, Any]:
    """Retrieve every query of the set and score it.

    Returns:
        {"per_query": DataFrame (split, obj, pred_obj, query_id, class_ok, err_deg, rot_ok, vsd, vsd_ok),
         "per_object": DataFrame, "means": {"class_acc", "rot_acc", "vsd_acc", "median_vsd"},
         "records": the retrieval's records (R_est per query)}.
    """
    bank = tless_bank(model, tset, device, cache, progress)
    res = evaluate(model, bank, tset.queries, GREEDY, device)
    pq = res["per_query"].copy()
    R_est = {r.query_id: r.R_est for r in res["records"]}
    vsd = np.ones(len(pq))
    for name in tqdm(tset.names, desc="err_vsd", disable=not progress):
        rows = np.flatnonzero((pq["obj"] == name).to_numpy())
        ok = rows[pq["class_ok"].to_numpy()[rows]]
        if len(ok):
            idx = [int(q.rsplit(":", 1)[1]) for q in pq["query_id"].iloc[ok]]
            errs = vsd_errors(tset, name, np.stack([R_est[q] for q in pq["query_id"].iloc[ok]]), indices=idx)
            vsd[ok] = errs
    pq["vsd"] = vsd
    pq["vsd_ok"] = pq["class_ok"] & (pq["vsd"] <= VSD_THRESHOLD)
    pq.insert(0, "split", "tless")
    per_object, means = summarise_queries(pq)
    per_object["vsd_acc"] = 100.0 * pq.groupby("obj")["vsd_ok"].mean().reindex(per_object.index)
    means = {**means, "vsd_acc": float(per_object["vsd_acc"].mean()), "median_vsd": float(pq["vsd"].median())}
    return {"per_query": pq, "per_object": per_object, "means": means, "records": res["records"]}


def tless_table(results: dict[str, dict]) -> pd.DataFrame:
    """One row per method: Class. Acc., Rota. Acc. (< 30 deg) and VSD accuracy (%) with 95 % intervals
    (queries resampled within parts), the paper's T-LESS number where it has one."""
    rows = []
    for label, res in results.items():
        pq = res["per_query"]
        row = {"method": label}
        for col, name in (("class_ok", "class_acc"), ("rot_ok", "rot_acc"), ("vsd_ok", "vsd_acc")):
            v, ci = accuracy_ci(pq, col)
            row[name], row[f"{name} ci95"] = round(v, 2), f"[{ci[0]:.1f}, {ci[1]:.1f}]"
        row["median_vsd"] = round(float(pq["vsd"].median()), 3)
        row["paper vsd_acc"] = paper.TLESS_TABLE3.get("Ours (paper)" if label.startswith("Ours") else label)
        rows.append(row)
    return pd.DataFrame(rows)


def examples_figure(tset: TlessSet, res: dict, path: str | os.PathLike, n: int = 8):
    """Query | retrieved reference (the predicted part at the estimated rotation) with err_vsd, for the first
    query of ``n`` parts; green = err_vsd <= 0.3 with the right part."""
    plt = _plt()
    pq = res["per_query"]
    rows = pq.groupby("obj").head(1).head(n)
    R_est = {r.query_id: r.R_est for r in res["records"]} if "records" in res else {}
    fig, axes = plt.subplots(2, len(rows), figsize=(1.7 * len(rows), 3.8), squeeze=False)
    for j, (_, r) in enumerate(rows.iterrows()):
        name, i = r["query_id"].rsplit(":", 1)
        axes[0, j].imshow(tset.queries[name].images[int(i)])
        axes[0, j].set_title(name, fontsize=6)
        refs = tset.refs[r["pred_obj"]]
        k = int(np.argmax(np.einsum("nij,ij->n", refs.rotations.astype(np.float64), R_est[r["query_id"]])))
        axes[1, j].imshow(refs.images[k])
        axes[1, j].set_title(f"→ {r['pred_obj']}\nvsd {r['vsd']:.2f}", fontsize=6,
                             color="green" if r["vsd_ok"] else "red")
        for a in axes[:, j]:
            a.set_xticks([])
            a.set_yticks([])
    return save(fig, path)
