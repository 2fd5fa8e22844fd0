"""pirl_sim.viz.LiveView: a road drawn once, vehicles redrawn at each call."""

import numpy as np
import pytest

from pirl_sim.viz import LiveView, Road, data_to_pixel

from viz_testdata import has_color_near


def _road():
    x = np.linspace(0.0, 100.0, 11)
    return Road((np.column_stack([x, np.full_like(x, -2.0)]), np.column_stack([x, np.full_like(x, 2.0)])),
                ("solid", "solid"), (np.column_stack([x, np.zeros_like(x)]),))


def test_each_vehicle_is_drawn_in_its_colour_where_it_is_and_moves_with_it():
    view = LiveView(_road(), size_px=(400, 200))
    red, blue = (0.9, 0.1, 0.1), (0.1, 0.2, 0.9)
    first = view.render([20.0, 70.0], [0.0, 0.0], [0.0, np.pi], [5.0, 5.0], [2.0, 2.0], [red, blue], time=1.0)
    assert first.shape == (200, 400, 3) and first.dtype == np.uint8
    for x, rgb in ((20.0, red), (70.0, blue)):
        assert has_color_near(first, data_to_pixel(view.ax, (x, 0.0)), np.array(rgb) * 255)
    moved = view.render([40.0], [0.0], [0.0], [5.0], [2.0], [red], time=2.0)
    assert has_color_near(moved, data_to_pixel(view.ax, (40.0, 0.0)), np.array(red) * 255)
    assert not has_color_near(moved, data_to_pixel(view.ax, (20.0, 0.0)), np.array(red) * 255, radius=1)
    assert not has_color_near(moved, data_to_pixel(view.ax, (70.0, 0.0)), np.array(blue) * 255, radius=1)


def test_a_road_is_required():
    with pytest.raises(TypeError, match="road must be a pirl_sim.viz.Road"):
        LiveView("map.osm")
