"""Checks of drawn matplotlib figures that several test modules make (tests/evaluation, tests/experiments): legends
clear of the data, a labelled tick at or below the data. Test modules ``from figure_checks import ...``
(tests/conftest.py puts tests/ on sys.path)."""

import numpy as np


def data_boxes(ax):
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


def legends(fig):
    """The figure's legends and those of its axes."""
    return list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]


def assert_legends_clear(fig):
    """``fig`` has a legend, and no legend covers a data mark (`data_boxes`) of a visible axes."""
    from matplotlib.transforms import Bbox

    fig.canvas.draw()
    found = legends(fig)
    assert found, "the figure has a legend"
    for legend in found:
        box = legend.get_window_extent()
        for ax in fig.axes:
            if not ax.get_visible():
                continue
            clipped = [Bbox.intersection(b, ax.bbox) for b in data_boxes(ax)]  # marks are drawn inside the axes
            hits = [b for b in clipped if b is not None and box.overlaps(b)]
            assert not hits, f"legend {[t.get_text() for t in legend.get_texts()]} covers data of {ax.get_title()!r}"


def assert_tick_below_data(ax):
    """A labelled y tick at or below the lowest data point, inside the axis limits."""
    ax.figure.canvas.draw()
    lo, hi = ax.get_ylim()
    labelled = [t.get_loc() for t in ax.yaxis.get_major_ticks()
                if t.label1.get_visible() and t.label1.get_text() and lo * (1 - 1e-9) <= t.get_loc() <= hi]
    data_min = min(float(np.nanmin(ln.get_ydata())) for ln in ax.get_lines() if len(ln.get_ydata()))
    assert labelled and min(labelled) <= data_min, (ax.get_title(), labelled, data_min)
