"""Notebook 02: training one split's model, selected on held-out views of its seen objects."""

from __future__ import annotations

from pathlib import Path

from ..report_format import fmt, load_json
from .base import Experiment


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    m = load_json(d / "train_metrics.json")
    if not m:
        return ["## 2 · Training", "", "_not run_", ""]
    u = m["unseen_test"]
    ch = m["chance"]
    bv = m.get("best_val") or {}
    hist = (load_json(d / "history.json") or {}).get("history") or []
    run = (load_json(d / "run.json") or {}).get("parameters") or {}
    budget = (f"- training budget: {hist[-1]['global_step']:,} optimiser steps of {run.get('batch_size', '?')} queries "
              f"in {sum(h['seconds'] for h in hist):.0f} s (paper: 200 epochs over every real training image, "
              f"batch 16); a CPU budget for trends, not the paper's accuracy"
              if hist else "- training budget: n/a")
    return ["## 2 · Training (split #%d)" % m["split"], "",
            budget,
            f"- parameters: encoder/decoder {m['parameters']['encoder_decoder']:,}, fusion head "
            f"{m['parameters']['fusion_head']:,} (paper: about 1.9 M and 50 K)",
            f"- training speed {fmt(m['train_images_per_s'])} images/s; selected epoch {bv.get('epoch')} on held-out "
            f"views of seen objects by `{m.get('selection', 'rot_acc')}` (val Class. Acc. {fmt(bv.get('class_acc'))} %, "
            f"Rota. Acc. {fmt(bv.get('rot_acc'))} %)",
            f"- unseen objects of the split: Class. Acc. {fmt(u['class_acc'])} % (chance {fmt(ch['class_acc'])} %), "
            f"Rota. Acc. {fmt(u['rot_acc'])} % (chance {fmt(ch['rot_acc'], 2)} %)", "",
            "![history](02_train/loss.png)", ""]


EXPERIMENT = Experiment("02_train", "train one split's model, selected on held-out views of its seen objects",
                        section=section)
