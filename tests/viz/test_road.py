"""Roads (pirl_sim.viz.road): lines drawn where they are."""

import pytest
from matplotlib.colors import to_rgb

from pirl_sim.viz import Road, data_to_pixel, draw_road, figure_to_array, new_figure
from pirl_sim.viz.road import ROAD_COLORS

from viz_testdata import has_color_near


SMALL = (320, 240)


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
