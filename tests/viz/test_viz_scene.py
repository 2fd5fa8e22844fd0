"""pirl_sim.viz scenes: rendering to arrays, tracks and vehicles where their coordinates are, colours, errors."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import to_rgb
from viz_testdata import SAMPLE_MAP, SAMPLE_TRACKS, has_color_near, needs_sample, straight_tracks

from pirl_sim.viz import (
    Road,
    SceneView,
    TrackFrames,
    box_corners,
    color_rows,
    data_to_pixel,
    draw_recording,
    draw_road,
    draw_scene,
    draw_tracks,
    figure_to_array,
    new_figure,
)
from pirl_sim.viz.road import ROAD_COLORS

SMALL = (320, 240)


def test_figure_to_array_is_rgb_of_the_figure_size():
    fig = new_figure((200, 120))
    img = figure_to_array(fig)
    assert img.shape == (120, 200, 3) and img.dtype == np.uint8
    assert (img == 255).all()  # an empty white figure


def test_data_to_pixel_finds_a_drawn_point():
    fig = new_figure(SMALL)
    ax = fig.add_subplot()
    ax.set_xlim(0, 10)
    ax.set_ylim(0, 10)
    ax.plot([7.0], [2.0], "s", color="red", ms=6)
    img = figure_to_array(fig)
    col, row = data_to_pixel(ax, (7.0, 2.0))
    assert tuple(img[int(row), int(col)]) == (255, 0, 0)
    assert data_to_pixel(ax, [[7.0, 2.0], [1.0, 1.0]]).shape == (2, 2)


def test_box_corners_are_oriented_along_the_heading():
    corners = box_corners([1.0], [2.0], [np.pi / 2], [4.0], [2.0], nose=False)[0]
    # heading +y: the rear edge is at y = 0, the front at y = 4, the sides at x = 0 and x = 2
    np.testing.assert_allclose(corners, [[2.0, 0.0], [2.0, 4.0], [0.0, 4.0], [0.0, 0.0]], atol=1e-12)
    assert box_corners(np.zeros(3), np.zeros(3), np.zeros(3), 4.0, 2.0).shape == (3, 6, 2)


def test_each_track_is_drawn_where_its_coordinates_are_in_its_legend_colour():
    tracks = straight_tracks(3, 30)
    styles = {1: "calm", 2: "normal", 3: "aggressive"}
    fig = new_figure(SMALL)
    ax = fig.add_subplot()
    draw_tracks(ax, tracks, color_by=styles, label="style", linewidth=3.0)
    ax.set_xlim(-2, 17)
    ax.set_ylim(-5, 25)
    img = figure_to_array(fig)
    colors = color_rows(tracks, styles)
    legend = dict(colors.legend)
    assert set(legend) == {"calm", "normal", "aggressive"}
    for track_id, style in styles.items():
        mid = (7.0, 10.0 * (track_id - 1))
        assert has_color_near(img, data_to_pixel(ax, mid), legend[style], radius=1, tol=10), style
    # and not between the tracks
    between = data_to_pixel(ax, (7.0, 5.0))
    for rgba in legend.values():
        assert not has_color_near(img, between, rgba, radius=2, tol=60)
    assert ax.get_legend() is not None


def test_numbers_get_a_colour_bar_and_speed_is_computed_from_vx_vy():
    tracks = straight_tracks(2, 10)
    tracks.loc[tracks.track_id == 2, "vx"] = 10.0
    colors = color_rows(tracks, "speed")
    assert colors.cmap is not None and not colors.legend
    assert colors.norm.vmin == pytest.approx(5.0) and colors.norm.vmax == pytest.approx(10.0)
    fig = draw_scene(tracks, 5, color_by="speed", size_px=SMALL)
    assert len(fig.axes) == 2  # the scene and its colour bar
    assert color_rows(tracks, "track_id").legend  # few integers: a legend


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


def test_bad_track_tables_are_rejected_with_the_reason():
    tracks = straight_tracks(2, 5)
    with pytest.raises(ValueError, match=r"lacks column\(s\) \['psi_rad'\]"):
        TrackFrames(tracks.drop(columns="psi_rad"))
    bad = tracks.copy()
    bad.loc[3, "x"] = np.nan
    with pytest.raises(ValueError, match="'x' has values that are not finite"):
        TrackFrames(bad)
    with pytest.raises(ValueError, match="appears more than once"):
        TrackFrames(pd.concat([tracks, tracks.iloc[:1]]))
    with pytest.raises(ValueError, match="no rows"):
        TrackFrames(tracks.iloc[:0])
    with pytest.raises(TypeError, match="DataFrame"):
        TrackFrames(tracks.to_numpy())
    with pytest.raises(ValueError, match="extent must be"):
        SceneView(tracks, extent=(1, 0, 0, 1))
    with pytest.raises(ValueError, match="size_px width must be an integer"):
        SceneView(tracks, size_px=(3, 200))


def test_road_lines_are_drawn_where_they_are():
    road = Road(boundaries=[[[0, -2], [20, -2]], [[0, 2], [20, 2]]], styles=["solid", "dashed"],
                centerlines=[[[0, 0], [20, 0]]])
    assert road.bounds == (0.0, -2.0, 20.0, 2.0)
    fig = new_figure(SMALL)
    ax = fig.add_subplot()
    artists = draw_road(ax, road)
    assert len(artists) == 3
    ax.set_xlim(-1, 21)
    ax.set_ylim(-5, 5)
    img = figure_to_array(fig)
    solid = to_rgb(ROAD_COLORS["solid"])  # a 1.7 px antialiased line: its pixels are a little lighter
    assert has_color_near(img, data_to_pixel(ax, (10.0, -2.0)), solid, radius=1, tol=70)
    assert not has_color_near(img, data_to_pixel(ax, (10.0, -3.5)), solid, radius=1, tol=150)
    with pytest.raises(ValueError, match=r"unknown boundary style\(s\) \['wavy'\]; allowed"):
        Road([[[0, 0], [1, 0]]], ["wavy"])
    with pytest.raises(ValueError, match="one style per boundary"):
        Road([[[0, 0], [1, 0]]], [])
    with pytest.raises(ValueError, match=r"boundaries\[0\] must be a \(P, 2\) polyline"):
        Road([[[0, 0]]], ["solid"])


@needs_sample
def test_sample_map_and_tracks_drawn_together():
    pytest.importorskip("lanelet2")
    from pirl_sim.io.interaction import read_tracks
    from pirl_sim.viz import road_from_lanelet2

    road = road_from_lanelet2(SAMPLE_MAP)
    assert len(road.boundaries) >= 3 and "dashed" in road.styles and road.centerlines
    tracks = read_tracks(SAMPLE_TRACKS)
    frame = int(tracks.frame_id.iloc[len(tracks) // 2])
    view = SceneView(tracks, road=road, trail_s=0.0, size_px=SMALL)
    img = view.render(frame)
    rows = view.frames.rows(frame)
    for x, y, rgba in zip(view.frames.x[rows], view.frames.y[rows], view.colors.rgba[rows]):
        assert has_color_near(img, data_to_pixel(view.ax, (x, y)), rgba, radius=1, tol=10)


def test_a_map_without_lanelets_is_a_clear_error(tmp_path):
    pytest.importorskip("lanelet2")
    from pirl_sim.viz import road_from_lanelet2

    osm = tmp_path / "empty.osm"
    osm.write_text('<?xml version="1.0"?>\n<osm version="0.6">\n'
                   '  <node id="1" lat="0.0" lon="0.0" />\n  <node id="2" lat="0.0" lon="0.0001" />\n'
                   '  <way id="10"><nd ref="1" /><nd ref="2" /><tag k="type" v="line_thin" /></way>\n</osm>\n')
    with pytest.raises(ValueError, match="no lanelets"):
        road_from_lanelet2(osm)
    with pytest.raises(TypeError, match="lanelet_map must be a path"):
        road_from_lanelet2(42)


_NET = """<?xml version="1.0" encoding="UTF-8"?>
<net version="1.20" junctionCornerDetail="5" limitTurnSpeed="5.50">
    <location netOffset="0.00,0.00" convBoundary="0.00,0.00,100.00,0.00" origBoundary="0.00,0.00,100.00,0.00"
              projParameter="!"/>
    <edge id="e" from="a" to="b" priority="-1">
        <lane id="e_0" index="0" speed="13.89" length="100.00" width="3.00" shape="0.00,-1.50 100.00,-1.50"/>
        <lane id="e_1" index="1" speed="13.89" length="100.00" width="3.00" shape="0.00,1.50 100.00,1.50"/>
    </edge>
    <junction id="a" type="dead_end" x="0.00" y="0.00" incLanes="" intLanes="" shape="0.00,3.00 0.00,-3.00"/>
    <junction id="b" type="dead_end" x="100.00" y="0.00" incLanes="e_0 e_1" intLanes=""
              shape="100.00,-3.00 100.00,3.00"/>
