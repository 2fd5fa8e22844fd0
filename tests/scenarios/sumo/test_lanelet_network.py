"""SUMO networks from Lanelet2 maps: the lanes lie on the map's centre lines, every entry-to-exit route drives in
SUMO without teleport, and bad maps or parameters are clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pirl_sim.io.lanelet2_map import load_map, write_map
from pirl_sim.scenarios.lanelet_graph import edge_id, lanelet_edges, lanelet_paths, lanelet_routes, route_lanelets
from pirl_sim.scenarios.sumo.lanelet_network import lane_distances, network_from_lanelet2
from pirl_sim.scenarios.sumo.network import RoundaboutSpec, build_network, lane_graph, routes
from shared_sample import SAMPLE_MAP, SAMPLE_TRACKS, needs_sample



@pytest.fixture(scope="module")
def ring(tmp_path_factory):
    """A pirl_sim ring roundabout as a Lanelet2 map (every SUMO lane a lanelet), and its SUMO network."""
    d = tmp_path_factory.mktemp("ring")
    spec = RoundaboutSpec()
    files = build_network(spec, d / "sumo")
    lines, succ = lane_graph(files.net)
    write_map(lines, succ, d / "map.osm")
    return spec, files, lines, load_map(d / "map.osm"), d


def test_lanes_lie_on_the_maps_centre_lines_and_routes_match(ring):
    spec, files, lines, lmap, d = ring
    net = network_from_lanelet2(lmap, d / "from_map")
    assert net.net.is_file()
    # one route per pair of arms: the scenario's own routes, and the map's way round the ring back to one's arm
    assert len(net.routes) == len(routes(spec)) + spec.n_arms == spec.n_arms ** 2
    ids = {rid for rid, _ in net.routes}
    assert len(ids) == len(net.routes)
    points = np.concatenate([line for line in lmap.centerlines.values()])
    assert np.percentile(lane_distances(net.net, points), 99) < 0.05
    assert lane_distances(net.net, points + [0.0, 1.0]).min() >= 0.0


def test_every_route_drives_in_sumo_on_the_map(ring, tmp_path):
    import libsumo

    from pirl_sim.evaluation.realism import _lane_offsets  # distances to the map's centre lines

    *_, lmap, d = ring
    net = network_from_lanelet2(lmap, tmp_path)
    libsumo.start(["sumo", "-n", str(net.net), "--no-step-log", "--no-warnings", "--time-to-teleport", "30",
                   "--step-length", "0.5", "--seed", "0"])
    try:
        for k, (rid, edges) in enumerate(net.routes):
            libsumo.route.add(rid, list(edges))
            libsumo.vehicle.add(f"v{k}", rid, depart=str(3.0 * k))
        arrived = teleported = 0
        xy = []
        for _ in range(2000):
            libsumo.simulationStep()
            arrived += libsumo.simulation.getArrivedNumber()
            teleported += libsumo.simulation.getStartingTeleportNumber()
            xy.extend(libsumo.vehicle.getPosition(v) for v in libsumo.vehicle.getIDList())
            if libsumo.simulation.getMinExpectedNumber() == 0:
                break
    finally:
        libsumo.close()
    assert (arrived, teleported) == (len(net.routes), 0)
    assert np.percentile(_lane_offsets(lmap, np.array(xy)), 99) < 0.1


@needs_sample
def test_the_interaction_sample_map_converts_and_its_tracks_lie_on_the_lanes(tmp_path):
    from pirl_sim.io.interaction import read_tracks

    lmap = load_map(SAMPLE_MAP)
    net = network_from_lanelet2(lmap, tmp_path)
    assert [e for _, edges in net.routes for e in edges] and all(e.startswith("ll") for _, r in net.routes for e in r)
    tracks = read_tracks(SAMPLE_TRACKS)
    from pirl_sim.evaluation.realism import _lane_offsets

    xy = tracks[["x", "y"]].to_numpy()
    assert np.all(lane_distances(net.net, xy) <= _lane_offsets(lmap, xy) + 0.05)


def test_routes_follow_the_routing_graph(ring):
    *_, lmap, _ = ring
    succ = {k: {int(n.id) for n in lmap.routing_graph.following(lmap.map.laneletLayer[k])} for k in lmap.centerlines}
    paths = dict(lanelet_paths(lmap))
    for rid, edges in lanelet_routes(lmap):
        lanelets = route_lanelets(lmap, edges)
        assert lanelets == paths[rid]
        assert all(b in succ[a] for a, b in zip(lanelets[:-1], lanelets[1:]))
        assert not succ[lanelets[-1]]


def test_a_chain_of_lanelets_is_one_edge_and_the_routes_drive_on_it(ring, tmp_path):
    import sumolib

    *_, lmap, _ = ring
    chains = lanelet_edges(lmap)
    # the ring's lanelets (SUMO's lanes, junction-internal ones too) join into longer chains, each named by its head
    assert sorted(lid for c in chains.values() for lid in c) == sorted(lmap.centerlines)
    assert any(len(c) > 1 for c in chains.values()) and all(e == edge_id(c[0]) for e, c in chains.items())
    net = network_from_lanelet2(lmap, tmp_path)
    assert net.lanelets == chains
    assert {e.getID() for e in sumolib.net.readNet(str(net.net)).getEdges()} == set(chains)
    paths = dict(lanelet_paths(lmap))
    for rid, edges in net.routes:
        assert set(edges) <= set(chains) and all(a != b for a, b in zip(edges[:-1], edges[1:]))
        assert tuple(lid for e in edges for lid in chains[e]) == paths[rid]
        # a route given lanelet by lanelet reads back as the same lanelets
        assert route_lanelets(lmap, [edge_id(lid) for lid in paths[rid]]) == paths[rid]
    assert dict(net.routes) == dict(lanelet_routes(lmap))
    assert [rid for rid, _ in net.routes] == [rid for rid, _ in lanelet_routes(lmap, merge_chains=False)]
    single = network_from_lanelet2(lmap, tmp_path / "single", merge_chains=False)
    assert all(len(c) == 1 for c in single.lanelets.values()) and len(single.lanelets) == len(lmap.centerlines)
    with pytest.raises(ValueError, match="name no lanelet"):
        route_lanelets(lmap, ["ll999999"])


def test_no_lane_points_backwards_against_its_lanelets(ring, tmp_path):
    import sumolib

    *_, lmap, _ = ring
    net = network_from_lanelet2(lmap, tmp_path)
    sumo = sumolib.net.readNet(str(net.net))
    for eid, chain in net.lanelets.items():
        line = np.vstack([lmap.centerlines[lid] for lid in chain])
        lane = np.asarray(sumo.getEdge(eid).getLanes()[0].getShape())[:, :2]
        for a, b in ((lane[0], lane[1]), (lane[-2], lane[-1])):  # the lane's first and last segment
            mid = (a + b) / 2.0
            k = int(np.argmin(np.hypot(*((line[:-1] + line[1:]) / 2.0 - mid).T)))  # the centre line's nearest segment
            along = line[k + 1] - line[k]
            cos = np.dot(b - a, along) / (np.hypot(*(b - a)) * np.hypot(*along))
            assert cos > 0.0, f"lane of {eid} runs against its lanelets"


def test_bad_inputs(tmp_path, ring):
    *_, lmap, _ = ring
    with pytest.raises(ValueError, match="junction_radius"):
        network_from_lanelet2(lmap, tmp_path, junction_radius=-1.0)
    with pytest.raises(ValueError, match="speed"):
        network_from_lanelet2(lmap, tmp_path, speed=float("nan"))
    # a closed loop: every lanelet has a predecessor, so no route enters the map
    a = np.array([[0.0, 0.0], [50.0, 0.0]])
    b = np.array([[50.0, 0.0], [50.0, 50.0], [0.0, 50.0], [0.0, 0.0]])
    write_map({"A": a, "B": b}, {"A": ["B"], "B": ["A"]}, tmp_path / "loop.osm")
    with pytest.raises(ValueError, match="no route leads from an entry"):
        network_from_lanelet2(tmp_path / "loop.osm", tmp_path / "loop")
    net = network_from_lanelet2(lmap, tmp_path / "net")
    with pytest.raises(ValueError, match="xy must be"):
        lane_distances(net.net, np.zeros(3))


def test_ring_lanelets_have_priority_over_entries(ring, tmp_path):
    import sumolib

    *_, lmap, _ = ring
    net = sumolib.net.readNet(str(network_from_lanelet2(lmap, tmp_path).net))
    priority = {e.getID(): e.getPriority() for e in net.getEdges()}
    cycle = {eid for eid in priority if _on_cycle(net, eid)}
    assert cycle and {priority[e] for e in cycle} == {2}
    assert len(cycle) < len(priority) and {p for e, p in priority.items() if e not in cycle} == {1}


def _on_cycle(net, eid: str) -> bool:
    seen, todo = set(), [e.getID() for e in net.getEdge(eid).getOutgoing()]
    while todo:
        e = todo.pop()
        if e == eid:
            return True
        if e not in seen:
            seen.add(e)
            todo.extend(x.getID() for x in net.getEdge(e).getOutgoing())
    return False


@pytest.fixture(scope="module")
def map_run(ring, tmp_path_factory):
    """PIRL drivers on the ring read back from its Lanelet2 map, two routes drawn 1:3."""
    import dataclasses

    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION
    from pirl_sim.scenarios.sumo.scenario import SumoScenarioConfig, run_sumo_scenario

    *_, d = ring
    routes = [rid for rid, _ in lanelet_routes(load_map(d / "map.osm"))]
    weights = {routes[0]: 1.0, routes[5]: 3.0}
    config = SumoScenarioConfig(lanelet_map=str(d / "map.osm"), route_weights=weights,
                                population=dataclasses.replace(DEFAULT_POPULATION, n_vehicles=12, depart_interval=3.0))
    out = tmp_path_factory.mktemp("map_run")
    return config, run_sumo_scenario(config, seed=1, out_dir=out), out, weights


def test_pirl_drivers_drive_a_maps_roundabout_on_its_lanelets(map_run, ring):
    from pirl_sim.evaluation.realism import _lane_offsets

    config, res, out, weights = map_run
    *_, lmap, _ = ring
    assert config.routes == dict(lanelet_routes(lmap))  # the map's routes
    gt = res.recording.ground_truth
    assert len(gt) == 12 and set(gt["status"]) == {"arrived"} and not gt["collided"].any()
    assert set(gt["route_id"]) <= set(weights)
    assert gt["is_pirl"].sum() > 0 and np.isfinite(gt.loc[gt["is_pirl"], "theta_speed_dev"]).all()
    xy = res.recording.tracks[["x", "y"]].to_numpy()
    assert np.percentile(_lane_offsets(lmap, xy), 95) < 0.5  # [m] box centres on the map's centre lines
    # the drivers' reference paths are the map's centre lines, joined along each route
    path = res.routes.paths[res.routes.route_ids.index(sorted(weights)[0])]
    first = lmap.centerlines[int(config.routes[sorted(weights)[0]][0][2:])]
    assert np.hypot(path.x[0] - first[0, 0], path.y[0] - first[0, 1]) < 0.5


def test_a_map_run_reads_back_with_its_routes(map_run):
    from pirl_sim.scenarios.sumo.scenario import load_sumo_run

    config, res, out, _ = map_run
    info = json.loads((out / "run.json").read_text())
    assert info["config"]["lanelet_map"] == config.lanelet_map
    assert info["config"]["route_weights"] == config.route_weights
    run = load_sumo_run(out)
    assert run.config == config
    s = np.linspace(0.0, res.routes.paths[0].length, 7)
    np.testing.assert_allclose(run.routes.paths[0].position(s), res.routes.paths[0].position(s))


def test_route_weights_set_how_often_each_route_is_driven():
    import dataclasses

    from pirl_sim.scenarios.planning import plan_population
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION

    pop = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=2000)
    plan = plan_population(pop, ["a", "b", "c"], 0, route_weights={"a": 1.0, "b": 3.0})
    share = plan["route_id"].value_counts(normalize=True)
    assert "c" not in share and share["b"] == pytest.approx(0.75, abs=0.03)
    with pytest.raises(ValueError, match="route_weights give every route of background_routes weight 0"):
        plan_population(pop, ["a", "b", "c"], 0, background_routes=["c"], route_weights={"a": 1.0})
    unweighted = plan_population(pop, ["a", "b", "c"], 0)
    assert set(unweighted["route_id"]) == {"a", "b", "c"}


@pytest.mark.parametrize("kwargs, error, match", [
    ({"lanelet_map": "/nonexistent/map.osm"}, FileNotFoundError, "Lanelet2 map not found: /nonexistent/map.osm"),
    ({"lanelet_map": ""}, ValueError, "lanelet_map must be the path of a Lanelet2 map"),
    ({"lanelet_map": "MAP", "demand_per_arm": 600.0}, ValueError, "demand_per_arm sets the demand of the parametric"),
    ({"lanelet_map": "MAP", "route_weights": {"nowhere": 1.0}}, ValueError, r"route_weights: unknown route\(s\)"),
    ({"lanelet_map": "MAP", "route_weights": {"R0": -1.0}}, ValueError, r"route_weights\['r.*'\] must be a finite "
                                                                         "number >= 0"),
    ({"lanelet_map": "MAP", "route_weights": {"R0": 0.0}}, ValueError, "must give some route a weight > 0"),
])
def test_bad_map_scenarios_are_named(ring, kwargs, error, match):
    from pirl_sim.scenarios.sumo.scenario import SumoScenarioConfig

    *_, d = ring
    first = lanelet_routes(load_map(d / "map.osm"))[0][0]
    kwargs = {k: (str(d / "map.osm") if v == "MAP" else v) for k, v in kwargs.items()}
    if "route_weights" in kwargs:
        kwargs["route_weights"] = {(first if k == "R0" else k): v for k, v in kwargs["route_weights"].items()}
    with pytest.raises(error, match=match):
        SumoScenarioConfig(**kwargs)


def test_a_scenario_file_finds_its_map_beside_it(ring, tmp_path):
    import shutil

    from pirl_sim.scenarios.sumo.scenario import load_scenario

    *_, d = ring
    shutil.copy(d / "map.osm", tmp_path / "ring.osm")
    (tmp_path / "scenario.toml").write_text('lanelet_map = "ring.osm"\n')
    config = load_scenario(tmp_path / "scenario.toml")
    assert config.lanelet_map == str(tmp_path / "ring.osm") and config.routes
