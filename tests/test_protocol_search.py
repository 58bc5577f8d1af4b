"""The protocol's search at a reference density (eval_method "density"): decided from rotations alone."""

import numpy as np
import pytest

from helpers.core.configs import paper_ratio_search
from helpers.core.rotations import haar_uniform
from helpers.search.fps import anchor_coverage_deg
from helpers.study.parameters import configs_from
from helpers.study.protocols.linemod import density_matched_search


def test_anchor_coverage_shrinks_with_more_anchors_and_is_zero_when_all_are_anchors():
    rots = haar_uniform(256, np.random.default_rng(3))
    coarse, fine = anchor_coverage_deg(rots, 8), anchor_coverage_deg(rots, 64)
    assert 0 < fine < coarse < 180
    assert anchor_coverage_deg(rots, 256) == pytest.approx(0.0, abs=1e-3)


@pytest.mark.parametrize("n, want", [(48, "greedy"), (512, "greedy"), (2048, "greedy"), (10000, "fast")])
def test_fast_search_only_at_the_papers_density(n, want):
    search, info = density_matched_search(paper_ratio_search(n), haar_uniform(n, np.random.default_rng(1)))
    assert search.method == want and info["chosen"] == want
    assert info["k_ac"] == round(n * 0.1024) and info["paper"] == "1024 of 10000"
    # The decision is the geometry: fast exactly when its anchors cover as densely as the paper's (5 % slack).
    assert (info["anchor_coverage_deg"] <= 1.05 * info["paper_anchor_coverage_deg"]) == (want == "fast")
    assert search.k_ac == info["k_ac"]  # the fast settings travel with it (the other search of Table 1)


def test_density_parameter_builds_the_fast_candidate():
    P = {"n_references": 512, "k_ac": 0, "fps_k": 0, "eval_method": "density"}
    s = configs_from(P).search
    assert s.method == "fast" and s.k_ac == 52


def test_stale_files_of_the_protocols_own_search_are_dropped(tmp_path):
    from helpers.core.configs import GREEDY
    from helpers.study.protocols.linemod import drop_stale_search_files

    for name in ("per_query_ours.csv", "per_query_ours_fast.csv", "per_query_hog_greedy.csv",
                 "per_query_ours_greedy.csv", "table1_splits.csv"):
        (tmp_path / name).write_text("x\n")
    gone = drop_stale_search_files(tmp_path, GREEDY)
    assert sorted(p.name for p in gone) == ["per_query_hog_greedy.csv", "per_query_ours_greedy.csv"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["per_query_ours.csv", "per_query_ours_fast.csv",
                                                          "table1_splits.csv"]
