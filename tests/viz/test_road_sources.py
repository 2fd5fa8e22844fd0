"""Roads from Lanelet2 maps, SUMO networks and highway-env (pirl_sim.viz.road_sources)."""

import numpy as np
import pytest

from pirl_sim.viz import SceneView, data_to_pixel

from viz_testdata import SAMPLE_MAP, SAMPLE_TRACKS, has_color_near, needs_sample


SMALL = (320, 240)


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