</net>
"""


def test_sumo_lanes_become_centre_lines_and_borders(tmp_path):
    pytest.importorskip("sumolib")
    from pirl_sim.viz import road_from_sumo

    net = tmp_path / "two_lanes.net.xml"
    net.write_text(_NET)
    road = road_from_sumo(net)
    assert len(road.centerlines) == 2
    # outer borders solid at y = -3 and y = 3, the border between the lanes dashed at y = 0
    ys = sorted((float(b[:, 1].mean()), s) for b, s in zip(road.boundaries, road.styles))
    assert [s for _, s in ys] == ["solid", "dashed", "solid"]
    np.testing.assert_allclose([y for y, _ in ys], [-3.0, 0.0, 3.0], atol=1e-9)
    with pytest.raises(FileNotFoundError):
        road_from_sumo(tmp_path / "missing.net.xml")


def test_highway_roundabout_road():
    pytest.importorskip("highway_env")
    from pirl_sim.scenarios.highway.network import RoundaboutGeometry

    from pirl_sim.viz import road_from_highway

    road = road_from_highway(geometry=RoundaboutGeometry(radius=20.0))
    radii = np.hypot(*np.vstack(road.centerlines).T)
    assert radii.min() == pytest.approx(20.0, abs=0.5)  # the ring's centre line
    assert {"solid", "dashed", "virtual"} >= set(road.styles)
    with pytest.raises(ValueError, match="either network or geometry"):
        road_from_highway(object(), geometry=RoundaboutGeometry())
