"""The compiled driver kernel (numba) against the numpy reference: random MPC problems, the dense Newton model,
the projection, a closed-loop SUMO run, reproducibility and bad input."""

import dataclasses
import functools

import numpy as np
import pytest

pytest.importorskip("numba")
pytest.importorskip("sumolib")

from pirl_sim.driving import roundabout_features  # noqa: E402
from pirl_sim.mpc import SequentialMPC  # noqa: E402
from pirl_sim.scenarios import drivers as drivers_module  # noqa: E402
from pirl_sim.scenarios.driver_kernel import CompiledDriverMPC, KernelUnsupported  # noqa: E402
from pirl_sim.scenarios.drivers import PirlDrivers, RouteSetDriverModel, RouteSetProfile, route_set_model  # noqa: E402

HORIZON = 30


def _problems(route_set, seed, m=48):
    """Random starts along every route (some outside the bounds), weights and warm starts (some on a bound)."""
    rng = np.random.default_rng(seed)
    r = rng.integers(0, route_set.n_routes, m)
    s = rng.uniform(0.0, 1.0, m) * route_set.lengths[r]
    x0 = np.column_stack([route_set.to_global(r, s), rng.uniform(-1.0, 17.0, m), rng.uniform(-5.0, 4.0, m)])
    theta = np.exp(rng.normal(0.0, 1.0, (m, 3)))
    theta[:, 2] = 1.0
    init = rng.normal(0.0, 2.0, (m, HORIZON, 1))
    init[: m // 6, 3:6] = 8.0  # warm starts on the jerk bound: straight to the bounded QPs
    return x0, theta, init


@pytest.mark.parametrize("n_iter, n_qp_iter, atol", [(1, 1, 1e-9), (3, 2, 1e-6)])
def test_plans_equal_the_numpy_mpc_on_random_problems(route_set, n_iter, n_qp_iter, atol):
    reference = route_set_model(route_set, dt=0.1, n_iter=n_iter, n_qp_iter=n_qp_iter).predictor()
    model = route_set_model(route_set, dt=0.1, n_iter=n_iter, n_qp_iter=n_qp_iter)  # its own QP counters
    kernel = CompiledDriverMPC(model, model.predictor())
    for seed in (0, 1):
        x0, theta, init = _problems(route_set, seed)
        want = reference.controls(x0, theta, HORIZON, init=init)
        got = kernel.controls(x0, theta, HORIZON, init)
        assert got.shape == want.shape == (len(x0), HORIZON, 1)
        np.testing.assert_allclose(got, want, rtol=0, atol=atol)
        assert np.abs(want).max() > 1.0  # the plans are not trivial
    # the same bounded QPs were solved (the kernel counts on its model's predictor)
    assert kernel.mpc.n_qp == reference.n_qp > 0
    assert kernel.mpc.n_infeasible == reference.n_infeasible


def _interacting_problems(route_set, seed, m=48):
    """`_problems` with the obstacles of drivers who interact: a vehicle ahead (near, far, none) and a standing
    obstacle to yield to (near or none), and five weights."""
    from pirl_sim.scenarios.leaders import NO_LEADER_GAP

    rng = np.random.default_rng(seed)
    x0, theta, init = _problems(route_set, seed, m)
    gap = np.where(rng.random(m) < 0.2, NO_LEADER_GAP, rng.uniform(-1.0, 40.0, m))
    g_y = np.where(rng.random(m) < 0.3, NO_LEADER_GAP, rng.uniform(0.0, 30.0, m))
    x0 = np.column_stack([x0, gap, rng.uniform(0.0, 12.0, m), g_y, np.zeros(m)])
    theta = np.column_stack([theta, np.exp(rng.normal(0.0, 1.5, (m, 2)))])
    return x0, theta, init


@pytest.mark.parametrize("n_iter, n_qp_iter, atol", [(1, 1, 1e-9), (3, 2, 1e-6)])
def test_interacting_plans_equal_the_numpy_mpc(route_set, n_iter, n_qp_iter, atol):
    """Drivers who interact (headway and yielding on two obstacles): the same plans as the numpy MPC on the
    seven states of `pirl_sim.dynamics.following`, and the obstacles change them."""
    reference = route_set_model(route_set, dt=0.1, n_iter=n_iter, n_qp_iter=n_qp_iter, interacting=True).predictor()
    model = route_set_model(route_set, dt=0.1, n_iter=n_iter, n_qp_iter=n_qp_iter, interacting=True)
    kernel = CompiledDriverMPC(model, model.predictor())
    assert kernel.n_obstacles == 2
    paper = route_set_model(route_set, dt=0.1, n_iter=n_iter, n_qp_iter=n_qp_iter)
    free = CompiledDriverMPC(paper, paper.predictor())
    for seed in (0, 1):
        x0, theta, init = _interacting_problems(route_set, seed)
        want = reference.controls(x0, theta, HORIZON, init=init)
        got = kernel.controls(x0, theta, HORIZON, init)
        np.testing.assert_allclose(got, want, rtol=0, atol=atol)
        alone = free.controls(x0[:, :3], theta[:, :3], HORIZON, init)
        assert np.abs(got - alone).max() > 1.0  # the obstacles matter
    assert kernel.mpc.n_qp == reference.n_qp > 0
    assert kernel.mpc.n_infeasible == reference.n_infeasible


def test_plans_are_bit_for_bit_reproducible(route_set):
    model = route_set_model(route_set, dt=0.1, n_iter=1, n_qp_iter=1)
    x0, theta, init = _problems(route_set, 2)
    a = CompiledDriverMPC(model, model.predictor()).controls(x0, theta, HORIZON, init)
    b = CompiledDriverMPC(model, model.predictor()).controls(x0, theta, HORIZON, init)
    assert np.array_equal(a, b)


@pytest.mark.parametrize("interacting", [False, True])
def test_dense_model_equals_the_numpy_newton_model(route_set, interacting):
    model = route_set_model(route_set, dt=0.1, interacting=interacting)
    mpc = model.predictor()
    kernel = CompiledDriverMPC(model, mpc)
    x0, theta, init = (_interacting_problems if interacting else _problems)(route_set, 3, m=16 if interacting else 12)
    x0 = mpc._qp.clip_start(x0)
    for m in range(len(x0)):
        A, b, _ = mpc._model(x0[m:m + 1], init[m:m + 1], theta[m:m + 1])
        H, g = kernel.model(x0[m], theta[m], init[m, :, 0])
        np.testing.assert_allclose(H, A[0], rtol=0, atol=1e-10 * np.abs(A[0]).max())
        np.testing.assert_allclose(g, b[0], rtol=0, atol=1e-10 * np.abs(b[0]).max())


def test_projection_equals_the_route_sets(route_set):
    model = route_set_model(route_set, dt=0.1)
    kernel = CompiledDriverMPC(model, model.predictor())
    rng = np.random.default_rng(4)
    r = rng.integers(0, route_set.n_routes, 200)
    s = rng.uniform(-0.02, 1.02, 200) * route_set.lengths[r]
    xy = route_set.position(route_set.to_global(r, s)) + rng.normal(0.0, 0.6, (200, 2))
    guess = s + rng.normal(0.0, 1.0, 200)
    guess[:5] = np.nan  # first positions: found by to_frenet, as in RouteSet.project
    want = route_set.project(r, xy, guess)
    got = kernel.project(r, xy, guess)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    assert (s < 0).any() and (s > route_set.lengths[r]).any()  # both straight extensions were exercised
    with pytest.raises(ValueError, match="route indices"):
        kernel.project(r[:3], xy[:2], guess[:3])
    with pytest.raises(ValueError, match="route indices must lie"):
        kernel.project(np.array([route_set.n_routes]), xy[:1], guess[:1])


def test_bad_input_and_unsupported_models(route_set):
    model = route_set_model(route_set, dt=0.1)
    kernel = CompiledDriverMPC(model, model.predictor())
    x0, theta, init = _problems(route_set, 5, m=4)
    with pytest.raises(ValueError, match="init must be finite"):
        kernel.controls(x0, theta, HORIZON, init[:, :10])
    with pytest.raises(ValueError, match="start states"):
        kernel.controls(x0[:, :2], theta, HORIZON, init)
    interacting = route_set_model(route_set, dt=0.1, interacting=True)
    with pytest.raises(ValueError, match=r"shape \(M, 7\)"):
        CompiledDriverMPC(interacting, interacting.predictor()).controls(x0, theta, HORIZON, init)
    with pytest.raises(ValueError, match="weights"):
        kernel.controls(x0, -theta, HORIZON, init)
    with pytest.raises(TypeError, match="horizon"):
        kernel.controls(x0, theta, 30.0, init)
    # another feature set: the numpy path only
    other = RouteSetDriverModel(model.dynamics, roundabout_features(RouteSetProfile(route_set), "speed-level"),
                                model.bounds, routes=route_set)
    with pytest.raises(KernelUnsupported, match="features"):
        CompiledDriverMPC(other, other.predictor())
    with pytest.raises(KernelUnsupported, match="bounds"):
        CompiledDriverMPC(model, SequentialMPC(model.dynamics, model.features, None))
    with pytest.raises(KernelUnsupported, match="own predictor"):
        CompiledDriverMPC(model, SequentialMPC(model.dynamics, other.features, model.bounds))
    with pytest.raises(ValueError, match="kernel must be"):
        PirlDrivers(model, {}, kernel="fortran")
    with pytest.raises(KernelUnsupported):
        PirlDrivers(other, {}, kernel="numba")
    assert PirlDrivers(other, {})._compiled is None  # "auto" falls back to numpy
    assert PirlDrivers(model, {})._compiled is not None
    assert PirlDrivers(model, {}, kernel="numpy")._compiled is None


@pytest.mark.parametrize("population", ["default", "interacting"])
def test_closed_loop_sumo_run_equals_the_numpy_drivers(monkeypatch, population):
    """A short SUMO run driven by the compiled kernel and by the numpy MPC: the same commands to rounding (the
    paper's drivers, and drivers who interact)."""
    pytest.importorskip("libsumo")
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, INTERACTING_POPULATION
    from pirl_sim.scenarios.sumo import SumoScenarioConfig, run_sumo_scenario
    from pirl_sim.scenarios.sumo import scenario as scenario_module

    pop = {"default": DEFAULT_POPULATION, "interacting": INTERACTING_POPULATION}[population]
    cfg = SumoScenarioConfig(population=dataclasses.replace(pop, n_vehicles=10), max_duration=40.0)
    frames = {}
    for kernel in ("numba", "numpy"):
        monkeypatch.setattr(scenario_module, "PirlDrivers", functools.partial(drivers_module.PirlDrivers, kernel=kernel))
        res = run_sumo_scenario(cfg, seed=1)
        frames[kernel] = res.sumo.frame
    a, b = frames["numba"], frames["numpy"]
    assert len(a) == len(b) > 1000
    assert list(a["vehicle_id"]) == list(b["vehicle_id"])
    cmd_a, cmd_b = a["commanded_speed"].to_numpy(float), b["commanded_speed"].to_numpy(float)
    assert np.array_equal(np.isnan(cmd_a), np.isnan(cmd_b)) and np.isfinite(cmd_a).sum() > 500
    np.testing.assert_allclose(cmd_a, cmd_b, rtol=0, atol=1e-7, equal_nan=True)
    np.testing.assert_allclose(a["speed"].to_numpy(float), b["speed"].to_numpy(float), rtol=0, atol=1e-7)
