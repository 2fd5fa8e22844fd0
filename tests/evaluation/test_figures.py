"""Figure helpers (pirl_sim.evaluation.figures): the kNN-vs-k figure on a log axis, and log-axis labels."""

import numpy as np
import pandas as pd
import pytest


def _data_boxes(ax):
    """Display-space boxes of every data mark in ``ax``: bars, and each segment of lines and error bars."""
    from matplotlib.transforms import Bbox

    boxes = [p.get_window_extent() for p in ax.patches if p.get_visible() and p.get_height() > 0]
    paths = [(ln.get_transform(), ln.get_path()) for ln in ax.get_lines()]
    for coll in ax.collections:
        paths += [(coll.get_transform(), p) for p in coll.get_paths()]
    for transform, path in paths:
        xy = transform.transform(path.vertices)
        xy = xy[np.isfinite(xy).all(axis=1)]
        boxes += [Bbox([np.minimum(a, b), np.maximum(a, b)]) for a, b in zip(xy[:-1], xy[1:])] or \
            [Bbox([p, p]) for p in xy]
    return boxes


def _legends(fig):
    return list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]


def _assert_legends_clear(fig):
    from matplotlib.transforms import Bbox

    fig.canvas.draw()
    legends = _legends(fig)
    assert legends, "the figure has a legend"
    for legend in legends:
        box = legend.get_window_extent()
        for ax in fig.axes:
            if not ax.get_visible():
                continue
            clipped = [Bbox.intersection(b, ax.bbox) for b in _data_boxes(ax)]  # marks are drawn inside the axes
            hits = [b for b in clipped if b is not None and box.overlaps(b)]
            assert not hits, f"legend {[t.get_text() for t in legend.get_texts()]} covers data of {ax.get_title()!r}"


def _assert_tick_below_data(ax):
    """A labelled y tick at or below the lowest data point, inside the axis limits."""
    ax.figure.canvas.draw()
    lo, hi = ax.get_ylim()
    labelled = [t.get_loc() for t in ax.yaxis.get_major_ticks()
                if t.label1.get_visible() and t.label1.get_text() and lo * (1 - 1e-9) <= t.get_loc() <= hi]
    data_min = min(float(np.nanmin(ln.get_ydata())) for ln in ax.get_lines() if len(ln.get_ydata()))
    assert labelled and min(labelled) <= data_min, (ax.get_title(), labelled, data_min)


def test_knn_vs_k_draws_no_band_through_zero_on_a_log_axis():
    from matplotlib.container import ErrorbarContainer

    from pirl_sim.evaluation.figures import knn_vs_k_figure, pyplot

    ktable = pd.DataFrame({"protocol": ["paper"] * 3 + ["online"] * 3, "k": [1, 3, 10] * 2,
                           "med": [6e-5, 4e-5, 9e-5, 1.4e-5, 9e-6, 2e-5],
                           "med_std": [1.7e-4, 8e-5, 3e-4, 4e-5, 2e-5, 7e-5]})  # std > mean, as measured
    fig = knn_vs_k_figure(ktable, "test")
    try:
        (ax,) = fig.axes
        assert ax.get_yscale() == "log"
        assert not [c for c in ax.containers if isinstance(c, ErrorbarContainer)], "no mean - std bar below 0"
        drawn = np.concatenate([np.asarray(ln.get_ydata(), float) for ln in ax.get_lines()])
        drawn = drawn[np.isfinite(drawn)]
        lo, hi = ax.get_ylim()
        assert (drawn > 0).all() and lo <= drawn.min() and drawn.max() <= hi  # everything is on the axis
        for std in ktable["med_std"]:
            assert np.isclose(drawn, std).any(), "the std is drawn as its own curve"
        assert "neighbours" in ax.get_xlabel()
        _assert_legends_clear(fig)
        _assert_tick_below_data(ax)
    finally:
        pyplot().close(fig)


def test_label_log_axis_rejects_bad_limits():
    from pirl_sim.evaluation.figures import label_log_axis, pyplot

    fig, ax = pyplot().subplots()
    try:
        with pytest.raises(ValueError, match="lo="):
            label_log_axis(ax, 0.0, 1.0)
        with pytest.raises(ValueError, match="hi="):
            label_log_axis(ax, 1.0, float("nan"))
    finally:
        pyplot().close(fig)
