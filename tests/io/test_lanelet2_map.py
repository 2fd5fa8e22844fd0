"""Lanelet2 maps (pirl_sim.io.lanelet2_map): loading, writing and route matching, maps that lanelet2 would read
differently refused, bad nodes named, and fuzzed maps (hypothesis)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from shared_sample import SAMPLE_MAP, needs_sample

pytest.importorskip("hypothesis")
lanelet2 = pytest.importorskip("lanelet2", reason="lanelet2 (the 'maps' extra) is not installed")

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from pirl_sim.io.interaction import read_tracks  # noqa: E402
from pirl_sim.io.lanelet2_map import (  # noqa: E402
    JOINT_TOLERANCE,
    LaneletMap,
    _arc_lengths,
    _inside,
    _project,
    load_map,
    match_route,
    write_map,
)

from shared_sample import SAMPLE_TRACKS  # noqa: E402
from toml_fuzz import read_or_error_naming_it  # noqa: E402


RING_RADIUS = 20.0  # [m]
ENTRY_LENGTH = 40.0  # [m]


def hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance [m] of a vertex of either polyline from the other polyline."""
    return max(_project(a, b, _arc_lengths(b))[0].max(), _project(b, a, _arc_lengths(a))[0].max())


def ring_scene() -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
    """8 counter-clockwise 45-degree arcs of a 20 m circle (ring0 starts at (0, -20)) and a straight entry
    that joins ring0 tangentially from the west."""
    lanes = {}
    for k in range(8):
        angle = np.linspace(-np.pi / 2 + k * np.pi / 4, -np.pi / 2 + (k + 1) * np.pi / 4, 13)
        lanes[f"ring{k}"] = RING_RADIUS * np.column_stack([np.cos(angle), np.sin(angle)])
    lanes["entry"] = np.column_stack([np.linspace(-ENTRY_LENGTH, 0.0, 9), np.full(9, -RING_RADIUS)])
    successors = {f"ring{k}": [f"ring{(k + 1) % 8}"] for k in range(8)}
    successors["entry"] = ["ring0"]
    return lanes, successors


def ring_track(n: int, angle_end: float, rng: np.random.Generator, noise: float = 0.3) -> np.ndarray:
    """Positions [m] driving the entry, then the ring counter-clockwise up to angle_end [rad] past (0, -20)."""
    s = np.linspace(0.0, ENTRY_LENGTH + RING_RADIUS * angle_end, n)
    on_ring = s > ENTRY_LENGTH
    phi = -np.pi / 2 + (s - ENTRY_LENGTH) / RING_RADIUS
    xy = np.where(
        on_ring[:, None],
        RING_RADIUS * np.column_stack([np.cos(phi), np.sin(phi)]),
        np.column_stack([s - ENTRY_LENGTH, np.full(n, -RING_RADIUS)]),
    )
    return xy + rng.normal(0.0, noise, xy.shape)


@pytest.fixture(scope="module")
def ring_map(tmp_path_factory) -> tuple[LaneletMap, dict[str, int], dict[str, np.ndarray]]:
    lanes, successors = ring_scene()
    path = tmp_path_factory.mktemp("maps") / "ring.osm"
    ids = write_map(lanes, successors, path)
    return load_map(path), ids, lanes


@pytest.fixture(scope="module")
def sample_map() -> LaneletMap:
    return load_map(SAMPLE_MAP)

@needs_sample
def test_sample_map_loads_with_lanelets_and_centerlines(sample_map):
    assert sample_map.lanelet_ids == (20, 21)
    for lanelet_id, line in sample_map.centerlines.items():
        assert line.ndim == 2 and line.shape[1] == 2 and len(line) >= 2
        assert not line.flags.writeable
        ll = sample_map.map.laneletLayer[lanelet_id]
        np.testing.assert_allclose(line, [[p.x, p.y] for p in ll.centerline])
    # lanelet 20 runs +x along y = 2.5 m, 21 runs -x along y = 5.5 m (the tracks' lanes)
    np.testing.assert_allclose(sample_map.centerlines[20][[0, -1]], [[1, 2.5], [101, 2.5]], atol=1e-5)
    np.testing.assert_allclose(sample_map.centerlines[21][[0, -1]], [[101, 5.5], [1, 5.5]], atol=1e-5)


