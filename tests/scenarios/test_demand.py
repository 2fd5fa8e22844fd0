"""Demand from a recording: SUMO's drivers on a network built from a Lanelet2 map drive known departures; reading
the demand back from their tracks gives each vehicle's route and its departure time; sampled demand keeps the
rates and route shares and is reproducible."""

from __future__ import annotations

import numpy as np
import pytest

from pirl_sim.io.interaction import read_tracks
from pirl_sim.io.lanelet2_map import load_map, write_map
from pirl_sim.scenarios.demand import Departure, RecordedDemand, demand_from_tracks
from pirl_sim.scenarios.sumo.demand_run import run_demand
from pirl_sim.scenarios.lanelet_graph import lanelet_paths
from pirl_sim.scenarios.sumo.lanelet_network import network_from_lanelet2
from pirl_sim.scenarios.sumo.network import RoundaboutSpec, build_network, lane_graph


@pytest.fixture(scope="module")
def ring_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("demand")
    files = build_network(RoundaboutSpec(), d / "sumo")
    lines, succ = lane_graph(files.net)
    write_map(lines, succ, d / "map.osm")
    lmap = load_map(d / "map.osm")
    net = network_from_lanelet2(lmap, d / "net")
    routes = [r for _, r in lanelet_paths(lmap)]
    rng = np.random.default_rng(0)
    lanelets = [routes[k] for k in rng.integers(0, len(routes), 12)]
    given = [Departure(6.0 * k, r, 4.0 + 0.1 * k, 1.8) for k, r in enumerate(lanelets)]
    path = run_demand(net, given, d / "vehicle_tracks_000.csv", seed=0)
    return lmap, net, given, read_tracks(path)


def test_the_demand_read_back_is_the_demand_driven(ring_run):
    lmap, net, given, tracks = ring_run
    assert tracks["track_id"].nunique() == len(given)
    assert tracks.groupby("track_id")["length"].first().to_numpy() == pytest.approx([d.length for d in given])
    demand = demand_from_tracks(tracks, lmap, [r for _, r in lanelet_paths(lmap)])
    assert demand.unmatched == 0
    back = {d.track_id: d for d in demand.departures}
    for k, d in enumerate(given, start=1):
        assert back[k].route == d.route
    t_given = np.array([d.time_s for d in given])
    t_back = np.array([back[k].time_s for k in range(1, len(given) + 1)])
    assert np.abs((t_back - t_back[0]) - (t_given - t_given[0])).max() < 1.5  # [s]
    assert sum(demand.rates().values()) == pytest.approx(3600.0 * len(given) / demand.duration_s)
    for shares in demand.route_probabilities().values():
        assert sum(shares.values()) == pytest.approx(1.0)


def test_sampled_demand_is_reproducible_and_keeps_the_rates():
    routes = [(1, 2, 3), (1, 2, 4), (5, 6)]
    dep = tuple(Departure(float(t), routes[t % 3]) for t in range(0, 600, 2))
    demand = RecordedDemand(dep, 600.0)
    a = demand.sample(np.random.default_rng(1), 36_000.0)
    b = demand.sample(np.random.default_rng(1), 36_000.0)
    assert a == b
    by_entry = {e: sum(d.route[0] == e for d in a) / 10.0 for e in (1, 5)}  # per hour
    assert by_entry[1] == pytest.approx(demand.rates()[1], rel=0.05)
    assert by_entry[5] == pytest.approx(demand.rates()[5], rel=0.1)
    share = np.mean([d.route == (1, 2, 3) for d in a if d.route[0] == 1])
    assert share == pytest.approx(demand.route_probabilities()[1][(1, 2, 3)], abs=0.03)


def test_bad_inputs(ring_run, tmp_path):
    lmap, net, given, tracks = ring_run
    with pytest.raises(ValueError, match="duration_s"):
        RecordedDemand((), 0.0)
    with pytest.raises(TypeError, match="Generator"):
        RecordedDemand(tuple(given), 60.0).sample(0)
    with pytest.raises(ValueError, match="no routes"):
        demand_from_tracks(tracks, lmap, [])
    far = tracks.assign(x=tracks["x"] + 5000.0)
    with pytest.raises(ValueError, match="does the recording belong to this map"):
        demand_from_tracks(far, lmap, [r for _, r in lanelet_paths(lmap)])
    with pytest.raises(ValueError, match="no departures"):
        run_demand(net, [], tmp_path / "t.csv")
    route = given[0].route
    with pytest.raises(ValueError, match=r"lanelet\(s\) \[999999\] of route .* are on no edge of"):
        run_demand(net, [Departure(0.0, (*route, 999999), 4.0, 1.8)], tmp_path / "t.csv")
