"""The desired-speed fit (pirl_sim.speed_fit): a_lat and v_max recovered despite braking outliers."""

import numpy as np
import pytest

from pirl_sim.driving import smooth_desired_speed
from pirl_sim.speed_fit import fit_desired_speed


def test_desired_speed_fit_recovers_a_lat_and_v_max_despite_braking_outliers():
    rng = np.random.default_rng(0)
    kappa = rng.uniform(0.0, 0.12, 4000)
    v = smooth_desired_speed(kappa, 2.5, 11.0)[0] + rng.normal(0.0, 0.3, kappa.size)
    slow = rng.random(kappa.size) < 0.15  # braking to yield: far below the desired speed
    v[slow] = rng.uniform(1.0, 3.0, slow.sum())
    fit = fit_desired_speed(kappa, v)
    assert fit.a_lat == pytest.approx(2.5, rel=0.05) and fit.v_max == pytest.approx(11.0, rel=0.03)
    assert fit.converged and not fit.at_bound and fit.n_samples == int((v >= 1.0).sum())
    with pytest.raises(ValueError, match="same shape"):
        fit_desired_speed(kappa, v[:-1])
    with pytest.raises(ValueError, match="at least 10 samples"):
        fit_desired_speed(kappa[:5], v[:5])
