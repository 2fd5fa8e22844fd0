"""Property tests over random trajectories (Hypothesis)."""

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given, settings  # noqa: E402

from pirl_sim.dynamics import longitudinal, point_mass  # noqa: E402
from pirl_sim.features import lqr_features  # noqa: E402
from pirl_sim.testing import trajectories  # noqa: E402


@settings(max_examples=40, deadline=None)
@given(trajectories(longitudinal(0.2)))
def test_controls_from_states_inverts_rollout(traj):
    dyn = longitudinal(0.2)
    np.testing.assert_allclose(dyn.controls_from_states(traj.states), traj.controls, atol=1e-6 * (1 + np.abs(traj.controls).max()))


@settings(max_examples=40, deadline=None)
@given(trajectories(point_mass(0.1), min_steps=2))
def test_windows_partition_the_features(traj):
    # sum-reduced features are additive over consecutive windows
    fs = lqr_features()
    k = traj.n_steps // 2
    whole = fs.trajectory_values([traj])[0]
    parts = fs.trajectory_values([traj.window(0, k), traj.window(k)])
    np.testing.assert_allclose(parts.sum(axis=0), whole, rtol=1e-9, atol=1e-9)
