"""Rasters (pirl_sim.viz.raster): figures to RGB arrays and data to pixels."""

import numpy as np

from pirl_sim.viz import data_to_pixel, figure_to_array, new_figure


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
