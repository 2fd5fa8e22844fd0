"""Figure helpers (pirl_sim.evaluation.figures): the kNN-vs-k figure on a log axis, and log-axis labels."""

import numpy as np
import pandas as pd
import pytest

from figure_checks import assert_legends_clear, assert_tick_below_data


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
        assert_legends_clear(fig)
        assert_tick_below_data(ax)
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
