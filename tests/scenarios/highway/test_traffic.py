"""The highway-env roundabout's traffic: IDM, vehicle dynamics, leaders, yielding, crashes, the shared plan."""

import math

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("highway_env")

from pirl_sim.scenarios.planning import PLAN_COLUMNS, plan_population  # noqa: E402
from pirl_sim.scenarios.highway.scenario import ROUTE_IDS, HighwayScenarioConfig, build_routes  # noqa: E402
from pirl_sim.scenarios.highway.traffic import (  # noqa: E402
    IDM_A_MAX,
    IDM_S0,
    IDM_T,
    STEP_LENGTH,
    DriverConfig,
    RoundaboutTraffic,
    TrafficRules,
    idm_acceleration,
)
from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, population_from_dict  # noqa: E402
from pirl_sim.scenarios.sumo.scenario import SumoScenarioConfig, plan_vehicles  # noqa: E402

THETA = {"tracks desired speed": (3.0, 0.3, 1.0)}


@pytest.fixture(scope="module")
def road():
    return build_routes(HighwayScenarioConfig())


def make_plan(rows):
    """A plan from (vehicle_id, depart, route_id, is_pirl) tuples; PIRL drivers 'track desired speed'."""
    data = []
    for vid, depart, rid, is_pirl in rows:
        th = THETA["tracks desired speed"] if is_pirl else (np.nan,) * 3
        data.append((vid, float(depart), rid, is_pirl, 0 if is_pirl else -1,
                     "tracks desired speed" if is_pirl else "background", *th))
    return pd.DataFrame(data, columns=list(PLAN_COLUMNS))


def make_traffic(road, rows=(), rules=None, seed=0):
    net, catalogue, routes = road
    return RoundaboutTraffic(net, catalogue, routes, make_plan(rows), drivers=DriverConfig(),
                             rules=rules or TrafficRules(), noise_rng=np.random.default_rng(seed),
                             behaviour_rng=np.random.default_rng(seed))


def run(traffic, seconds):
    for _ in range(round(seconds / STEP_LENGTH)):
        traffic.act()
        traffic.step(STEP_LENGTH)


# ----------------------------------------------------------------------------------------------

def test_idm_has_highway_envs_physics():
    assert idm_acceleration(10.0, 10.0) == pytest.approx(0.0)
    assert idm_acceleration(0.0, 10.0) == pytest.approx(IDM_A_MAX)
    # steady following: same speed, the gap where the interaction balances the free-road term
    v, v0, delta = 5.0, 10.0, 4.0
    gap = (IDM_S0 + v * IDM_T) / math.sqrt(1.0 - (v / v0) ** delta)
    assert idm_acceleration(v, v0, gap, v, delta=delta) == pytest.approx(0.0, abs=1e-12)
    # the limit an obstacle imposes (no free-road term) is a_max (1 - (s*/gap)^2)
    assert idm_acceleration(v, v0, 2 * (IDM_S0 + v * IDM_T), v, free=False) == pytest.approx(0.75 * IDM_A_MAX)


def test_vehicles_move_by_the_mean_speed_of_the_step_and_never_reverse(road):
    traffic = make_traffic(road)
    v = traffic.add_vehicle("background", "b", "arm0_to_arm2", 20.0, 5.0)
    v.act()  # steering on the straight access lane: 0
    v.action["acceleration"] = 2.0
    x0 = v.route_s
    v.step(STEP_LENGTH)
    assert v.speed == pytest.approx(5.2)
    assert v.route_s - x0 == pytest.approx(0.5 * (5.0 + 5.2) * STEP_LENGTH, rel=1e-9)
    v.speed = 0.2
    v.action["acceleration"] = -6.0
    x0 = v.route_s
    v.step(STEP_LENGTH)
    assert v.speed == 0.0
    assert v.route_s - x0 == pytest.approx(0.2**2 / (2 * 6.0), rel=1e-9)
    assert v.applied_acceleration == pytest.approx(-2.0)


