"""The sweep report's figures (pirl_sim.experiments.sweep_report) of the committed results/sweep: legends clear of
the data, one colour per learner or feature, and what k counts."""

from contextlib import contextmanager
from pathlib import Path

import pandas as pd

from figure_checks import assert_legends_clear, assert_tick_below_data


SWEEP_TABLE = Path(__file__).resolve().parents[2] / "results" / "sweep" / "table.csv"


def _sweep_summary():
    from pirl_sim.experiments.sweep_report import best_variants, summary_table

    summary = summary_table(pd.read_csv(SWEEP_TABLE))
    return summary, best_variants(summary)


def _series_colors(ax):
    """{label: colour} of the labelled lines / bar containers of ``ax``."""
    from matplotlib.colors import to_hex

    out = {}
    for c in ax.containers:
        label = c.get_label()
        if label and not label.startswith("_"):
            artist = c.patches[0] if hasattr(c, "patches") else c.lines[0]
            out[label] = to_hex(artist.get_facecolor() if hasattr(c, "patches") else artist.get_color())
    for ln in ax.get_lines():
        if not ln.get_label().startswith("_"):
            out.setdefault(ln.get_label(), to_hex(ln.get_color()))
    return out


def _assert_one_colour_per_series(fig):
    seen = {}
    for ax in fig.axes:
        for label, color in _series_colors(ax).items():
            assert seen.setdefault(label, color) == color, f"{label!r} changes colour between panels"
    assert seen, "labelled series"


@contextmanager
def _series_figure(fig):
    """``fig``, checked first for legends clear of the data and one colour per labelled series; closed at the end."""
    from pirl_sim.evaluation.figures import pyplot

    try:
        assert_legends_clear(fig)
        _assert_one_colour_per_series(fig)
        yield fig
    finally:
        pyplot().close(fig)


def test_learners_figure_legend_clear_and_colours_per_learner():
    from pirl_sim.experiments.sweep_report import learners_side_by_side_figure

    _, best = _sweep_summary()
    with _series_figure(learners_side_by_side_figure(best)) as fig:
        texts = [t.get_text() for ax in fig.axes for t in ax.texts]
        assert any(t.startswith("k=") for t in texts), "the best k is written at its bar"


def test_med_vs_k_figure_legend_colours_and_what_k_counts():
    from pirl_sim.experiments.sweep_report import med_vs_k_figure

    summary, _ = _sweep_summary()
    with _series_figure(med_vs_k_figure(summary)) as fig:
        labels = {ax.get_title(): ax.get_xlabel() for ax in fig.axes if ax.get_visible()}
        assert any("PIRL-GMM" in t for t in labels) and any("PIRL-kNN" in t for t in labels)
        for title, xlabel in labels.items():
            if "PIRL-GMM" in title:
                assert "clusters" in xlabel and "neighbours" not in xlabel, xlabel
            if "PIRL-kNN" in title:
                assert "neighbours" in xlabel and "clusters" not in xlabel, xlabel
        passage = [ax for ax in fig.axes if ax.get_title().startswith("passage")]
        assert passage
        for ax in fig.axes:
            if ax.get_visible():
                assert_tick_below_data(ax)  # the passage panel's lowest line (~0.12 m) was below every tick


def test_recovery_figure_one_colour_per_feature():
    from matplotlib.colors import to_hex

    from pirl_sim.evaluation.figures import pyplot
    from pirl_sim.experiments.sweep_report import recovery_figure

    summary, best = _sweep_summary()
    recovery = pd.read_parquet(SWEEP_TABLE.with_name("recovery.parquet"))
    fig = recovery_figure(recovery, best)
    try:
        seen = {}
        for ax in fig.axes:
            for coll in ax.collections:
                label = coll.get_label()
                if label and not label.startswith("_"):
                    color = to_hex(coll.get_facecolor()[0], keep_alpha=False)
                    assert seen.setdefault(label, color) == color, f"{label!r} changes colour between panels"
        assert len(set(seen.values())) == len(seen) >= 2
        assert_legends_clear(fig)
    finally:
        pyplot().close(fig)
