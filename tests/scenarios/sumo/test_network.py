"""Parametric SUMO roundabouts: spec validation, bounded geometry, netconvert output geometry, routes, reference
paths, and the lane graph as a Lanelet2 map."""

import math
import sys

import numpy as np
import pytest

pytest.importorskip("sumolib")

from pirl_sim.scenarios.sumo import (  # noqa: E402
    DEFAULT_NETWORK,
    RoundaboutSpec,
    build_network,
    lane_graph,
    load_net,
    route_centerline,
    route_edges,
    route_id,
    routes,
    validate_route,
)


RADIUS = 20.0  # [m]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    spec = RoundaboutSpec(radius=RADIUS, n_arms=4)
    files = build_network(spec, tmp_path_factory.mktemp("roundabout"))
    return files, load_net(files)


def _radii(shape, center=(0.0, 0.0)):
    s = np.asarray(shape, dtype=float)[:, :2]
    return np.hypot(s[:, 0] - center[0], s[:, 1] - center[1])

@pytest.mark.parametrize("kwargs, match", [
    ({"radius": -20.0}, "radius must be > 0"),
    ({"radius": 0.0}, "radius must be > 0"),
    ({"radius": float("nan")}, "radius must be a finite number"),
    ({"n_arms": 2}, "n_arms must be >= 3"),
    ({"n_arms": 4.0}, "n_arms must be an integer"),
    ({"lanes": 0}, "lanes must be >= 1"),
    ({"approach_length": 0.0}, "approach_length must be > 0"),
    ({"ring_segments": 3}, "ring_segments must be >= n_arms"),
    ({"speed_limit": -1.0}, "speed_limit must be > 0"),
    ({"lane_width": 0.0}, "lane_width must be > 0"),
    ({"splitter_width": -0.5}, "splitter_width must be >= 0"),
    ({"junction_radius": 0.0}, "junction_radius must be > 0"),
    ({"center": (1.0,)}, "center must be two finite numbers"),
    ({"radius": 3.0}, "must exceed the ring's width"),
    ({"radius": 5.0, "n_arms": 6}, "arms too wide"),
])
def test_spec_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RoundaboutSpec(**kwargs)


def test_spec_is_frozen_and_normalises_center():
    spec = RoundaboutSpec(center=[10, -5])
    assert spec.center == (10.0, -5.0)
    with pytest.raises(AttributeError):
        spec.radius = 30.0


def test_overlapping_junctions_are_rejected(tmp_path):
    with pytest.raises(ValueError, match="junctions of neighbouring arms overlap"):
        build_network(RoundaboutSpec(radius=12.0, n_arms=6), tmp_path)
    assert not list(tmp_path.glob("*.net.xml"))  # nothing half-done left at the target

def test_build_writes_plain_xml_and_net(built):
    files, _ = built
    for path in (files.nodes, files.edges, files.connections, files.net):
        assert path.is_file() and path.stat().st_size > 0
    edg = files.edges.read_text()
    assert "<roundabout " in edg and 'spreadType="center"' in edg
    assert not [p for p in files.net.parent.iterdir() if p.name.endswith(".tmp") or ".tmp." in p.name]


def test_coordinates_are_not_normalised(built):
    _, net = built
    # the ring node of arm 2 (pointing to -x) stays at (-20, 0); normalisation would shift it to x >= 0
    x, y = net.getNode("ring2").getCoord()
    assert (x, y) == pytest.approx((-RADIUS, 0.0), abs=1e-2)
    assert net.getLocationOffset() == pytest.approx((0.0, 0.0))


def test_ring_lanes_lie_on_the_circle(built):
    _, net = built
    ring_lanes = [lane for e in net.getEdges(withInternal=False) if e.getID().startswith("ring")
                  for lane in e.getLanes()]
    assert len(ring_lanes) == 4
    for lane in ring_lanes:
        shape = lane.getShape()
        assert len(shape) >= 5  # round, not a chord between nodes
        assert np.all(np.abs(_radii(shape) - RADIUS) < 1.5)
        assert np.all(np.abs(_radii(shape) - RADIUS) < 0.05)  # shape points are on the circle
    # the ring -> ring lanes through the junctions follow the circle too (custom shapes)
    through = [c for e in net.getEdges(withInternal=False) if e.getID().startswith("ring")
               for c in e.getLane(0).getOutgoing() if c.getTo().getID().startswith("ring")]
    assert len(through) == 4
    for c in through:
        assert np.all(np.abs(_radii(net.getLane(c.getViaLaneID()).getShape()) - RADIUS) < 0.05)


