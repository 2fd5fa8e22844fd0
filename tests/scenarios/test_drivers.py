"""PIRL drivers (pirl_sim.scenarios.drivers): one model for every route, real-time iteration near the converged MPC,
the batched controller, the standstill hand-back, bad input."""

from types import MappingProxyType

import numpy as np
import pytest

pytest.importorskip("sumolib")

from pirl_sim.driving import roundabout_model  # noqa: E402
from pirl_sim.scenarios.drivers import PirlDrivers, RouteSet, route_set_model  # noqa: E402
from pirl_sim.scenarios.sumo import Observation, VehicleState  # noqa: E402
from pirl_sim.trajectory import Trajectory  # noqa: E402


STYLES = np.array([[3.0, 0.3, 1.0], [0.1, 3.0, 1.0], [0.3, 0.3, 1.0]])  # the paper's three, normalised
# route_set: the scenarios' default paths on one axis (a fixture of tests/conftest.py)


def test_one_model_for_all_routes_gives_each_routes_features(route_set):
    """Learning across routes: features on the global axis equal those of each route's own model."""
    route_set = RouteSet(route_set.route_ids, route_set.paths)  # the paths' own curvature, as roundabout_model
    model = route_set_model(route_set, dt=0.1)
    for r in (0, 5, 11):
        own = roundabout_model(route_set.paths[r], dt=0.1)
        x0 = np.array([[15.0, 12.0, 0.0]])
        U = own.predictor().controls(x0, STYLES[r % 3], 40)
        X = own.dynamics.rollout(x0[0], U[0])
        Xg = X.copy()
        Xg[:, 0] += route_set.offsets[r]
        np.testing.assert_allclose(model.feature_values([Trajectory(Xg, U[0], 0.1)]),
                                   own.feature_values([Trajectory(X, U[0], 0.1)]), rtol=1e-9)
        np.testing.assert_allclose(model.positions(Xg), own.positions(X), atol=1e-9)


def _closed_loop(route_set, rid, n_iter, n_qp_iter, n_steps=180):
    r = route_set.index(rid)
    state = np.tile([route_set.offsets[r] + 5.0, 13.9, 0.0], (3, 1))
    model = route_set_model(route_set, dt=0.1, n_iter=n_iter, n_qp_iter=n_qp_iter)
    mpc, plan, xs = model.predictor(), None, []
    for _ in range(n_steps):
        init = None if plan is None else np.concatenate([plan[:, 1:], plan[:, -1:]], axis=1)
        plan = mpc.controls(state, STYLES, 30, init=init)
        state = state @ model.dynamics.A.T + plan[:, 0] @ model.dynamics.B.T
        xs.append(state)
    return np.array(xs)


def test_real_time_iteration_stays_near_the_converged_mpc(route_set):
    """The drivers' default (one Newton step and one bounded QP per re-plan, warm-started) and three of
    each against a converged MPC, closed loop for the three styles, on a route with the largest gaps
    (through routes: 0.066 and 0.038 m/s measured)."""
    rid = "arm0_to_arm2"
    converged = _closed_loop(route_set, rid, 30, 10)
    rti = _closed_loop(route_set, rid, 1, 1)
    three = _closed_loop(route_set, rid, 3, 3)
    gap_rti = np.abs(rti[..., 1] - converged[..., 1]).max()
    gap_three = np.abs(three[..., 1] - converged[..., 1]).max()
    print(f"max speed gap to a converged MPC: one iteration {gap_rti:.3f} m/s, three {gap_three:.3f} m/s")
    assert gap_rti < 0.1 and gap_three < 0.05
    r = route_set.index(rid)
    assert np.all(rti[-1, :, 0] > route_set.offsets[r] + 150.0)  # nobody stopped


def _obs(vid, x, y, speed, accel=0.0, t=1.0):
    st = VehicleState(x=x, y=y, x_front=x, y_front=y, psi_rad=0.0, speed=speed, accel=accel, length=5.0,
                      width=1.8, edge_id="e", lane_id="e_0", lane_pos=0.0)
    return Observation(time=t, vehicle_id=vid, ego=st, others=MappingProxyType({}), leader=None,
                       route_edges=("e",))


def test_batched_commands_equal_one_vehicle_at_a_time(route_set):
    ids = ["arm0_to_arm1", "arm1_to_arm3", "arm2_to_arm0", "arm3_to_arm2"]
    drivers = {f"v{k}": (rid, STYLES[k % 3]) for k, rid in enumerate(ids)}
    model = route_set_model(route_set, dt=0.1, n_iter=1, n_qp_iter=1)
    batch = PirlDrivers(model, drivers)
    single = PirlDrivers(route_set_model(route_set, dt=0.1, n_iter=1, n_qp_iter=1), drivers)
    for step, s in enumerate((40.0, 41.3, 42.6)):
        obs = {}
        for k, rid in enumerate(ids):
            p = route_set.path(rid)
            x, y = p.position(s + 3 * k)
            obs[f"v{k}"] = _obs(f"v{k}", float(x), float(y), 12.0 - k, t=0.1 * (step + 1))
        got = batch.commands(0.1 * (step + 1), MappingProxyType(obs))
        for vid, o in obs.items():
            assert single(0.1 * (step + 1), vid, o) == pytest.approx(got[vid], abs=1e-9)
    assert batch.n_calls == 3 and batch.n_plans == 12 and single.n_calls == 12
    assert all(0.0 <= v < 14.0 for v in got.values())


