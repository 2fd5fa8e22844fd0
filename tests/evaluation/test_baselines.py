"""The kinematic baselines (pirl_sim.evaluation.baselines): constant velocity and constant acceleration, which
never reverses."""

import numpy as np
import pytest

from pirl_sim.evaluation.baselines import ConstantAcceleration, ConstantVelocity, KinematicModel


def test_ca_baseline_never_reverses():
    """The replay's CA along the path is the sweep's pseudo-learner (`KinematicModel`)."""
    from types import SimpleNamespace

    from pirl_sim.dynamics import longitudinal
    from pirl_sim.evaluation.baselines import KinematicModel

    x0 = np.array([
        [10.0, -0.5, -1.0],  # reversing estimate, braking: stays
        [10.0, 0.0, -2.0],   # stopped, braking: stays
        [10.0, -0.2, 0.0],   # reversing estimate, no acceleration: stays
        [10.0, 2.0, -1.0],   # braking: stops after 2 s at 12 m
        [10.0, -0.2, 1.0],   # starting from standstill
        [10.0, 5.0, 0.5],    # accelerating
    ])
    model = SimpleNamespace(dynamics=longitudinal(0.2), features=None)  # (s, v, a) states at dt 0.2 s
    s = KinematicModel(model, "ca").predict_states(x0, None, 15)[:, 1:, 0]
    t = 0.2 * np.arange(1, 16)
    np.testing.assert_allclose(s[0], 10.0)
    np.testing.assert_allclose(s[1], 10.0)
    np.testing.assert_allclose(s[2], 10.0)
    np.testing.assert_allclose(s[3], 10.0 + 2.0 * np.minimum(t, 2.0) - 0.5 * np.minimum(t, 2.0) ** 2)
    np.testing.assert_allclose(s[4], 10.0 + 0.5 * t**2)
    np.testing.assert_allclose(s[5], 10.0 + 5.0 * t + 0.25 * t**2)
    assert np.all(np.diff(np.column_stack([x0[:, :1], s]), axis=1) >= 0)


def test_baselines_predict_constant_velocity_and_acceleration():
    from pirl_sim.driving import roundabout_model
    from pirl_sim.paths import ReferencePath

    path = ReferencePath.from_polyline(np.c_[np.linspace(0, 200, 50), np.zeros(50)])
    model = roundabout_model(path, dt=0.5)
    x0 = np.array([[10.0, 8.0, -2.0], [0.0, 5.0, 1.0]])
    cv = KinematicModel(model, "cv").predict_states(x0, None, 4)
    np.testing.assert_allclose(cv[:, :, 0], [[10, 14, 18, 22, 26], [0, 2.5, 5, 7.5, 10]])
    np.testing.assert_allclose(cv[:, 1:, 2], 0.0)
    ca = KinematicModel(model, "ca").predict_states(x0, None, 12)
    # braking at 2 m/s^2 from 8 m/s stops after 4 s (8 steps) at 10 + 16 m, and stays there
    np.testing.assert_allclose(ca[0, 8:, 0], 26.0)
    np.testing.assert_allclose(ca[0, 8:, 1], 0.0)
    np.testing.assert_allclose(ca[0, 2, :2], [10 + 8 * 1.0 - 1.0, 6.0])
    np.testing.assert_allclose(ca[1, 4, 0], 5.0 * 2 + 0.5 * 2**2)
    assert ConstantVelocity(model=model).fit().infer_weights([]).shape == (0, 3)
    from pirl_sim.model import synthetic_model

    with pytest.raises(ValueError, match="needs an acceleration"):
        ConstantAcceleration(model=synthetic_model()).fit()