@needs_sample
def test_bare_origin_gives_mercator_coordinates_off_by_centimetres(sample_map):
    """Why load_map uses UtmProjector: lanelet2.io.load(path, Origin) projects with Mercator instead."""
    mercator = lanelet2.io.load(str(SAMPLE_MAP), lanelet2.io.Origin(0.0, 0.0))
    utm = sample_map.map
    gaps = [
        np.hypot(utm.pointLayer[p.id].x - p.x, utm.pointLayer[p.id].y - p.y) for p in mercator.pointLayer
    ]
    assert len(gaps) == 6
    assert max(gaps) > 0.01
    # node 6 sits at (101, 7) m in the tracks' (UTM) frame
    node = utm.pointLayer[6]
    assert (node.x, node.y) == pytest.approx((101.0, 7.0), abs=1e-4)
    assert np.hypot(mercator.pointLayer[6].x - 101.0, mercator.pointLayer[6].y - 7.0) > 0.01


def test_missing_file_raises_file_not_found(tmp_path):
    missing = tmp_path / "nope.osm"
    with pytest.raises(FileNotFoundError, match="nope.osm"):
        load_map(missing)


@needs_sample
def test_truncated_osm_raises_value_error(tmp_path):
    text = SAMPLE_MAP.read_text()
    bad = tmp_path / "truncated.osm"
    bad.write_text(text[: len(text) // 2])
    with pytest.raises(ValueError, match=r"truncated\.osm.*not a readable Lanelet2 map"):
        load_map(bad)


def test_map_without_lanelets_raises_value_error(tmp_path):
    empty = tmp_path / "empty.osm"
    empty.write_text('<?xml version="1.0"?>\n<osm version="0.6" generator="test">\n</osm>\n')
    with pytest.raises(ValueError, match=r"empty\.osm: the map has no lanelets"):
        load_map(empty)


@needs_sample
def test_lanelet2_parse_errors_raise(tmp_path):
    broken = tmp_path / "broken.osm"
    broken.write_text(SAMPLE_MAP.read_text().replace('<member type="way" ref="12" role="right" />',
                                                     '<member type="way" ref="99" role="right" />'))
    with pytest.raises(ValueError, match=r"broken\.osm: lanelet2 reported errors.*nonexistent member 99"):
        load_map(broken)


def test_geometry_helpers_agree_with_lanelet2(ring_map):
    lmap, ids, _ = ring_map
    ll = lmap.map.laneletLayer[ids["ring1"]]
    line = lmap.centerlines[ll.id]
    polygon = np.array([[p.x, p.y] for p in ll.polygon2d()])
    lo, hi = polygon.min(axis=0) - 2.0, polygon.max(axis=0) + 2.0
    points = np.random.default_rng(3).uniform(lo, hi, (300, 2))
    centerline_2d = lanelet2.geometry.to2D(ll.centerline)
    ref_distance = [lanelet2.geometry.distance(centerline_2d, lanelet2.core.BasicPoint2d(*p)) for p in points]
    ref_inside = [lanelet2.geometry.inside(ll, lanelet2.core.BasicPoint2d(*p)) for p in points]
    np.testing.assert_allclose(_project(points, line, _arc_lengths(line))[0], ref_distance, atol=1e-9)
    np.testing.assert_array_equal(_inside(points, polygon), ref_inside)
    assert 20 < sum(ref_inside) < 280  # the sample exercises both answers

@needs_sample
def test_sample_tracks_match_their_lanelets(sample_map):
    tracks = read_tracks(SAMPLE_TRACKS)
    expected = {1: 20, 2: 21}
    for track_id, track in tracks.groupby("track_id"):
        xy = track[["x", "y"]].to_numpy()
        match = match_route(sample_map, xy, max_offset=3.0)
        assert match.fraction_within >= 0.9
        assert match.lanelet_ids == (expected[track_id],)
        assert match.n_off_map == 0
        assert np.all(match.point_route_index == 0)
        assert match.offsets.shape == (len(xy),) and match.offsets.max() < 1e-3
        # heading from the file gives the same answer
        psi_match = match_route(sample_map, xy, psi=track["psi_rad"].to_numpy())
        assert psi_match.lanelet_ids == match.lanelet_ids


@needs_sample
def test_lane_change_uses_left_relation_and_cuts_centerline(tmp_path):
    """Both sample lanelets made to run +x: 21 is then left of 20 across a dashed line."""
    text = SAMPLE_MAP.read_text()
    same_way = text.replace(
        '<member type="way" ref="11" role="left" />\n    <member type="way" ref="12" role="right" />',
        '<member type="way" ref="12" role="left" />\n    <member type="way" ref="11" role="right" />',
    )
    assert same_way != text
    path = tmp_path / "two_lanes.osm"
    path.write_text(same_way)
    lmap = load_map(path)
    x = np.linspace(1.0, 100.0, 100)
    y = np.interp(x, [40.0, 60.0], [2.5, 5.5])  # lane 20 (y = 2.5 m) -> lane 21 (y = 5.5 m)
    match = match_route(lmap, np.column_stack([x, y]))
    assert match.lanelet_ids == (20, 21)
    assert match.relations == ("left",)
    assert match.fraction_within == 1.0
    line = match.centerline
    assert line[0] == pytest.approx([1.0, 2.5], abs=1e-5) and line[-1] == pytest.approx([101.0, 5.5], abs=1e-5)
    assert np.all(np.diff(line[:, 0]) > -1e-6)  # the route never runs backwards
    assert set(match.point_route_index) == {0, 1}


@needs_sample
def test_two_way_lanelet_is_matched_in_the_driven_direction(tmp_path):
    path = tmp_path / "two_way.osm"
    path.write_text(SAMPLE_MAP.read_text().replace('<tag k="one_way" v="yes" />', '<tag k="one_way" v="no" />'))
    lmap = load_map(path)
    x = np.linspace(100.0, 1.0, 60)
    match = match_route(lmap, np.column_stack([x, np.full_like(x, 2.5)]))
    assert match.lanelet_ids == (20,) and match.inverted == (True,)
    assert match.centerline[0] == pytest.approx([101.0, 2.5], abs=1e-5)


def test_ring_track_matches_entry_then_ring(ring_map, rng):
    lmap, ids, _ = ring_map
    xy = ring_track(150, np.pi * 0.9, rng)  # entry, then 162 degrees of the ring: ring0 .. ring3
    match = match_route(lmap, xy)
    names = {v: k for k, v in ids.items()}
    assert [names[i] for i in match.lanelet_ids] == ["entry", "ring0", "ring1", "ring2", "ring3"]
    assert match.relations == ("successor",) * 4
    assert match.fraction_within == 1.0
    assert np.all(np.diff(match.point_route_index) >= 0)
    # the route polyline: entry start to ring3 end, every joint once
    assert match.centerline[0] == pytest.approx([-ENTRY_LENGTH, -RING_RADIUS], abs=1e-3)
    assert match.centerline[-1] == pytest.approx([0.0, RING_RADIUS], abs=1e-3)
    assert np.all(np.hypot(*np.diff(match.centerline, axis=0).T) > 1e-6)


def test_sparse_track_fills_skipped_lanelets_from_the_graph(ring_map, rng):
    lmap, ids, _ = ring_map
    xy = ring_track(150, np.pi * 1.9, rng)[[10, 50, 149]]  # entry, ring0, ring7: 7 lanelets apart
    match = match_route(lmap, xy)
    names = {v: k for k, v in ids.items()}
    assert [names[i] for i in match.lanelet_ids] == ["entry"] + [f"ring{k}" for k in range(8)]
    np.testing.assert_array_equal(match.point_route_index, [0, 1, 8])


def test_track_far_from_every_lanelet_raises(ring_map, rng):
    lmap, _, _ = ring_map
    xy = ring_track(40, 1.0, rng) + [500.0, 0.0]
    with pytest.raises(ValueError, match="all 40 of 40 points are off-map"):
        match_route(lmap, xy)


def test_partly_off_map_track_counts_off_map_points(ring_map, rng):
    lmap, ids, _ = ring_map
    xy = np.vstack([[[-80.0 + 2 * k, -RING_RADIUS - 30.0] for k in range(10)], ring_track(90, 1.0, rng)])
    match = match_route(lmap, xy)
    assert match.n_off_map == 10
    assert np.all(match.point_route_index[:10] == -1)
    assert match.fraction_within == pytest.approx(0.9)
    assert match.lanelet_ids[0] == ids["entry"]


def test_a_break_in_the_graph_keeps_the_longer_part_of_the_track(ring_map, rng):
    """From the ring back onto the entry no graph path leads: the 50 ring points are the route, the 20
    entry points are marked unconnected (this raised and dropped the whole track)."""
    lmap, ids, _ = ring_map
    track = ring_track(150, np.pi, rng)
    xy = np.vstack([track[100:], track[:20]])
    match = match_route(lmap, xy)
    names = {v: k for k, v in ids.items()}
    assert all(names[i].startswith("ring") for i in match.lanelet_ids)
    np.testing.assert_array_equal(match.unconnected, np.arange(70) >= 50)
    assert match.n_unconnected == 20 and match.n_off_map == 0
    assert np.all(match.point_route_index[50:] == -1) and np.all(match.point_route_index[:50] >= 0)


def test_one_unconnected_point_is_left_out_not_fatal(ring_map, rng):
    """A single stray position on a lanelet no route reaches (here: the entry, mid-ring) is left out and
    counted; the route is the one the other points drove."""
    lmap, ids, _ = ring_map
    xy = ring_track(150, np.pi * 0.9, rng, noise=0.05)
    clean = match_route(lmap, xy)
    stray = xy.copy()
    stray[120] = [-20.0, -RING_RADIUS]  # on the entry, while the track is already on ring2 / ring3
    match = match_route(lmap, stray)
    assert match.lanelet_ids == clean.lanelet_ids
    np.testing.assert_array_equal(np.flatnonzero(match.unconnected), [120])
    assert match.n_unconnected == 1 and match.point_route_index[120] == -1
    np.testing.assert_array_equal(np.delete(match.point_route_index, 120), np.delete(clean.point_route_index, 120))


def test_a_clean_track_has_no_unconnected_points(ring_map, rng):
    match = match_route(ring_map[0], ring_track(150, np.pi * 1.5, rng))
    assert match.n_unconnected == 0 and not match.unconnected.any()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"xy": np.zeros((5, 3))}, r"xy must have shape \(n, 2\)"),
        ({"xy": np.full((5, 2), np.nan)}, "non-finite"),
        ({"xy": np.zeros((5, 2)), "max_offset": 0.0}, "max_offset must be a positive"),
        ({"xy": np.zeros((5, 2)), "psi": np.zeros(4)}, r"psi must have shape \(5,\)"),
    ],
)
def test_match_route_rejects_bad_input(ring_map, kwargs, message):
    with pytest.raises(ValueError, match=message):
        match_route(ring_map[0], **kwargs)

