"""highway-env roads of Lanelet2 maps: the lanes lie on the map's centre lines, the routes and the ring are the map's,
recorded tracks lie on the lanes, PIRL drivers and highway-env's IDM drive the map's roundabout, and bad maps or
scenarios are clear errors."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

pytest.importorskip("highway_env")
pytest.importorskip("lanelet2")

from pirl_sim.io.lanelet2_map import load_map, write_map  # noqa: E402
from pirl_sim.scenarios.highway.lanelet_road import CenterlineLane, lanelet_road  # noqa: E402
from pirl_sim.scenarios.highway.network import build_network, lane_graph, ring_lanes  # noqa: E402
from pirl_sim.scenarios.highway.scenario import (  # noqa: E402
    HighwayScenarioConfig,
    load_highway_run,
    load_scenario,
    run_highway_scenario,
)
from pirl_sim.scenarios.population_config import DEFAULT_POPULATION  # noqa: E402
from pirl_sim.scenarios.lanelet_graph import lanelet_paths, ring_lanelets  # noqa: E402


@pytest.fixture(scope="module")
def ring_map(tmp_path_factory):
    """highway-env's own roundabout written as a Lanelet2 map (each of its lanes a lanelet)."""
    d = tmp_path_factory.mktemp("hw_map")
    lines, succ = lane_graph(build_network())
    write_map(lines, succ, d / "map.osm")
    return load_map(d / "map.osm"), lines, d


def _distance_to_lanes(network, xy: np.ndarray) -> np.ndarray:
    """[m] each point's distance to the nearest lane's centre line (inside the lane's length)."""
    lanes = [lane for tos in network.graph.values() for ls in tos.values() for lane in ls]
    out = np.full(len(xy), np.inf)
    for k, p in enumerate(xy):
        for lane in lanes:
            s, lat = lane.local_coordinates(p)
            if -0.5 <= s <= lane.length + 0.5:
                out[k] = min(out[k], abs(lat))
    return out


def test_a_centerline_lane_is_highway_envs_straight_lane_on_a_straight_line():
    from highway_env.road.lane import StraightLane

    straight, ours = StraightLane([0.0, 0.0], [10.0, 5.0]), CenterlineLane([[0.0, 0.0], [4.0, 2.0], [10.0, 5.0]], 4.0)
    assert ours.length == pytest.approx(straight.length)
    for p in ([3.0, 4.0], [12.0, 1.0], [-2.0, -3.0]):  # beside, beyond the end, before the start
        np.testing.assert_allclose(ours.local_coordinates(np.array(p)), straight.local_coordinates(np.array(p)))
    for s, lat in ((0.0, 0.0), (3.0, 1.5), (11.5, -2.0)):
        np.testing.assert_allclose(ours.position(s, lat), straight.position(s, lat))
        assert ours.heading_at(s) == pytest.approx(straight.heading_at(s))
    with pytest.raises(ValueError, match="must not repeat"):
        CenterlineLane([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0]], 4.0)
    with pytest.raises(ValueError, match=r"points must be a finite \(P >= 2, 2\) array"):
        CenterlineLane([[0.0, 0.0]], 4.0)


def test_the_maps_lanelets_are_the_lanes_and_its_routes_and_ring_are_kept(ring_map):
    lmap, lines, _ = ring_map
    road = lanelet_road(lmap)
    lanes = [lane for tos in road.network.graph.values() for ls in tos.values() for lane in ls]
    assert len(lanes) == len(lmap.centerlines) == len(road.lane_of)
    for lid, (a, b) in road.lane_of.items():  # each lane runs along its lanelet's centre line
        lane, line = road.network.get_lane((a, b, 0)), lmap.centerlines[lid]
        seg = np.hypot(*np.diff(line, axis=0).T)
        assert lane.length == pytest.approx(seg.sum())
        s = np.concatenate(([0.0], np.cumsum(seg)))
        np.testing.assert_allclose([lane.position(x, 0.0) for x in s], line, atol=1e-9)
    # the routes are the map's entry-to-exit routes, with the ids the SUMO network gives them
    assert {rid: ids for rid, ids in lanelet_paths(lmap)} == road.lanelets
    assert list(road.routes) == sorted(road.lanelets)
    # the ring is the lanelets on a cycle: highway-env's own ring lanes
    assert road.ring == frozenset(road.lane_of[lid] for lid in ring_lanelets(lmap))
    assert len(road.ring) == len(ring_lanes(build_network())) and ring_lanes(road.network) == road.ring
    for rid, route in road.routes.items():  # each route joins the ring where its first ring lanelet starts
        ring_pos = [k for k, ix in enumerate(route.lanes) if ix[:2] in road.ring]
        assert ring_pos and route.entry_lane == ring_pos[0] - 1 and route.merge_node == route.lanes[ring_pos[0]][0]
        assert route.length == pytest.approx(route.lengths.sum())