def test_steering_is_highway_envs_lane_following(road):
    """The vehicles' scalar steering equals highway-env's ControlledVehicle.steering_control on every
    route lane, off-centre, misaligned, slow (not_zero), and towards the next lane."""
    from highway_env.vehicle.controller import ControlledVehicle

    traffic = make_traffic(road)
    rng = np.random.default_rng(3)
    n = 0
    for rid in ROUTE_IDS:
        route = traffic.routes[rid]
        for s in np.linspace(1.0, route.length - 1.0, 15):
            v = traffic.add_vehicle("background", f"v{n}", rid, float(s), float(rng.uniform(0.0, 15.0)))
            v.position = v.position + rng.normal(0.0, 0.8, 2)
            v.heading += float(rng.normal(0.0, 0.3))
            if n % 7 == 0:
                v.speed = float(rng.uniform(-0.01, 0.01))
            v.on_state_update()
            for target in {v.lane_index, route.lanes[min(v.route_pos + 1, len(route.lanes) - 1)]}:
                assert v.steering_control(target) == pytest.approx(
                    ControlledVehicle.steering_control(v, target), abs=1e-12)
            n += 1


def test_a_leader_is_found_across_ring_lane_segments(road):
    traffic = make_traffic(road)
    route = traffic.routes["arm0_to_arm2"]
    k = route.position_of[("se", "ex")]
    end = route.offsets[k] + route.lengths[k]
    follower = traffic.add_vehicle("background", "f", "arm0_to_arm2", end - 6.0, 5.0)
    leader = traffic.add_vehicle("background", "l", "arm0_to_arm2", end + 10.0, 0.0)
    assert follower.lane_index != leader.lane_index  # different ring segments
    gap, v_lead = traffic._leader(follower, traffic.vehicles)
    assert gap == pytest.approx(16.0 - 5.0, abs=1e-6)
    assert v_lead == 0.0


def _leader_by_brute_force(traffic, v, others):
    """The leader definition, checked against every other vehicle (the reference of the indexed search)."""
    route, best_d, best = v.route_lanes, traffic.rules.lookahead, None
    for o in others:
        if o is v:
            continue
        m = route.position_of.get(o.lane_index[:2])
        if m is not None and m >= v.route_pos:
            d = route.offsets[m] + o.lane_s - v.route_s
            if 0.0 < d < best_d:
                best_d, best = d, o
        if o.committed and o.entering:
            m = route.start_pos.get(o.route_lanes.merge_node)
            if m is not None and m > v.route_pos:
                d = route.offsets[m] - o.merge_distance - v.route_s
                if 0.0 < d < best_d:
                    best_d, best = d, o
    for m in range(v.route_pos, len(route.lanes) - 1):  # the first diverge ahead: ring cars just past its node
        a, b = route.lanes[m][:2]
        ring_on = [(b, c) for c in traffic.network.graph.get(b, {}) if len(b) == 2 and len(c) == 2]
        if len(a) == 2 and ring_on and ring_on[0] != route.lanes[m + 1][:2]:
            for o in others:
                if o is not v and o.lane_index[:2] == ring_on[0] and o.lane_s - 0.5 * o.LENGTH <= v.LENGTH:
                    d = route.offsets[m + 1] + o.lane_s - v.route_s
                    if 0.0 < d < best_d:
                        best_d, best = d, o
            break
    return (None, 0.0) if best is None else (best_d - 0.5 * (v.LENGTH + best.LENGTH), best.speed)


def test_leader_search_equals_checking_every_vehicle(road):
    population = population_from_dict({**DEFAULT_POPULATION.to_dict(), "n_vehicles": 40, "depart_interval": 1.0})
    net, catalogue, routes = road
    traffic = RoundaboutTraffic(net, catalogue, routes, plan_population(population, ROUTE_IDS, 5),
                                drivers=DriverConfig(), rules=TrafficRules(), noise_rng=np.random.default_rng(5),
                                behaviour_rng=np.random.default_rng(5))
    traffic.insert_due()
    n_checked = n_led = 0
    for _ in range(300):
        traffic.act()
        traffic.step(STEP_LENGTH)
        others = traffic.vehicles
        occupancy = traffic._occupancy(others)
        for v in others:
            expected = _leader_by_brute_force(traffic, v, others)
            assert traffic._leader(v, others, occupancy) == pytest.approx(expected)
            n_checked += 1
            n_led += expected[0] is not None
    assert n_checked > 1000 and n_led > 300  # busy enough to mean something


