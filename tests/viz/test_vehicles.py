"""Vehicle boxes (pirl_sim.viz.vehicles): corners oriented along the heading."""

import numpy as np

from pirl_sim.viz import box_corners


def test_box_corners_are_oriented_along_the_heading():
    corners = box_corners([1.0], [2.0], [np.pi / 2], [4.0], [2.0], nose=False)[0]
    # heading +y: the rear edge is at y = 0, the front at y = 4, the sides at x = 0 and x = 2
    np.testing.assert_allclose(corners, [[2.0, 0.0], [2.0, 4.0], [0.0, 4.0], [0.0, 0.0]], atol=1e-12)
    assert box_corners(np.zeros(3), np.zeros(3), np.zeros(3), 4.0, 2.0).shape == (3, 6, 2)