def test_tracks_recorded_on_the_roundabout_lie_on_the_maps_lanes(ring_map, tmp_path):
    """Every position recorded on highway-env's own roundabout is as close to a lane of its map's road as to the
    map's lanelet centre lines, within 0.05 m (the map samples the lanes every 0.5 m: the ring's chords)."""
    from pirl_sim.evaluation.realism import _lane_offsets

    lmap, _, _ = ring_map
    population = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=10, depart_interval=3.0)
    res = run_highway_scenario(HighwayScenarioConfig(population=population), seed=0)
    xy = res.recording.tracks[["x", "y"]].to_numpy()[::7]
    assert np.all(_distance_to_lanes(lanelet_road(lmap).network, xy) <= _lane_offsets(lmap, xy) + 0.05)


@pytest.fixture(scope="module")
def map_run(ring_map, tmp_path_factory):
    """PIRL drivers and highway-env's IDM on the map's roundabout, two routes drawn 1:3."""
    lmap, _, d = ring_map
    routes = [rid for rid, _ in lanelet_paths(lmap)]
    weights = {routes[0]: 1.0, routes[5]: 3.0}
    population = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=14, depart_interval=3.0, background_share=0.3)
    config = HighwayScenarioConfig(lanelet_map=str(d / "map.osm"), route_weights=weights, population=population)
    out = tmp_path_factory.mktemp("hw_map_run")
    return config, run_highway_scenario(config, seed=1, out_dir=out), out, weights


def test_pirl_drivers_and_idm_drive_a_maps_roundabout_on_its_lanelets(map_run, ring_map):
    from pirl_sim.evaluation.realism import _lane_offsets

    config, res, _, weights = map_run
    lmap, _, _ = ring_map
    gt = res.recording.ground_truth
    assert len(gt) == 14 and set(gt["status"]) == {"arrived"} and not gt["collided"].any()
    assert set(gt["route_id"]) <= set(weights) and gt["is_pirl"].any() and not gt["is_pirl"].all()
    assert np.isfinite(gt.loc[gt["is_pirl"], "theta_speed_dev"]).all()
    xy = res.recording.tracks[["x", "y"]].to_numpy()
    assert np.percentile(_lane_offsets(lmap, xy), 95) < 0.5  # [m] on the map's centre lines
    # the drivers' reference paths are the map's centre lines joined along each route
    rid = sorted(weights)[0]
    path = res.routes.paths[res.routes.route_ids.index(rid)]
    first = lmap.centerlines[lanelet_road(lmap).lanelets[rid][0]]
    assert np.hypot(path.x[0] - first[0, 0], path.y[0] - first[0, 1]) < 0.5


def test_a_map_run_reads_back_with_its_routes(map_run):
    config, res, out, _ = map_run
    info = json.loads((out / "run.json").read_text())
    assert info["config"]["lanelet_map"] == config.lanelet_map
    assert info["config"]["route_weights"] == config.route_weights
    assert info["routes"] == list(config.route_ids())
    run = load_highway_run(out)
    assert run.config == config
    s = np.linspace(0.0, res.routes.paths[0].length, 7)
    np.testing.assert_allclose(run.routes.paths[0].position(s), res.routes.paths[0].position(s))


def test_a_scenario_file_finds_its_map_beside_it(ring_map, tmp_path):
    import shutil

    _, _, d = ring_map
    shutil.copy(d / "map.osm", tmp_path / "ring.osm")
    (tmp_path / "scenario.toml").write_text('lanelet_map = "ring.osm"\n')
    config = load_scenario(tmp_path / "scenario.toml")
    assert config.lanelet_map == str(tmp_path / "ring.osm") and len(config.route_ids()) == 16


def test_bad_maps_and_scenarios_are_named(ring_map, tmp_path):
    from pirl_sim.scenarios.highway.network import RoundaboutGeometry

    _, _, d = ring_map
    a, b = np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([[10.0, 0.0], [20.0, 0.0]])
    write_map({"A": a, "B": b}, {"A": ["B"]}, tmp_path / "road.osm")
    with pytest.raises(ValueError, match="no roundabout: no lanelets form a cycle"):
        lanelet_road(tmp_path / "road.osm")
    with pytest.raises(FileNotFoundError, match="Lanelet2 map not found: /nonexistent/map.osm"):
        HighwayScenarioConfig(lanelet_map="/nonexistent/map.osm")
    with pytest.raises(ValueError, match="lanelet_map must be the path of a Lanelet2 map"):
        HighwayScenarioConfig(lanelet_map="")
    with pytest.raises(ValueError, match="with lanelet_map the map's roundabout is driven, leave geometry out"):
        HighwayScenarioConfig(lanelet_map=str(d / "map.osm"), geometry=RoundaboutGeometry(30.0))
    with pytest.raises(ValueError, match=r"route_weights: unknown route\(s\) \['arm0_to_arm1'\]"):
        HighwayScenarioConfig(lanelet_map=str(d / "map.osm"), route_weights={"arm0_to_arm1": 1.0})
    with pytest.raises(ValueError, match="must give some route a weight > 0"):
        HighwayScenarioConfig(route_weights={"arm0_to_arm1": 0.0})
