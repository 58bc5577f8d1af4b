"""Notebook 07: fast retrieval against greedy search, and coarse-to-fine variants (paper Table 4)."""

from __future__ import annotations

from pathlib import Path

from ...evaluation import paper
from ...evaluation.claims import fast_claims
from ...evaluation.search_results import SearchComparison
from ..report_format import claim_line, md_table
from .base import Experiment

TITLE = "## Fast retrieval vs greedy search (paper Table 4)"


def section(d: Path, claims: dict[str, dict]) -> list[str]:
    r = SearchComparison.load(d)
    if r is None:
        return [TITLE, "", "_not run_", ""]
    g = paper.FAST_VS_GREEDY
    b = r.bank
    return [TITLE, "", md_table(r.table), "",
            f"Bank: {b['objects']} objects x {b['refs_per_object']} references, {b['k_ac']} anchors; "
            f"{r.n_queries} queries on `{r.device}`; agreement with greedy: "
            + ", ".join(f"{k} {100 * v:.0f} %" for k, v in r.agreement_with_greedy.items()) + ".", "",
            f"Paper: fast {g['fast']['rot_acc']} % in {g['fast']['seconds_per_query']} s vs greedy "
            f"{g['greedy']['rot_acc']} % in {g['greedy']['seconds_per_query']} s (V100, 13 x 10,000).", "",
            *claim_line(claims, "fast_speedup", "fast retrieval is faster than greedy (greedy / fast, median "
                        "seconds per query)", unit="x"),
            *claim_line(claims, "fast_minus_greedy", "fast retrieval costs accuracy (fast minus greedy, paired)"),
            *claim_line(claims, "c2f_minus_fast", "coarse-to-fine (one cut) within 1 point of fast (paired)"),
            *claim_line(claims, "c2f_halving_minus_fast", "coarse-to-fine (halving) within 1 point of fast "
                        "(paired)"),
            *_c2f_selection_lines(r.c2f_selection), "", "![time](07_fast_vs_greedy/fast_vs_greedy.png)", ""]


def _c2f_selection_lines(sel: dict) -> list[str]:
    """The coarse-to-fine settings and how they were chosen (held-out views of seen objects)."""
    return [f"- coarse-to-fine {fam}: coarse_k {c['coarse_k']}, refine_objects {c['refine_objects']}, chosen on "
            f"held-out views of seen objects (same reference as fast on {100 * c['agreement_with_fast']:.1f} % of "
            f"them; bar {100 * sel['min_agreement']:.0f} % {'met' if c['met'] else 'NOT met: most agreeing kept'}; "
            f"{c['mean_comparisons']:.0f} pair scores/query)"
            for fam, c in sorted((sel.get("chosen") or {}).items(), key=lambda kv: kv[0] != "one cut")]  # one cut first


EXPERIMENT = Experiment("07_fast_vs_greedy", "fast retrieval against greedy search, and coarse-to-fine (paper Table 4)",
                        claims=fast_claims, section=section,
                        headline=(("fast_minus_greedy", "Fast minus greedy search (split #1)"),
                                  ("fast_speedup", "Fast search's speed-up over greedy (median s/query)"),
                                  ("c2f_halving_minus_fast", "Coarse-to-fine (halving) minus fast search")))
