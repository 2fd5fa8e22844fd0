"""Statistics of the tables (pirl_sim.evaluation.stats): the 95 % interval is Student's t half-width."""

import numpy as np
import pytest


def test_ci95_is_the_student_t_half_width():
    from pirl_sim.evaluation.stats import ci95

    assert np.isnan(ci95([1.0])) and np.isnan(ci95([]))
    # n = 3, sd = 1: t(0.975, 2) = 4.3027 -> 4.3027 / sqrt(3)
    assert ci95([1.0, 2.0, 3.0]) == pytest.approx(4.302653 / np.sqrt(3), rel=1e-5)
    assert ci95([1.0, np.nan, 3.0, 2.0]) == pytest.approx(4.302653 / np.sqrt(3), rel=1e-5)
