"""highway-env's roundabout as routes: catalogue, lane curvature, reference paths and desired speed."""

import math

import numpy as np
import pytest

pytest.importorskip("highway_env")

from pirl_sim.paths import DEFAULT_A_LAT, DEFAULT_V_MAX  # noqa: E402
from pirl_sim.scenarios.highway.network import (  # noqa: E402
    RoundaboutGeometry,
    build_network,
    lane_curvature,
    lane_graph,
    route_catalogue,
    route_set,
)
from pirl_sim.scenarios.highway.scenario import ROUTE_IDS  # noqa: E402
from pirl_sim.scenarios.drivers import RouteSetProfile  # noqa: E402
from pirl_sim.scenarios.sumo.network import RoundaboutSpec, routes as sumo_routes  # noqa: E402


@pytest.fixture(scope="module")
def net():
    return build_network(RoundaboutGeometry(20.0))


@pytest.fixture(scope="module")
def catalogue(net):
    return route_catalogue(net)


def test_catalogue_has_the_sumo_scenarios_route_ids_in_their_order(catalogue):
    assert tuple(catalogue) == ROUTE_IDS
    assert ROUTE_IDS == tuple(rid for rid, _ in sumo_routes(RoundaboutSpec()))
    south_to_north = catalogue["arm0_to_arm2"]
    assert [ix[:2] for ix in south_to_north.lanes] == [
        ("ser", "ses"), ("ses", "se"), ("se", "ex"), ("ex", "ee"), ("ee", "nx"), ("nx", "nxs"), ("nxs", "nxr")]
    assert south_to_north.merge_node == "se"
    assert south_to_north.merge_s == pytest.approx(90.0 + south_to_north.lengths[1])


def test_lanes_meet_their_successors(net, catalogue):
    for route in catalogue.values():
        for a, b in zip(route.lanes[:-1], route.lanes[1:]):
            la, lb = net.get_lane(a), net.get_lane(b)
            assert np.hypot(*(la.position(la.length, 0) - lb.position(0, 0))) < 1e-9


@pytest.mark.parametrize("radius", [15.0, 20.0, 30.0])
def test_lane_curvature_is_one_over_the_radius_on_the_ring_and_zero_on_straights(radius):
    net = build_network(RoundaboutGeometry(radius))
    route = route_catalogue(net)["arm1_to_arm3"]
    ring = np.linspace(route.merge_s + 1.0, route.offsets[-2] - 1.0, 20)  # up to the exit's S-bend
    assert lane_curvature(net, route, ring) == pytest.approx(np.full(20, 1.0 / radius), rel=1e-4)
    assert lane_curvature(net, route, np.linspace(1.0, 80.0, 10)) == pytest.approx(np.zeros(10), abs=1e-9)
    # the entry's S-bend: lateral offset a sin(w x - pi/2), so |kappa| peaks near a w^2 at both ends
    lane = net.get_lane(route.lanes[route.entry_lane])
    peak = lane.amplitude * lane.pulsation**2
    u = route.offsets[route.entry_lane] + np.linspace(0.1, lane.length - 0.1, 200)
    assert lane_curvature(net, route, u).max() == pytest.approx(peak, rel=0.02)


def test_desired_speed_is_the_ring_speed_on_the_ring_with_no_peak_where_entries_join(net, catalogue):
    routes = route_set(net, catalogue, smoothing=2.0, speed_smoothing=8.0)
    profile = RouteSetProfile(routes)
    ring_speed = math.sqrt(DEFAULT_A_LAT * 20.0)  # 6 m/s
    for r, rid in enumerate(routes.route_ids):
        route = catalogue[rid]
        s = np.linspace(0.0, routes.lengths[r], 800)
        v = profile(routes.offsets[r] + s)[0]
        assert v.max() <= DEFAULT_V_MAX + 1e-9 and v[0] == pytest.approx(DEFAULT_V_MAX, rel=1e-3)
        assert v.min() >= 0.95 * ring_speed
        # no peak where the entry joins the ring at a 66 degree kink (smoothing the kink would make one of
        # 13.8 m/s): the desired speed falls from the S-bend's into the ring's
        near = v[np.abs(s - route.merge_s) < 10.0]
        assert near.max() == pytest.approx(near[0]) and near[-1] < 7.0


def test_lane_graph_names_every_lane_and_links_successors(net):
    lines, succ = lane_graph(net)
    assert len(lines) == 8 + 16  # ring segments, 4 x (access, S-bend) in and out
    assert succ["ses_se"] == ["se_ex"]
    assert succ["se_ex"] == ["ex_ee", "ex_exs"]
    for name, nxt in succ.items():
        for b in nxt:
            assert np.hypot(*(lines[name][-1] - lines[b][0])) < 1e-9


def test_geometry_is_validated():
    with pytest.raises(ValueError, match="radius must be a number of metres in"):
        RoundaboutGeometry(5.0)
    with pytest.raises(ValueError, match="radius"):
        RoundaboutGeometry(float("nan"))