def test_arms_are_one_way_edges_on_either_side_of_the_axis(built):
    files, net = built
    spec = files.spec
    d = spec.arm_offset
    for i in range(spec.n_arms):
        a = spec.arm_angle(i)
        left = np.array([-math.sin(a), math.cos(a)])
        for eid, side in ((f"arm{i}_in", 1.0), (f"arm{i}_out", -1.0)):
            shape = np.asarray(net.getEdge(eid).getLane(0).getShape())
            assert shape @ left == pytest.approx(np.full(len(shape), side * d), abs=1e-2)
            assert net.getEdge(eid).getLength() == pytest.approx(spec.approach_length, abs=10.0)

def test_routes_cover_every_entry_exit_pair(built):
    files, net = built
    spec = files.spec
    rs = routes(spec)
    assert len(rs) == spec.n_arms * (spec.n_arms - 1)
    assert len({rid for rid, _ in rs}) == len(rs)
    for rid, edges in rs:
        assert validate_route(net, edges, route_id=rid) == edges
    by_id = dict(rs)
    # from arm 0: first exit (right), through, left
    assert by_id[route_id(0, 1)] == ["arm0_in", "ring0_1", "arm1_out"]
    assert by_id[route_id(0, 2)] == ["arm0_in", "ring0_1", "ring1_2", "arm2_out"]
    assert by_id[route_id(0, 3)] == ["arm0_in", "ring0_1", "ring1_2", "ring2_3", "arm3_out"]
    assert by_id[route_id(3, 0)] == ["arm3_in", "ring3_0", "arm0_out"]


@pytest.mark.parametrize("entry, exit_, match", [(1, 1, "must differ"), (0, 4, "exit_arm must be"),
                                                 (-1, 2, "entry_arm must be")])
def test_route_edges_rejects_bad_arms(entry, exit_, match):
    with pytest.raises(ValueError, match=match):
        route_edges(RoundaboutSpec(), entry, exit_)


def test_validate_route_names_the_unreachable_route(built):
    _, net = built
    with pytest.raises(ValueError, match=r"route 'bad' is unreachable: unknown edge 'nowhere'"):
        validate_route(net, ["arm0_in", "nowhere"], route_id="bad")
    with pytest.raises(ValueError, match=r"route 'gap' is unreachable: edge 'arm0_in' does not lead to "
                                         r"'ring1_2'"):
        validate_route(net, ["arm0_in", "ring1_2", "arm2_out"], route_id="gap")
    with pytest.raises(ValueError, match="unknown edge ':ring0_0'"):  # internal edges are not route edges
        validate_route(net, ["arm0_in", ":ring0_0", "ring0_1"])
    with pytest.raises(ValueError, match="is empty"):
        validate_route(net, [])

def test_route_centerline_of_a_through_route_is_continuous(built):
    files, net = built
    edges = route_edges(files.spec, 0, 2)
    path = route_centerline(net, edges)
    assert path.ndim == 2 and path.shape[1] == 2 and len(path) > 50
    steps = np.hypot(*np.diff(path, axis=0).T)
    assert steps.max() <= 2.0
    assert steps.min() >= 1e-3  # duplicates removed
    on_ring = np.abs(_radii(path) - RADIUS) < 0.1
    assert on_ring.sum() >= 20
    # it runs from the start of arm 0's in lane to the end of arm 2's out lane, through the junctions
    assert path[0] == pytest.approx(net.getEdge("arm0_in").getLane(0).getShape()[0])
    assert path[-1] == pytest.approx(net.getEdge("arm2_out").getLane(0).getShape()[-1])
    for a, b in zip(edges[:-1], edges[1:]):  # entry, ring through arm 1, exit
        (conn,) = net.getEdge(a).getOutgoing()[net.getEdge(b)]
        for p in net.getLane(conn.getViaLaneID()).getShape():
            assert np.min(np.hypot(*(path - np.asarray(p)).T)) < 1e-6


def test_route_centerline_is_continuous_for_every_route_of_a_two_lane_roundabout(tmp_path):
    spec = RoundaboutSpec(radius=25.0, lanes=2, n_arms=3)
    net = load_net(build_network(spec, tmp_path))
    for rid, edges in routes(spec):
        path = route_centerline(net, edges, route_id=rid)
        assert np.hypot(*np.diff(path, axis=0).T).max() <= 2.0, rid


