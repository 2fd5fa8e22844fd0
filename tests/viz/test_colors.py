"""Colours (pirl_sim.viz.colors): distinct colours stay apart."""

import itertools

import numpy as np
import pytest

from pirl_sim.viz import distinct_colors


def test_distinct_colours_stay_apart():
    for k in (1, 2, 10, 19, 20, 40):
        rgb = distinct_colors(k)[:, :3] * 255
        assert rgb.shape == (k, 3)
        gaps = [np.linalg.norm(a - b) for a, b in itertools.combinations(rgb, 2)]
        assert min(gaps, default=np.inf) > (60 if k <= 19 else 15)
    with pytest.raises(ValueError, match="k must be a positive integer, got 0"):
        distinct_colors(0)
