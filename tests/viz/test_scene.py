"""Scenes (pirl_sim.viz.scene): vehicles and colours where they belong, colour bars, blitting, and errors."""

import numpy as np
import pytest

from pirl_sim.viz import SceneView, color_rows, data_to_pixel, draw_scene, figure_to_array

from viz_testdata import has_color_near, straight_tracks


SMALL = (320, 240)


def test_numbers_get_a_colour_bar_and_speed_is_computed_from_vx_vy():
    tracks = straight_tracks(2, 10)
    tracks.loc[tracks.track_id == 2, "vx"] = 10.0
    colors = color_rows(tracks, "speed")
    assert colors.cmap is not None and not colors.legend
    assert colors.norm.vmin == pytest.approx(5.0) and colors.norm.vmax == pytest.approx(10.0)
    fig = draw_scene(tracks, 5, color_by="speed", size_px=SMALL)
    assert len(fig.axes) == 2  # the scene and its colour bar
    assert color_rows(tracks, "track_id").legend  # few integers: a legend


def test_vehicle_box_drawn_at_its_position_along_its_heading():
    tracks = straight_tracks(1, 5)
    tracks["psi_rad"] = np.pi / 2  # heading +y
    tracks["length"], tracks["width"] = 12.0, 2.0
    view = SceneView(tracks, trail_s=0.0, extent=(-15, 15, -15, 15), size_px=(300, 300))
    img = view.render(3)
    colour = view.colors.rgba[view.frames.rows(3)][0]
    x = view.frames.x[view.frames.rows(3)][0]
    # along the heading (y) the box covers +-5 m; across it (x) only +-1 m
    for dy in (-4.5, 0.0, 4.5):
        assert has_color_near(img, data_to_pixel(view.ax, (x, dy)), colour, radius=1, tol=10)
    for dx in (-4.0, 4.0):
        assert not has_color_near(img, data_to_pixel(view.ax, (x + dx, 0.0)), colour, radius=1, tol=60)


def test_blitted_render_equals_a_full_draw():
    tracks = straight_tracks(3, 40)
    view = SceneView(tracks, color_by="speed", show_tracks=True, size_px=SMALL)
    view.render(10)
    blitted = view.render(30)
    assert np.array_equal(blitted, figure_to_array(view.figure))


def test_frame_outside_the_recording_names_the_frame_range():
    tracks = straight_tracks(2, 20, first_frame=5)
    with pytest.raises(ValueError, match=r"frame 100 is outside the recording: frames 5\.\.24"):
        draw_scene(tracks, 100, size_px=SMALL)
    with pytest.raises(TypeError, match="frame must be an integer"):
        SceneView(tracks, size_px=SMALL).set_frame(5.5)


def test_unknown_colour_column_lists_the_columns():
    tracks = straight_tracks(2, 5)
    with pytest.raises(ValueError, match=r"unknown colour column 'style'.*'track_id'.*'psi_rad'.*'speed'"):
        draw_scene(tracks, 1, color_by="style", size_px=SMALL)
    with pytest.raises(ValueError, match="names none of the table's tracks"):
        color_rows(tracks, {99: "calm"})
    with pytest.raises(TypeError, match="color_by must be"):
        color_rows(tracks, 3.5)
