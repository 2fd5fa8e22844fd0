"""Crossings and merges of highway-env roads away from the ring: found with their ranks, none on highway-env's own
roundabout, and vehicles give way there (without the rule they drive into each other)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("highway_env")
pytest.importorskip("lanelet2")

from pirl_sim.io.lanelet2_map import load_map, write_map  # noqa: E402
from pirl_sim.scenarios.highway.crossings import lane_conflicts, route_conflicts  # noqa: E402
from pirl_sim.scenarios.highway.lanelet_road import CenterlineLane, lanelet_road  # noqa: E402
from pirl_sim.scenarios.highway.network import RouteLanes, build_network, ring_lanes, route_catalogue  # noqa: E402
from pirl_sim.scenarios.highway.scenario import HighwayScenarioConfig, run_highway_scenario  # noqa: E402
from pirl_sim.scenarios.population_config import DEFAULT_POPULATION  # noqa: E402


def _arc(a0: float, a1: float, r: float = 20.0) -> np.ndarray:
    t = np.radians(np.linspace(a0, a1, max(2, int(np.ceil(np.radians(a1 - a0) * r / 0.5)) + 1)))
    return np.c_[r * np.cos(t), r * np.sin(t)]


def _line(p, q) -> np.ndarray:
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    return p + np.linspace(0.0, 1.0, max(2, int(np.ceil(np.hypot(*(q - p)) / 0.5)) + 1))[:, None] * (q - p)


def _at(angle: float, r: float = 20.0) -> np.ndarray:
    return r * np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])


@pytest.fixture(scope="module")
def crossing_map(tmp_path_factory):
    """A ring (radius 20 m, counter-clockwise) whose exit at -100 degrees crosses the entry that joins the ring at -80
    degrees, as on some real roundabouts; a second entry and exit elsewhere."""
    lines = {"R1": _arc(-100, -80), "R2": _arc(-80, 30), "R3": _arc(30, 150), "R4": _arc(150, 260),
             "E": _line(_at(-80) - 30 * np.array([np.cos(np.radians(40)), np.sin(np.radians(40))]), _at(-80)),
             "XB": _line(_at(-100), _at(-100) + 30 * np.array([np.cos(np.radians(-60)), np.sin(np.radians(-60))])),
             "XC": _line(_at(30), _at(30, 50.0)), "E2": _line(_at(150, 50.0), _at(150))}
    succ = {"R1": ["R2"], "R2": ["R3", "XC"], "R3": ["R4"], "R4": ["R1", "XB"], "E": ["R2"], "E2": ["R4"]}
    path = tmp_path_factory.mktemp("crossing") / "map.osm"
    ids = write_map(lines, succ, path)
    lmap = load_map(path)
    return path, lmap, ids, lanelet_road(lmap)


def test_an_exit_crossing_an_entry_is_found_and_the_entry_ranks_lower(crossing_map):
    _, _, ids, road = crossing_map
    conflicts = lane_conflicts(road.network, road.routes, road.ring)
    assert len(conflicts) == 1
    (c,) = conflicts
    lanes = {c.lane_a: c.rank_a, c.lane_b: c.rank_b}
    assert c.kind == "crossing" and lanes == {road.lane_of[ids["XB"]]: 1, road.lane_of[ids["E"]]: 0}
    assert c.angle == pytest.approx(100.0, abs=2.0)
    line_a, line_b = (road.network.get_lane((*k, 0)) for k in (c.lane_a, c.lane_b))
    np.testing.assert_allclose(line_a.position(c.s_a, 0.0), line_b.position(c.s_b, 0.0), atol=1e-6)
    # a route through one of the two lanes has the point ahead, at its route coordinate; a route through both
    # (entering at -80 degrees, leaving at -100 after a full turn) crosses itself there and does not
    ahead = route_conflicts(road.routes, conflicts)
    for rid, route in road.routes.items():
        through = [k for k in (c.lane_a, c.lane_b) if k in route.position_of]
        assert len(ahead[rid]) == (len(through) == 1), rid
        if len(through) == 1:
            k = route.position_of[through[0]]
            s = c.s_a if through[0] == c.lane_a else c.s_b
            assert ahead[rid][0][0] == pytest.approx(route.offsets[k] + s)
    with pytest.raises(ValueError, match=r"min_angle must be in \[0, 180\) degrees"):
        lane_conflicts(road.network, road.routes, road.ring, min_angle=-1.0)


def test_highway_envs_own_roundabout_has_no_conflicts_and_lanes_merging_off_the_ring_do():
    net = build_network()
    assert lane_conflicts(net, route_catalogue(net), ring_lanes(net)) == ()
    from highway_env.road.road import RoadNetwork

    road = RoadNetwork()  # two lanes that end at one node at 30 degrees, then one lane on
    road.add_lane("a", "m", CenterlineLane(_line((-20.0, 0.0), (0.0, 0.0)), 3.5))
    road.add_lane("b", "m", CenterlineLane(_line((-20 * np.cos(np.radians(30)), -10.0), (0.0, 0.0)), 3.5))
    road.add_lane("m", "c", CenterlineLane(_line((0.0, 0.0), (20.0, 0.0)), 3.5))
    routes = {}
    for rid, first in (("ra", "a"), ("rb", "b")):
        lanes = ((first, "m", 0), ("m", "c", 0))
        lengths = np.array([road.get_lane(ix).length for ix in lanes])
        routes[rid] = RouteLanes(rid, lanes, lengths, np.array([0.0, lengths[0]]), -1, first)
    (merge,) = lane_conflicts(road, routes, frozenset())
    assert merge.kind == "merge" and {merge.lane_a, merge.lane_b} == {("a", "m"), ("b", "m")}
    assert merge.angle == pytest.approx(30.0, abs=0.5) and merge.rank_a == merge.rank_b == 0


def test_vehicles_give_way_at_the_crossing_and_collide_without_the_rule(crossing_map, monkeypatch):
    """40 of highway-env's IDM drivers at 1.5 s intervals, half entering across the exit, half leaving by it:
    with the rule nobody collides and everyone arrives, over three seeds; without it (no conflicts known) vehicles
    collide at the crossing."""
    import pirl_sim.scenarios.highway.traffic as traffic

    path, _, ids, road = crossing_map
    weights = {rid: 1.0 for rid, lanelets in road.lanelets.items()
               if {ids["E"], ids["XC"]} <= set(lanelets) or {ids["E2"], ids["XB"]} <= set(lanelets)}
    assert len(weights) == 2
    population = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=40, depart_interval=1.5, background_share=1.0)
    config = HighwayScenarioConfig(lanelet_map=str(path), population=population, route_weights=weights)
    for seed in range(3):
        gt = run_highway_scenario(config, seed).recording.ground_truth
        assert not gt["collided"].any() and set(gt["status"]) == {"arrived"}, seed
    monkeypatch.setattr(traffic, "lane_conflicts", lambda *args, **kwargs: ())
    collided = [int(run_highway_scenario(config, seed).recording.ground_truth["collided"].sum()) for seed in range(3)]
    assert min(collided) > 0, collided