def test_written_ring_round_trips(ring_map):
    lmap, ids, lanes = ring_map
    assert lmap.ids_by_name() == ids
    for name, line in lanes.items():
        back = lmap.centerlines[ids[name]]
        assert hausdorff(back, line) < 0.05, name
        np.testing.assert_allclose(back[[0, -1]], line[[0, -1]], atol=1e-3)
    graph, layer = lmap.routing_graph, lmap.map.laneletLayer
    _, successors = ring_scene()
    for name, nexts in successors.items():
        assert sorted(x.id for x in graph.following(layer[ids[name]])) == sorted(ids[n] for n in nexts)
    path = graph.shortestPath(layer[ids["entry"]], layer[ids["ring5"]])
    assert [ll.id for ll in path] == [ids[n] for n in ["entry", "ring0", "ring1", "ring2", "ring3", "ring4", "ring5"]]
    for ll in layer:
        attrs = ll.attributes
        assert (attrs["type"], attrs["subtype"], attrs["location"], attrs["one_way"]) == (
            "lanelet", "road", "urban", "yes")


def test_written_boundaries_are_lane_width_apart(tmp_path):
    lanes = {"a": np.column_stack([np.linspace(0, 30, 7), np.zeros(7)])}
    ids = write_map(lanes, {}, tmp_path / "one.osm", lane_width=3.0)
    lmap = load_map(tmp_path / "one.osm")
    ll = lmap.map.laneletLayer[ids["a"]]
    left = np.array([[p.x, p.y] for p in ll.leftBound])
    right = np.array([[p.x, p.y] for p in ll.rightBound])
    np.testing.assert_allclose(left[:, 1], 1.5, atol=1e-6)
    np.testing.assert_allclose(right[:, 1], -1.5, atol=1e-6)
    assert not list(tmp_path.glob(".*.tmp"))  # atomic write left no temporary file