def test_route_centerline_rejects_unknown_edges(built):
    _, net = built
    with pytest.raises(ValueError, match="unknown edge 'nope'"):
        route_centerline(net, ["arm0_in", "nope"])


# ------------------------------------------------------------------------------------------ simulators
@pytest.mark.parametrize("kwargs, match", [
    ({"radius": 1e7}, r"radius must be in \[5, 500\] m, got 10000000.0"),
    ({"approach_length": 1e7}, r"approach_length must be in \[1, 2000\] m"),
    ({"lanes": 50, "radius": 400.0}, r"lanes must be in \[1, 6\], got 50"),
    ({"n_arms": 40, "radius": 400.0, "ring_segments": 64}, r"n_arms must be in \[3, 12\], got 40"),
])
def test_sumo_roundabout_geometry_is_bounded(kwargs, match):
    from pirl_sim.scenarios.sumo.network import RoundaboutSpec

    with pytest.raises(ValueError, match=match):
        RoundaboutSpec(**kwargs)


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    return build_network(DEFAULT_NETWORK, tmp_path_factory.mktemp("roundabout"))


def test_lane_graph_is_a_connected_lanelet2_map(net, tmp_path):
    pytest.importorskip("lanelet2")
    from pirl_sim.io.lanelet2_map import load_map, write_map

    lanes, succ = lane_graph(net)
    n = DEFAULT_NETWORK.n_arms
    assert {f"arm{i}_in_0" for i in range(n)} <= set(lanes) and any(k.startswith(":ring") for k in lanes)
    for a, nexts in succ.items():
        for b in nexts:
            assert np.hypot(*(lanes[a][-1] - lanes[b][0])) == 0.0
    ids = write_map(lanes, succ, tmp_path / "map.osm")
    lmap = load_map(tmp_path / "map.osm")
    # every route is a path in the routing graph from its entry lane to its exit lane
    graph, layer = lmap.routing_graph, lmap.map.laneletLayer
    for rid, edges in routes(DEFAULT_NETWORK):
        route = graph.getRoute(layer[ids[f"{edges[0]}_0"]], layer[ids[f"{edges[-1]}_0"]])
        assert route is not None, rid
        assert math.isfinite(route.length2d())


@pytest.mark.parametrize("name", ["sumolib", "traci", "libsumo"])
def test_a_missing_sumo_module_is_an_error_naming_the_extra(monkeypatch, name):
    from pirl_sim.scenarios.sumo.imports import sumo_module

    monkeypatch.setitem(sys.modules, name, None)  # what `import name` meets when it is not installed
    with pytest.raises(ModuleNotFoundError, match=rf"{name} is not installed.*'sumo' extra.*pirl_sim\[sumo\]"):
        sumo_module(name)


def test_building_a_network_without_sumolib_names_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "sumolib", None)
    with pytest.raises(ModuleNotFoundError, match=r"'sumo' extra"):
        build_network(RoundaboutSpec(), tmp_path)


@pytest.mark.parametrize("radius, lanes", [(150.0, 1), (400.0, 2), (500.0, 3)])
def test_large_rings_join_their_lanes_at_every_junction(tmp_path, radius, lanes):
    """The ring's chords stay within a few centimetres of the circle that its connections follow, so a large
    ring's lanes meet their successors (a recording's map can be written)."""
    files = build_network(RoundaboutSpec(radius=radius, lanes=lanes, junction_radius=10.0), tmp_path)
    lines, succ = lane_graph(files.net)
    gaps = [np.hypot(*(lines[a][-1] - lines[b][0])) for a, nexts in succ.items() for b in nexts]
    assert max(gaps) == 0.0  # lane_graph moved every joint onto one point, none farther than LANE_JOINT_SNAP


def test_a_lane_of_no_length_is_left_out_and_its_neighbours_joined():
    """netconvert makes junction lanes of one point on some real maps (DR_USA_Roundabout_EP): no lanelet can hold
    them, so the lanes before them lead to the lanes after them."""
    from pirl_sim.scenarios.sumo.network import _drop_points

    lines = {"a": np.array([[0.0, 0.0], [5.0, 0.0]]), ":j_0": np.array([[5.0, 0.0]]),
             "b": np.array([[5.0, 0.0], [9.0, 0.0]]), "c": np.array([[5.0, 0.0], [5.0, 4.0]])}
    succ = {"a": [":j_0"], ":j_0": ["b", "c"]}
    _drop_points(lines, succ)
    assert set(lines) == {"a", "b", "c"} and succ == {"a": ["b", "c"]}