def test_standstill_hand_back(route_set):
    p = route_set.path("arm0_to_arm2")
    x, y = (float(c) for c in p.position(60.0))
    drv = PirlDrivers(route_set_model(route_set, n_iter=1, n_qp_iter=1), {"v": ("arm0_to_arm2", STYLES[1])},
                      stop_speed=0.5, resume_speed=3.0)
    assert isinstance(drv.commands(0.1, {"v": _obs("v", x, y, 8.0)})["v"], float)
    assert drv.commands(0.2, {"v": _obs("v", x, y, 0.2)})["v"] is None  # SUMO stopped it: SUMO drives
    assert drv.commands(0.3, {"v": _obs("v", x, y, 2.5)})["v"] is None  # not yet back above 3 m/s
    cmd = drv.commands(0.4, {"v": _obs("v", x, y, 3.2)})["v"]
    assert isinstance(cmd, float) and cmd > 0
    assert drv.handbacks == {"v": 1}


def test_controller_rejects_bad_input(route_set):
    model = route_set_model(route_set)
    with pytest.raises(ValueError, match="unknown route"):
        PirlDrivers(model, {"v": ("nowhere", STYLES[0])})
    with pytest.raises(ValueError, match="positive weights"):
        PirlDrivers(model, {"v": ("arm0_to_arm1", np.array([1.0, -1.0, 1.0]))})
    with pytest.raises(TypeError, match="rng"):
        PirlDrivers(model, {}, control_noise=0.1)
    with pytest.raises(ValueError, match="stop_speed <= resume_speed"):
        PirlDrivers(model, {}, stop_speed=4.0, resume_speed=3.0)
    drv = PirlDrivers(model, {})
    with pytest.raises(ValueError, match="no PIRL driver"):
        drv.commands(0.1, {"w": _obs("w", 0.0, 0.0, 5.0)})


def _frame(route_set, rid, cars):
    """A Frame of cars (id, arc length [m], speed [m/s]) on route ``rid``, heading along it."""
    from pirl_sim.scenarios.contract import Frame

    p = route_set.path(rid)
    xy = np.array([p.position(s) for _, s, _ in cars], dtype=float)
    ahead = np.array([p.position(s + 0.5) for _, s, _ in cars], dtype=float)
    psi = np.arctan2(ahead[:, 1] - xy[:, 1], ahead[:, 0] - xy[:, 0])
    return Frame(tuple(c[0] for c in cars), xy, psi, np.array([c[2] for c in cars]), np.full(len(cars), 5.0),
                 (rid,) * len(cars))


def test_drivers_who_weigh_headway_brake_for_the_car_ahead_by_their_weight(route_set):
    """A car 25 m behind a stopped one: the larger its headway weight, the harder it slows now; with nobody
    ahead the weight changes nothing. Without the step's frame such drivers refuse to plan."""
    rid = "arm0_to_arm2"
    model = route_set_model(route_set, dt=0.1, n_iter=10, n_qp_iter=4, interacting=True)
    assert model.dynamics.n_x == 7 and model.features.names[-2:] == ("headway", "yielding")
    p = route_set.path(rid)
    x, y = (float(c) for c in p.position(40.0))
    cmds = {}
    for w in (0.1, 10.0):
        drv = PirlDrivers(model, {"v": (rid, np.array([1.0, 0.3, 1.0, w, 1.0]))}, kernel="numpy")
        assert drv.needs_frame
        with pytest.raises(ValueError, match="need the step's frame"):
            drv.commands(0.1, {"v": _obs("v", x, y, 10.0)})
        cmds[w] = drv.commands(0.1, {"v": _obs("v", x, y, 10.0)},
                               frame=_frame(route_set, rid, [("v", 40.0, 10.0), ("stopped", 70.0, 0.0)]))["v"]
        alone = PirlDrivers(model, {"v": (rid, np.array([1.0, 0.3, 1.0, w, 1.0]))}, kernel="numpy").commands(
            0.1, {"v": _obs("v", x, y, 10.0)}, frame=_frame(route_set, rid, [("v", 40.0, 10.0)]))["v"]
        cmds[w, "alone"] = alone
    assert cmds[10.0] < cmds[0.1] - 0.01
    assert cmds[10.0, "alone"] == pytest.approx(cmds[0.1, "alone"], abs=1e-6)
    with pytest.raises(ValueError, match="not in the step's frame"):
        PirlDrivers(model, {"v": (rid, np.array([1.0, 0.3, 1.0, 1.0, 1.0]))}, kernel="numpy").commands(
            0.1, {"v": _obs("v", x, y, 10.0)}, frame=_frame(route_set, rid, [("other", 40.0, 10.0)]))