def test_write_map_rejects_bad_input(tmp_path):
    line = np.column_stack([np.linspace(0, 10, 5), np.zeros(5)])
    out = tmp_path / "x.osm"
    with pytest.raises(ValueError, match="must meet within"):
        write_map({"a": line, "b": line + [10.0 + 2 * JOINT_TOLERANCE, 0.0]}, {"a": ["b"]}, out)
    with pytest.raises(ValueError, match=r"without a centerline: \['c'\]"):
        write_map({"a": line}, {"a": ["c"]}, out)
    with pytest.raises(ValueError, match="repeats a point"):
        write_map({"a": np.vstack([line[:2], line[1:]])}, {}, out)
    with pytest.raises(ValueError, match=r"shape \(P, 2\)"):
        write_map({"a": line[:1]}, {}, out)
    with pytest.raises(ValueError, match="lane_width"):
        write_map({"a": line}, {}, out, lane_width=-1.0)
    with pytest.raises(ValueError, match="head-on"):
        write_map({"a": line, "b": line[::-1]}, {"a": ["b"]}, out)
    assert not out.exists()


# ---------------------------------------------------------------------------------------------- Lanelet2 maps
def _osm(lat="0.00002", left=(1, 2), right=(3, 4), right_way=11, doctype=""):
    nodes = {1: ("0.0", "0.0"), 2: ("0.0", "0.0002"), 3: (lat, "0.0"), 4: ("0.00002", "0.0002")}
    out = ['<?xml version="1.0"?>', doctype, '<osm version="0.6">']
    out += [f'<node id="{i}" lat="{la}" lon="{lo}"/>' for i, (la, lo) in nodes.items()]
    for way, refs in ((10, left), (11, right)):
        out.append(f'<way id="{way}">' + "".join(f'<nd ref="{i}"/>' for i in refs)
                   + '<tag k="type" v="line_thin"/><tag k="subtype" v="solid"/></way>')
    out.append(f'<relation id="20"><member type="way" ref="10" role="left"/><member type="way" ref="{right_way}" '
               'role="right"/><tag k="type" v="lanelet"/><tag k="subtype" v="road"/><tag k="location" v="urban"/>'
               '<tag k="one_way" v="yes"/></relation>')
    return "\n".join(out + ["</osm>"])


