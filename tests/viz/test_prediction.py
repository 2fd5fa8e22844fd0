"""pirl_sim.viz predictions: K futures in K distinguishable colours where they are, and checked inputs."""

from __future__ import annotations

import numpy as np
import pytest

from pirl_sim.viz import (
    PredictionView,
    PredictionWindow,
    data_to_pixel,
    distinct_colors,
    draw_prediction,
    figure_to_array,
)
from pirl_sim.viz.prediction import FUTURE_COLOR, HISTORY_COLOR

from viz_testdata import has_color_near, straight_tracks


def fan(k: int, horizon: int = 20, length: float = 20.0) -> np.ndarray:
    """``(k, horizon, 2)`` straight futures from the origin, fanned over 120 degrees."""
    angles = np.linspace(-np.pi / 3, np.pi / 3, k)
    s = np.linspace(length / horizon, length, horizon)
    return np.stack([np.column_stack([s * np.cos(a), s * np.sin(a)]) for a in angles])


@pytest.mark.parametrize("k", [1, 3, 6])
def test_k_futures_are_drawn_in_k_distinguishable_colours_where_they_are(k):
    preds = fan(k)
    window = PredictionWindow(history=np.column_stack([np.linspace(-10, 0, 11), np.zeros(11)]),
                              predictions=preds, probabilities=np.full(k, 1.0 / k),
                              future=np.column_stack([np.linspace(1, 15, 15), np.full(15, -3.0)]))
    fig = draw_prediction(window, extent=(-12, 22, -20, 20), size_px=(400, 400))
    ax = fig.axes[0]
    img = figure_to_array(fig)
    colours = distinct_colors(k)
    for i in range(k):
        far = preds[i, -4]  # near the end, where the futures are apart
        assert has_color_near(img, data_to_pixel(ax, far), colours[i], radius=1, tol=10), f"mode {i}"
        for j in set(range(k)) - {i}:
            assert not has_color_near(img, data_to_pixel(ax, far), colours[j], radius=1, tol=10)
    assert has_color_near(img, data_to_pixel(ax, (-5.0, 0.0)), np.array([0, 0, 0]), radius=1, tol=10)  # history
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[:2] == ["history", "recorded future"]
    assert labels[2:] == [f"mode {i + 1}: p = {1.0 / k:.2f}" for i in range(k)]
    assert HISTORY_COLOR != FUTURE_COLOR


def test_prediction_window_rejects_bad_arrays_naming_them():
    hist = np.zeros((5, 2))
    with pytest.raises(ValueError, match=r"predictions must have shape \(K, H, 2\).*got \(20, 2\)"):
        PredictionWindow(hist, np.zeros((20, 2)), [1.0])
    with pytest.raises(ValueError, match=r"probabilities must have shape \(K,\) = \(3,\)"):
        PredictionWindow(hist, fan(3), [0.5, 0.5])
    with pytest.raises(ValueError, match=r"must be >= 0 and sum to 1.*sum 0\.9"):
        PredictionWindow(hist, fan(2), [0.4, 0.5])
    with pytest.raises(ValueError, match=r"history must have shape \(N, 2\)"):
        PredictionWindow(np.zeros(5), fan(1), [1.0])
    with pytest.raises(ValueError, match="predictions has values that are not finite"):
        PredictionWindow(hist, np.full((1, 3, 2), np.nan), [1.0])
    with pytest.raises(TypeError, match="window must be a PredictionWindow"):
        draw_prediction(fan(1))
    view = PredictionView(max_k=2, size_px=(200, 200))
    with pytest.raises(ValueError, match="K = 3 predicted futures; this view draws at most max_k = 2"):
        view.update(PredictionWindow(hist, fan(3), [0.2, 0.3, 0.5]))


def test_other_vehicles_at_the_window_frame_are_drawn():
    tracks = straight_tracks(2, 30)
    window = PredictionWindow(history=np.array([[0.0, 0.0], [1.0, 0.0]]), predictions=fan(2, length=5.0),
                              probabilities=[0.5, 0.5], frame=20, track_id=1)
    view = PredictionView(tracks=tracks, extent=(-5, 15, -5, 15), size_px=(300, 300))
    img = view.render(window)
    other = (view.frames.x[view.frames.rows(20)][1], 10.0)  # track 2 at frame 20, on y = 10
    assert has_color_near(img, data_to_pixel(view.ax, other), (0xb0, 0xb0, 0xb0), radius=1, tol=10)
    with pytest.raises(ValueError, match=r"frame 99 is outside the recording: frames 1\.\.30"):
        view.update(PredictionWindow(window.history, window.predictions, window.probabilities, frame=99))
