"""Figures a reader can trust at a glance: labels that do not run together."""

import matplotlib

matplotlib.use("Agg")

import pandas as pd  # noqa: E402

from helpers.study import figures  # noqa: E402


def test_reference_count_axes_label_each_count_once(tmp_path, monkeypatch):
    df = pd.DataFrame({"refs_per_object": [128, 256, 512, 1024, 2048] * 2,
                       "unseen rot_acc": [38.3, 51.0, 58.0, 70.0, 75.5, 30.0, 35.0, 42.3, 50.0, 64.5],
                       "queries/s": [40.0, 25.0, 11.0, 5.0, 2.5, 90.0, 70.0, 60.0, 40.0, 20.0],
                       "search": ["greedy"] * 5 + ["fast"] * 5})
    kept = {}
    monkeypatch.setattr(figures, "save", lambda fig, path: kept.setdefault("fig", fig))
    figures.reference_count_figure(df, 1, tmp_path / "rc.png")
    fig = kept["fig"]
    fig.canvas.draw()
    ax, ax2 = fig.axes
    assert [t.get_text() for t in ax.get_xticklabels()] == ["128", "256", "512", "1,024", "2,048"]
    assert not [t for t in ax.get_xticklabels(minor=True) if t.get_text()]
    assert not [t for t in ax2.get_yticklabels(minor=True) if t.get_text()]  # no "3x10^1 4x10^1 ..." run-together


def test_table1_intervals_hold_the_table_values_and_are_drawn(tmp_path):
    """Table 1's error bars come from the per-query table: each interval holds its bar (the committed quick run),
    and both Table 1 figures are written."""
    import pandas as pd

    from helpers.core.paths import REPO_ROOT
    from helpers.study.figures import bar_chart, methods_figure, table1_intervals

    d = REPO_ROOT / "reports" / "quick" / "03_evaluate"
    t1, pq = pd.read_csv(d / "table1_splits.csv"), pd.read_csv(d / "per_query_ours.csv")
    ci = table1_intervals(t1, pq)
    assert list(ci["split"]) == list(t1["split"])
    for col in ("unseen rot_acc", "seen rot_acc", "occluded unseen rot_acc"):
        lo, hi, v = ci[f"{col} lo"], ci[f"{col} hi"], t1[col]
        assert ((lo <= v + 1e-9) & (v <= hi + 1e-9) & (hi - lo > 0)).all(), (col, ci)
    assert bar_chart(t1, tmp_path / "t1.png", pq).stat().st_size > 0
    hog = pd.read_csv(d / "per_query_hog.csv")
    by_method = {("Ours", "greedy"): pq[pq["part"] == "unseen"], ("HOG", "greedy"): hog}
    assert methods_figure(by_method, tmp_path / "m.png").stat().st_size > 0