def test_stop_line_keeps_a_waiting_vehicle_clear_of_the_ring(road):
    traffic = make_traffic(road)
    net = road[0]
    route = traffic.routes["arm0_to_arm2"]
    offset = traffic._stop_offset_of(route)
    assert 1.0 < offset < 5.0
    entry = net.get_lane(route.lanes[route.entry_lane])
    ring = [net.get_lane(("sx", "se", 0)), net.get_lane(("se", "ex", 0))]
    sc = entry.length - offset - 2.5  # the centre of a vehicle whose front is at the stop line
    c, h = entry.position(sc, 0.0), entry.heading_at(sc)
    d, n = np.array([np.cos(h), np.sin(h)]), np.array([-np.sin(h), np.cos(h)])
    corners = [c + a * 2.5 * d + b * 1.0 * n for a in (-1, 1) for b in (-1, 1)]
    assert min(abs(lane.local_coordinates(p)[1]) for lane in ring for p in corners) >= 1.0 + 0.75


def test_an_entering_driver_yields_to_the_ring_and_is_flagged_interacted(road):
    """Ring vehicle 25 m before the south entry at 6 m/s; a PIRL driver 30 m before it at 7 m/s, both
    ~4 s away: the entering driver waits, enters after the ring vehicle, nobody crashes."""
    rows = [("ring", 0.0, "arm3_to_arm1", False), ("entering", 0.0, "arm0_to_arm2", True)]
    times = {}
    for with_ring in (True, False):
        traffic = make_traffic(road, rows)
        traffic._pending = []
        route_e = traffic.routes["arm0_to_arm2"]
        route_r = traffic.routes["arm3_to_arm1"]
        node_r = route_r.offsets[route_r.start_pos["se"]]
        if with_ring:
            ring = traffic.add_vehicle("background", "ring", "arm3_to_arm1", node_r - 25.0, 6.0)
            ring.speed_factor = 1.0
        entering = traffic.add_vehicle("pirl", "entering", "arm0_to_arm2", route_e.merge_s - 30.0, 7.0,
                                       style=0, style_name="tracks desired speed",
                                       theta=np.array(THETA["tracks desired speed"]))
        passed = {}
        for _ in range(150):
            traffic.act()
            traffic.step(STEP_LENGTH)
            if "entering" not in passed and entering.merge_distance < 0:
                passed["entering"] = traffic.time
            if with_ring and "ring" not in passed and ring.route_s > node_r:
                passed["ring"] = traffic.time
        summary = traffic.summary().set_index("vehicle_id")
        assert not summary["collided"].any()
        times[with_ring] = (passed, summary.loc["entering"])
    passed, entering = times[True]
    assert passed["ring"] < passed["entering"]
    assert entering["n_overridden"] > 0  # yielding overrode the driver's own plan: an interaction
    alone_passed, alone = times[False]
    assert alone["n_overridden"] == 0 and not alone["handed_back"]
    assert alone_passed["entering"] < passed["entering"]


