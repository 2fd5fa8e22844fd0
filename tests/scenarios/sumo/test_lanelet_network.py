"""SUMO networks from Lanelet2 maps: the lanes lie on the map's centre lines, every entry-to-exit route drives in
SUMO without teleport, and bad maps or parameters are clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from pirl_sim.io.lanelet2_map import load_map, write_map
from pirl_sim.scenarios.sumo.lanelet_network import edge_id, lane_distances, lanelet_routes, network_from_lanelet2
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
    succ = {edge_id(k): {edge_id(int(n.id)) for n in lmap.routing_graph.following(lmap.map.laneletLayer[k])}
            for k in lmap.centerlines}
    for _, edges in lanelet_routes(lmap):
        assert all(b in succ[a] for a, b in zip(edges[:-1], edges[1:]))
        assert not succ[edges[-1]]


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