@pytest.fixture(name="load_map")
def load_map_fixture():
    pytest.importorskip("lanelet2", reason="lanelet2 (the 'maps' extra) is not installed")
    from pirl_sim.io.lanelet2_map import load_map

    return load_map


def test_a_plain_lanelet_loads(tmp_path, load_map):
    (tmp_path / "ok.osm").write_text(_osm())
    assert load_map(tmp_path / "ok.osm").lanelet_ids == (20,)


@pytest.mark.parametrize("lat", ["0.00_002", "٠.٠٠٠٠٢", "０.００００２", "0.0\u20030"])
def test_coordinates_lanelet2_reads_differently_are_refused(tmp_path, load_map, lat):
    (tmp_path / "m.osm").write_text(_osm(lat=lat), encoding="utf-8")
    with pytest.raises(ValueError, match=r"m\.osm: node 3 has lat=.*ASCII digits.*no digit separators"):
        load_map(tmp_path / "m.osm")


@pytest.mark.parametrize("encoding", ["utf-8", "utf-16"])
def test_a_dtd_entity_is_refused(tmp_path, load_map, encoding):
    text = _osm(lat="&x;", doctype='<!DOCTYPE osm [<!ENTITY x "0.00002">]>')
    if encoding != "utf-8":
        text = text.replace('<?xml version="1.0"?>', f'<?xml version="1.0" encoding="{encoding}"?>')
    (tmp_path / "m.osm").write_text(text, encoding=encoding)
    with pytest.raises(ValueError, match=r"m\.osm: the file has a DTD.*lanelet2 does not expand its entities"):
        load_map(tmp_path / "m.osm")


@pytest.mark.parametrize("kw,message", [
    ({"left": (1,)}, r"lanelet 20 has a left border \(line 10\) of 1 node\(s\); a border needs at least two"),
    ({"right_way": 10}, r"lanelet 20 has its left border \(line 10\) and its right border \(line 10\) on the same"),
    ({"right": (1, 2)}, r"lanelet 20 has its left border \(line 10\) and its right border \(line 11\) on the same"),
    ({"left": (1, 1)}, r"lanelet 20 has a left border \(line 10\) whose nodes all lie on one point"),
])
def test_degenerate_lanelets_are_refused(tmp_path, load_map, kw, message):
    (tmp_path / "m.osm").write_text(_osm(**kw))
    with pytest.raises(ValueError, match=rf"m\.osm: {message}"):
        load_map(tmp_path / "m.osm")