@pytest.mark.parametrize("delay", [1.0, None])
def test_crashes_are_recorded_and_crashed_vehicles_removed_after_the_delay(road, delay):
    traffic = make_traffic(road, rules=TrafficRules(crash_removal_delay=delay))
    a = traffic.add_vehicle("background", "a", "arm0_to_arm1", 50.0, 8.0)
    b = traffic.add_vehicle("background", "b", "arm0_to_arm2", 52.0, 2.0)  # 2 m ahead: overlapping
    traffic.add_vehicle("background", "c", "arm2_to_arm0", 10.0, 8.0)  # far away, unaffected
    run(traffic, 3.0)
    summary = traffic.summary().set_index("vehicle_id")
    assert summary.loc["a", "collided"] and summary.loc["b", "collided"] and not summary.loc["c", "collided"]
    on_road = {v.vehicle_id for v in traffic.vehicles}
    if delay is None:
        assert {"a", "b"} <= on_road and a.speed < 1.0 and b.crashed  # highway-env brakes crashed vehicles
        assert summary.loc["a", "status"] == "running"
    else:
        assert not {"a", "b"} & on_road
        assert summary.loc["a", "status"] == "vanished" and summary.loc["a", "removed_early"]
        frames = summary.loc["a", "n_frames"]
        assert 1.0 / STEP_LENGTH <= frames <= 1.5 / STEP_LENGTH  # the crash comes at once, removal 1 s later
    rec = traffic.recording({"test": True}, {}, {})
    gt = rec.ground_truth.set_index("agent_id")
    assert gt.loc["a", "collided"] and gt.loc["b", "collided"] and not gt.loc["c", "collided"]
    assert gt.loc["a", "removed_early"] == (delay is not None)


def test_vehicles_are_inserted_only_where_there_is_room_and_leave_at_their_exits(road):
    rows = [(f"v{k}", 0.0, "arm0_to_arm1", True) for k in range(3)]
    traffic = make_traffic(road, rows)
    assert traffic.insert_due() == 1  # the others wait for room on the access lane
    run(traffic, 60.0)
    summary = traffic.summary()
    assert len(summary) == 3 and (summary["status"] == "arrived").all()
    assert not summary["collided"].any()
    assert traffic.vehicles == [] and traffic.n_pending == 0


@pytest.mark.parametrize("seed", [0, 7])
def test_plan_is_the_sumo_scenarios_plan(seed):
    pop = population_from_dict({**DEFAULT_POPULATION.to_dict(), "n_vehicles": 30, "arrivals": "poisson"})
    ours = plan_population(pop, ROUTE_IDS, seed, pirl_routes=["arm0_to_arm2", "arm1_to_arm3"])
    sumo = plan_vehicles(SumoScenarioConfig(population=pop, pirl_routes=("arm0_to_arm2", "arm1_to_arm3")), seed)
    pd.testing.assert_frame_equal(ours, sumo)


def test_configs_reject_bad_values():
    with pytest.raises(ValueError, match="drivers.horizon must be an integer >= 1"):
        DriverConfig(horizon=0)
    with pytest.raises(ValueError, match="stop_speed"):
        DriverConfig(stop_speed=4.0, resume_speed=3.0)
    with pytest.raises(ValueError, match="rules.yield_distance must be a finite number > 0"):
        TrafficRules(yield_distance=0.0)
    with pytest.raises(ValueError, match="rules.crash_removal_delay"):
        TrafficRules(crash_removal_delay=-1.0)
    with pytest.raises(ValueError, match="unknown route"):
        plan_population(DEFAULT_POPULATION, ROUTE_IDS, 0, pirl_routes=["nowhere"])
    with pytest.raises(ValueError, match="seed must be an integer"):
        plan_population(DEFAULT_POPULATION, ROUTE_IDS, -1)


def test_safe_acceleration_stops_behind_a_standing_obstacle_and_leaves_free_driving_alone():
    from pirl_sim.scenarios.highway.traffic import safe_acceleration

    dt, tau, b = 0.1, 0.5, 5.0
    for v0, gap0 in ((12.0, 30.0), (8.0, 10.0), (3.0, 2.0)):
        v, gap = v0, gap0
        for _ in range(200):  # the car takes at most the safe speed each step; the obstacle stands
            v = max(0.0, v + min(0.0, safe_acceleration(v, gap, 0.0, tau=tau, b=b, dt=dt)) * dt)
            gap -= v * dt
            assert gap > 0.0
        assert v < 1e-3
    assert safe_acceleration(10.0, 200.0, 10.0, tau=tau, b=b, dt=dt) > 0.0  # far behind: no limit
