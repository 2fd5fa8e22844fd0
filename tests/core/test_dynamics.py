"""Linear dynamics (pirl_sim.dynamics): rollout and its inverse (also as a hypothesis property), the longitudinal
chain, steering, constant acceleration and the following dynamics."""

import numpy as np
import pytest

from pirl_sim.dynamics import LinearDynamics, constant_acceleration_positions, longitudinal, point_mass

pytest.importorskip("hypothesis")

from hypothesis import given, settings  # noqa: E402

from pirl_sim.testing import trajectories  # noqa: E402


@pytest.mark.parametrize("dyn", [point_mass(0.1), longitudinal(0.2), longitudinal(0.1)])
def test_rollout_matches_step_by_step_and_inverts(dyn, rng):
    x0 = rng.normal(size=(3, dyn.n_x))
    U = rng.normal(size=(3, 7, dyn.n_u))
    X = dyn.rollout(x0, U)
    x = x0.copy()
    for k in range(7):
        x = x @ dyn.A.T + U[:, k] @ dyn.B.T
        np.testing.assert_allclose(X[:, k + 1], x, atol=1e-12)
    np.testing.assert_allclose(dyn.residual(X, U), 0.0, atol=1e-12)
    np.testing.assert_allclose(dyn.controls_from_states(X), U, atol=1e-9)


def test_longitudinal_is_exact_for_constant_jerk():
    dyn = longitudinal(0.2)
    j = 0.7
    X = dyn.rollout(np.array([1.0, 2.0, 0.3]), np.full((10, 1), j))
    t = 2.0
    assert X[-1, 0] == pytest.approx(1.0 + 2.0 * t + 0.3 * t**2 / 2 + j * t**3 / 6)
    assert X[-1, 1] == pytest.approx(2.0 + 0.3 * t + j * t**2 / 2)


def test_dynamics_validation():
    with pytest.raises(ValueError, match="A must have shape"):
        LinearDynamics(np.eye(3), np.ones((2, 1)), 0.1, ("p", "v"), ("a",))
    with pytest.raises(ValueError, match="dt must be"):
        LinearDynamics(np.eye(2), np.ones((2, 1)), -1.0, ("p", "v"), ("a",))


def test_steer_keeps_the_start_and_follows_the_targets():
    """`LinearDynamics.steer`: from a start it cannot change, the controls that follow target states best."""
    dyn = longitudinal(0.2)
    rng = np.random.default_rng(0)
    x0 = np.array([3.0, 6.0, 0.4])
    U = rng.normal(scale=0.5, size=(15, 1))
    truth = dyn.rollout(x0, U)
    states, controls = dyn.steer(x0, truth[1:], [1.0, 1.0, 0.0], ridge=1e-10)  # reachable: recovered
    np.testing.assert_allclose(states, truth, atol=1e-4)
    np.testing.assert_allclose(controls, U, atol=1e-2)
    moved = x0 + np.array([0.0, 0.4, -0.8])  # another estimate of the start: kept, and the positions followed
    states, controls = dyn.steer(moved, truth[1:], [1.0, 1.0, 0.0])
    np.testing.assert_array_equal(states[0], moved)
    np.testing.assert_allclose(dyn.rollout(moved, controls), states)
    assert np.abs(states[1:, 0] - truth[1:, 0]).mean() < 0.1
    # the same start and targets without the correction drift away: CA from the moved start
    drift = dyn.rollout(moved, np.zeros_like(U))
    assert np.abs(drift[1:, 0] - truth[1:, 0]).mean() > 0.5
    # a NaN where the weight is 0 is ignored
    masked = truth[1:].copy()
    masked[:, 2] = np.nan
    np.testing.assert_allclose(dyn.steer(x0, masked, [1.0, 1.0, 0.0])[0], dyn.steer(x0, truth[1:], [1.0, 1.0, 0.0])[0])


@pytest.mark.parametrize("args, match", [
    (dict(x0=np.zeros(2)), "expected x0"),
    (dict(targets=np.zeros((0, 3))), "expected x0"),
    (dict(weights=[1.0, -1.0, 0.0]), "weights must be"),
    (dict(weights=[0.0, 0.0, 0.0]), "weights must be"),
    (dict(weights=[1.0, 1.0]), "weights must be"),
    (dict(ridge=0.0), "ridge must be"),
    (dict(ridge=np.nan), "ridge must be"),
    (dict(targets=np.full((5, 3), np.nan)), "must be finite"),
])
def test_steer_rejects_bad_input(args, match):
    dyn = longitudinal(0.2)
    kw = {**dict(x0=np.zeros(3), targets=np.zeros((5, 3)), weights=[1.0, 1.0, 0.0], ridge=1e-2), **args}
    with pytest.raises(ValueError, match=match):
        dyn.steer(kw["x0"], kw["targets"], kw["weights"], kw["ridge"])


def test_constant_acceleration_positions_hold_the_acceleration_until_a_stop_and_read_states_by_name():
    """Along a path (s, v, a): s0 + v t + a t^2 / 2 until a braking start stops; a point mass (p, v) has no
    acceleration, so its base is constant speed."""
    x0 = np.array([[10.0, 5.0, 1.0], [0.0, 4.0, -2.0]])
    got = constant_acceleration_positions(longitudinal(0.5), x0, 6)
    t = 0.5 * np.arange(1, 7)
    np.testing.assert_allclose(got[0], 10 + 5 * t + 0.5 * t**2)
    tc = np.minimum(t, 2.0)  # 4 m/s at -2 m/s^2 stops after 2 s, 4 m on
    np.testing.assert_allclose(got[1], 4 * tc - tc**2)
    np.testing.assert_allclose(constant_acceleration_positions(point_mass(0.1), [[1.0, 2.0]], 3),
                               [[1.2, 1.4, 1.6]])


@settings(max_examples=40, deadline=None)
@given(trajectories(longitudinal(0.2)))
def test_controls_from_states_inverts_rollout(traj):
    dyn = longitudinal(0.2)
    np.testing.assert_allclose(dyn.controls_from_states(traj.states), traj.controls, atol=1e-6 * (1 + np.abs(traj.controls).max()))


def test_following_dynamics_close_the_gap_by_what_the_car_drives():
    from pirl_sim.dynamics import following

    dyn = following(0.2)
    x0 = np.array([3.0, 5.0, 1.0, 20.0, 4.0])
    xs = dyn.rollout(x0, np.array([[2.0], [-1.0], [0.5]]))
    lon = xs[:, :3]
    np.testing.assert_allclose(xs[:, 3], 20.0 + 4.0 * 0.2 * np.arange(4) - (lon[:, 0] - 3.0))
    np.testing.assert_allclose(xs[:, 4], 4.0)
