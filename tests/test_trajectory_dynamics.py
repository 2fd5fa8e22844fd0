import numpy as np
import pytest

from pirl_sim.dynamics import LinearDynamics, constant_acceleration_positions, longitudinal, point_mass
from pirl_sim.trajectory import Trajectory, stack_trajectories


def test_trajectory_validates_shapes_and_values():
    t = Trajectory(np.zeros((4, 2)), np.zeros((3, 1)), 0.1, {"style": 1})
    assert t.n_steps == 3 and t.duration == pytest.approx(0.3)
    with pytest.raises(ValueError, match="one more state than controls"):
        Trajectory(np.zeros((3, 2)), np.zeros((3, 1)), 0.1)
    with pytest.raises(ValueError, match="at least one step"):
        Trajectory(np.zeros((1, 2)), np.zeros((0, 1)), 0.1)
    bad = np.zeros((4, 2))
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"states must be finite.*index \(2, 1\)"):
        Trajectory(bad, np.zeros((3, 1)), 0.1)
    bad[2, 1] = np.inf
    with pytest.raises(ValueError, match="finite"):
        Trajectory(bad, np.zeros((3, 1)), 0.1)
    with pytest.raises(ValueError, match="2 dimensions"):
        Trajectory(np.zeros(4), np.zeros((3, 1)), 0.1)
    with pytest.raises(ValueError, match="dt must be"):
        Trajectory(np.zeros((4, 2)), np.zeros((3, 1)), 0.0)
    with pytest.raises(TypeError, match="dt"):
        Trajectory(np.zeros((4, 2)), np.zeros((3, 1)), "0.1")
    with pytest.raises(TypeError, match="numeric"):
        Trajectory([["a", "b"]] * 4, np.zeros((3, 1)), 0.1)


def test_trajectory_is_immutable_and_windows_keep_offsets():
    t = Trajectory(np.arange(10.0).reshape(5, 2), np.ones((4, 1)), 0.1)
    with pytest.raises(ValueError):
        t.states[0, 0] = 1.0
    w = t.window(1, 3)
    assert w.n_steps == 2 and w.metadata["window_start"] == 1
    np.testing.assert_array_equal(w.states, t.states[1:4])
    assert t.window(-2).metadata["window_start"] == 2
    with pytest.raises(ValueError, match="window"):
        t.window(3, 3)


def test_stack_rejects_mixed_lengths():
    a = Trajectory(np.zeros((4, 2)), np.zeros((3, 1)), 0.1)
    b = Trajectory(np.zeros((5, 2)), np.zeros((4, 1)), 0.1)
    with pytest.raises(ValueError, match="group trajectories by length"):
        stack_trajectories([a, b])
    with pytest.raises(TypeError, match="expected a pirl_sim.Trajectory"):
        stack_trajectories([a, "b"])


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
