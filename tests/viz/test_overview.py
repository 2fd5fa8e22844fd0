"""The recording overview (pirl_sim.viz.overview): a track coloured piecewise by speed."""

import numpy as np

from pirl_sim.viz import color_rows, data_to_pixel, draw_recording, figure_to_array

from viz_testdata import has_color_near, straight_tracks


SMALL = (320, 240)


def test_recording_figure_colours_a_track_piecewise_by_speed():
    tracks = straight_tracks(1, 40)
    tracks["vx"] = np.where(tracks.frame_id <= 20, 2.0, 8.0)  # slow first half, fast second half
    fig = draw_recording(tracks, color_by="speed", linewidth=4.0, size_px=SMALL)
    ax = fig.axes[0]
    img = figure_to_array(fig)
    colors = color_rows(tracks, "speed")
    slow, fast = colors.rgba[0], colors.rgba[-1]
    assert has_color_near(img, data_to_pixel(ax, (4.0, 0.0)), slow, radius=1, tol=10)
    assert has_color_near(img, data_to_pixel(ax, (15.0, 0.0)), fast, radius=1, tol=10)
    assert not has_color_near(img, data_to_pixel(ax, (15.0, 0.0)), slow, radius=1, tol=30)
    assert len(fig.axes) == 2  # and its colour bar