@pytest.mark.parametrize("attr, value", [("lat", "abc"), ("lon", ""), ("lat", "nan"), ("lon", "inf"),
                                         ("lat", "91")])
@needs_sample
def test_map_node_with_bad_coordinate_is_an_error_naming_the_node(tmp_path, attr, value):
    pytest.importorskip("lanelet2")
    from pirl_sim.io.lanelet2_map import load_map

    text = SAMPLE_MAP.read_text()
    bad = tmp_path / "bad.osm"
    bad.write_text(re.sub(rf'(<node id="3"[^>]*?){attr}="[^"]*"', rf'\g<1>{attr}="{value}"', text, count=1))
    assert bad.read_text() != text
    with pytest.raises(ValueError, match=rf"bad.osm: node 3 has {attr}='{re.escape(value)}'; expected a number"):
        load_map(bad)


@needs_sample
def test_map_node_without_lat_and_non_xml_map_are_errors(tmp_path):
    pytest.importorskip("lanelet2")
    from pirl_sim.io.lanelet2_map import load_map

    bad = tmp_path / "nolat.osm"
    bad.write_text(re.sub(r'(<node id="5"[^>]*?)lat="[^"]*"', r"\1", SAMPLE_MAP.read_text(), count=1))
    with pytest.raises(ValueError, match="node 5 has no lat attribute"):
        load_map(bad)
    binary = tmp_path / "binary.osm"
    binary.write_bytes(b"\x00\xff\xfe garbage")
    with pytest.raises(ValueError, match="binary.osm: not a readable Lanelet2 map"):
        load_map(binary)


#: field values a user's file might hold by mistake
ODD_FIELDS = st.sampled_from(["1.5", "nan", "inf", "-inf", "", " ", "abc", "-1", "0", "1e400", "1e3", "+2",
                              "99999999999999999999999", "1_0", "0x10", "car", "\"", "1,2", "NaN", "4.0"])


OSM_FIELD = st.one_of(ODD_FIELDS, st.floats(-1e-3, 1e-3).map(repr), st.integers(-3, 30).map(str))


@st.composite
def mutated_osm(draw):
    """The sample map with a few attribute values replaced, lines deleted, or the text cut."""
    import re

    text = SAMPLE_MAP.read_text()
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["attr", "attr", "delete", "cut"]))
        if kind == "attr":
            attrs = list(re.finditer(r'(lat|lon|id|ref|v)="([^"]*)"', text))
            if not attrs:
                continue
            m = draw(st.sampled_from(attrs))
            value = draw(OSM_FIELD).replace('"', "&quot;").replace("<", "&lt;").replace("&", "&amp;")
            text = text[:m.start(2)] + value + text[m.end(2):]
        elif kind == "delete":
            lines = text.splitlines()
            if not lines:  # an earlier cut left nothing to delete
                continue
            del lines[draw(st.integers(0, len(lines) - 1))]
            text = "\n".join(lines)
        else:
            text = text[:draw(st.integers(0, len(text)))]
    return text


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=mutated_osm())
@needs_sample
def test_fuzz_map_loader(tmp_path_factory, text):
    pytest.importorskip("lanelet2")
    import xml.etree.ElementTree as ET

    from pirl_sim.io.lanelet2_map import load_map

    path = tmp_path_factory.mktemp("osm") / "map.osm"
    path.write_text(text)
    loaded, lmap = read_or_error_naming_it(load_map, path)
    if not loaded:
        return
    # loaded: then every node of the file had real coordinates (none was read as 0 silently) ...
    for node in ET.parse(path).getroot().iter("node"):
        assert math.isfinite(float(node.get("lat"))) and math.isfinite(float(node.get("lon")))
    # ... and every centerline is finite
    assert all(np.isfinite(line).all() for line in lmap.centerlines.values())


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=200))
def test_fuzz_map_loader_random_bytes(tmp_path_factory, data):
    pytest.importorskip("lanelet2")
    from pirl_sim.io.lanelet2_map import load_map

    path = tmp_path_factory.mktemp("osm") / "map.osm"
    path.write_bytes(data)
    with pytest.raises(ValueError, match="map.osm"):
        load_map(path)
