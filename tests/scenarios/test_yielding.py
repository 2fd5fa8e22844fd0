"""Yielding on known routes (pirl_sim.scenarios.yielding): where routes meet, and whom a car yields to now."""

import numpy as np
import pytest

from pirl_sim.paths import ReferencePath
from pirl_sim.scenarios.route_set import RouteSet
from pirl_sim.scenarios.yielding import STOP_RULE, ConflictTable, yield_gaps

# a main road eastwards along y = 0, and a road joining it from the south-west at x = 0 and running on along it
MAIN = np.column_stack([np.linspace(-100.0, 100.0, 201), np.zeros(201)])
JOIN = np.vstack([np.column_stack([np.linspace(-50.0, 0.0, 51), np.linspace(-50.0, 0.0, 51)]),
                  np.column_stack([np.linspace(1.0, 100.0, 100), np.zeros(100)])])


@pytest.fixture(scope="module")
def roads():
    routes = RouteSet(("main", "join"), (ReferencePath.from_polyline(MAIN, smoothing=0.0),
                                         ReferencePath.from_polyline(JOIN, smoothing=0.0)))
    return routes, ConflictTable(routes)


def _state(routes, cars):
    """Arrays of cars given as (route index, arc length [m], speed [m/s])."""
    route = np.array([c[0] for c in cars])
    s = np.array([c[1] for c in cars], dtype=float)
    xy = np.array([routes.paths[r].to_cartesian(np.array([si]), np.zeros(1))[0] for r, si in zip(route, s)])
    ahead = np.array([routes.paths[r].to_cartesian(np.array([si + 0.5]), np.zeros(1))[0] for r, si in zip(route, s)])
    psi = np.arctan2(ahead[:, 1] - xy[:, 1], ahead[:, 0] - xy[:, 0])
    return route, s, np.array([c[2] for c in cars], dtype=float), xy, psi


def test_the_joining_road_meets_the_main_road_once(roads):
    routes, table = roads
    join_at = table.s_own[1, 0]  # on the joining road: where the main road comes within 1.5 m
    assert 50 * np.sqrt(2) - 3.0 < join_at < 50 * np.sqrt(2)
    assert table.s_other[1, 0] == pytest.approx(100.0 - (50 * np.sqrt(2) - join_at) / np.sqrt(2), abs=1.0)
    assert np.isnan(table.s_own[0, 0]) and np.isnan(table.s_own[1, 1])


def test_a_car_yields_to_traffic_from_its_left_that_arrives_first(roads):
    routes, table = roads
    join_at = table.s_own[1, 0]
    # the joining car 30 m before the point at 8 m/s; a main-road car 30 m before it at 10 m/s (3 s away)
    state = _state(routes, [(1, join_at - 30.0, 8.0), (0, table.s_other[1, 0] - 30.0, 10.0)])
    gap = yield_gaps(table, *state, egos=np.array([0, 1]))
    assert gap[0] == pytest.approx(30.0 - STOP_RULE.stop_margin)
    assert np.isinf(gap[1])  # the main-road car does not yield to a car on its right
    # the main-road car 60 m away (6 s: beyond the 4 s horizon), or the joining car 2 s ahead of it: no yield
    far = _state(routes, [(1, join_at - 30.0, 8.0), (0, table.s_other[1, 0] - 60.0, 10.0)])
    early = _state(routes, [(1, join_at - 8.0, 8.0), (0, table.s_other[1, 0] - 30.0, 10.0)])
    past = _state(routes, [(1, join_at - 30.0, 8.0), (0, table.s_other[1, 0] + 5.0, 10.0)])
    slow = _state(routes, [(1, join_at - 30.0, 8.0), (0, table.s_other[1, 0] - 3.0, 0.5)])
    for state in (far, early, past, slow):
        assert np.isinf(yield_gaps(table, *state, egos=np.array([0]))[0])
    # an unknown route is never yielded to
    route, s, v, xy, psi = _state(routes, [(1, join_at - 30.0, 8.0), (0, table.s_other[1, 0] - 30.0, 10.0)])
    assert np.isinf(yield_gaps(table, np.array([1, -1]), s, v, xy, psi, egos=np.array([0]))[0])
