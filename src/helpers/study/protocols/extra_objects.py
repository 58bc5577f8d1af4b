"""Screen e of issue #44 (an extension beyond the paper): does training on extra objects help on unseen objects?

Each arm is zoo models (one per training seed) of the current recipe plus the first N extra objects of
``data_extra_objects.yaml`` (:mod:`helpers.data.extra_objects`), at the budget of the current recipe's ``baseline``
models (N = 0). The arms are decided on the file's VALIDATION extras, meshes never trained on by any arm (unseen
objects, but never the benchmark's test or held-out objects); the split's unseen test accuracy is reported
afterwards and never used to choose.
"""

from __future__ import annotations

from typing import Any

import pandas as pd

from ...evaluation.stats import accuracy_ci, seed_mean
from .screens import CURRENT
from .variants import Trained

#: Columns of the curve (one row per arm, in order of N).
CURVE_COLUMNS = ("N extra objects", "arm", "seeds", "validation rot_acc", "validation ci95 lo", "validation ci95 hi",
                 "unseen test rot_acc", "unseen test ci95 lo", "unseen test ci95 hi")


def extra_counts(trained: dict[str, list[Trained]]) -> dict[str, int]:
    """label -> N, the extra training objects of its zoo models (read from their entries, never typed in).

    ValueError when the current recipe's models have extra objects, when one arm's seeds differ in N, or when
    two arms have the same N (a curve over N needs one arm per N)."""
    out = {}
    for label, ts in trained.items():
        ns = {int((t.info["zoo_entry"].get("extra") or {}).get("n", 0)) for t in ts}
        if len(ns) != 1:
            raise ValueError(f"arms: {label}'s models were trained with different numbers of extra objects "
                             f"{sorted(ns)}")
        out[label] = ns.pop()
    if out[CURRENT] != 0:
        raise ValueError(f"baseline: the current recipe's models have {out[CURRENT]} extra objects, expected none")
    dup = sorted({n for n in out.values() if list(out.values()).count(n) > 1})
    if dup:
        raise ValueError(f"arms: several arms train with N = {dup} extra objects; give each N one arm")
    return dict(sorted(out.items(), key=lambda kv: kv[1]))


def _mean_ci(rs: list[dict]) -> tuple[float, float, float]:
    acc, ci = accuracy_ci(seed_mean([r["per_query"] for r in rs]))
    return float(acc), float(ci[0]), float(ci[1])


def extra_curve(counts: dict[str, int], validation: dict[str, list[dict]],
                unseen: dict[str, list[dict]] | None = None) -> pd.DataFrame:
    """The curve: per arm (in order of N) the Rota. Acc. (%) on the validation extras, the deciding number, and on
    the split's unseen test objects (``unseen``; afterwards), each the seed mean with its 95 % bootstrap interval
    over queries (:data:`CURVE_COLUMNS`)."""
    rows = []
    for label, n in counts.items():
        v = _mean_ci(validation[label])
        u = _mean_ci(unseen[label]) if unseen else (None, None, None)
        rows.append(dict(zip(CURVE_COLUMNS, (n, label, len(validation[label]), *v, *u))))
    return pd.DataFrame(rows, columns=list(CURVE_COLUMNS))


def curve_record(curve: pd.DataFrame) -> list[dict[str, Any]]:
    """The curve as JSON records (metrics.json)."""
    return [{k: (None if pd.isna(v) else (int(v) if k in ("N extra objects", "seeds") else v))
             for k, v in row.items()} for row in curve.to_dict(orient="records")]
