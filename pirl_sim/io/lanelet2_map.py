"""Lanelet2 OSM maps in and out, and matching a track to the lanelet route it drove.

- :func:`load_map` reads a map into a :class:`LaneletMap` (lanelet2 map, vehicle routing graph, centerlines
  as arrays).
- :func:`match_route` finds the sequence of lanelets a track drove and returns it as a :class:`RouteMatch`.
- :func:`write_map` writes centerlines and successor relations of a simulated scene as a Lanelet2 OSM file
  that :func:`load_map` reads back.

Every function uses the projector of INTERACTION maps (:func:`projector`, ``UtmProjector`` around (0, 0)).
lanelet2 (the ``maps`` extra) is imported inside the functions, so importing this module works without it.
The maps and their projection are described in the documentation's "File formats" page (Lanelet2 maps).
"""

from __future__ import annotations

import errno
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from pirl_sim.extras import install_hint

from pirl_sim.joints import joined_ends, joint_members

from .atomic import atomic_write_text

__all__ = [
    "LaneletMap",
    "RouteMatch",
    "projector",
    "load_map",
    "match_route",
    "write_map",
    "JOINT_TOLERANCE",
]

JOINT_TOLERANCE = 0.01  #: [m] largest gap between a lane's end and its successor's start that write_map joins

# What lanelet2 (pugixml's as_double, i.e. strtod) and Python read alike: ASCII digits only, no digit separators
# ("0.00_0906" is 0.000906 to Python, 0.00 to strtod), no other scripts' digits (Python reads Arabic-Indic and
# full-width digits, strtod stops at them); leading and trailing ASCII blanks are skipped by both.
_DECIMAL = re.compile(r"[ \t\r\n]*[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?[ \t\r\n]*")
_INTEGER = re.compile(r"[ \t\r\n]*-?[0-9]+[ \t\r\n]*")

# Costs of the route search, in units of the cost of one point lying max_offset from its lanelet's centerline.
_COST_SUCCESSOR = 1.0  # entering a following lanelet
_COST_LANE_CHANGE = 1.0  # changing to a left/right lanelet where the routing graph allows it
_COST_ADJACENT = 3.0  # crossing to a neighbour where the markings forbid a lane change (drivers do it)
# Leaving an on-map point out of the route: more than any point's own cost (at most ~3: 1 for the offset,
# 2 for driving against the lanelet), so a point is only left out when its lanelets connect to the rest of
# the route by no path, or only by a detour of some ten lanelet changes or more (a stray point).
_COST_UNCONNECTED = 10.0
_HEADING_WEIGHT = 2.0  # cost of driving against a lanelet's direction; (1 - cos angle) / 2 scaled by this
_HEADING_WINDOW = 2  # [frames] either side of a point used to estimate its direction of motion
_MIN_MOTION = 1.0  # [m] displacement over the window below which the direction of motion is not used
_DUPLICATE = 1e-6  # [m] consecutive route points closer than this are one point
_MAX_MITER = 4.0  # largest factor by which a boundary vertex is pushed out at a sharp corner

_RELATION_COSTS = {
    "successor": _COST_SUCCESSOR,
    "left": _COST_LANE_CHANGE,
    "right": _COST_LANE_CHANGE,
    "adjacent_left": _COST_ADJACENT,
    "adjacent_right": _COST_ADJACENT,
}


# ----------------------------------------------------------------------------------------------
# lanelet2 access
# ----------------------------------------------------------------------------------------------

def _lanelet2():
    try:
        import lanelet2  # noqa: F401
        import lanelet2.core
        import lanelet2.io
        import lanelet2.projection
        import lanelet2.routing
        import lanelet2.traffic_rules
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(f"Lanelet2 maps need the lanelet2 package: {install_hint('maps')}") from exc
    return lanelet2


def projector():
    """The projector of INTERACTION maps: ``UtmProjector(Origin(0.0, 0.0))``.

    Returns
    -------
    lanelet2.projection.UtmProjector
        Maps lat/lon [deg] to local x, y [m] (``forward``) and back (``reverse``).
    """
    lanelet2 = _lanelet2()
    return lanelet2.projection.UtmProjector(lanelet2.io.Origin(0.0, 0.0))


# ----------------------------------------------------------------------------------------------
# loading
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class LaneletMap:
    """A loaded Lanelet2 map with its vehicle routing graph.

    Attributes
    ----------
    path : pathlib.Path                                   the file it was read from
    map : lanelet2.core.LaneletMap                        coordinates in the local UTM frame [m]
    routing_graph : lanelet2.routing.RoutingGraph         German traffic rules, vehicles (successor, lane-change and
                                                          adjacent relations)
    traffic_rules : lanelet2.traffic_rules.TrafficRules   the rules the routing graph was built with
    centerlines : dict[int, numpy.ndarray]                lanelet id -> read-only (P, 2) x, y [m], in its direction
    """

    path: Path
    map: Any = field(repr=False)
    routing_graph: Any = field(repr=False)
    traffic_rules: Any = field(repr=False)
    centerlines: dict[int, np.ndarray] = field(repr=False)

    @property
    def lanelet_ids(self) -> tuple[int, ...]:
        """Ids of all lanelets, sorted."""
        return tuple(sorted(self.centerlines))

    def ids_by_name(self) -> dict[str, int]:
        """Lanelet ids by the ``name`` tag of their relation (as :func:`write_map` writes it).

        Returns
        -------
        dict[str, int]
            Only lanelets that have a ``name`` tag.
        """
        out = {}
        for ll in self.map.laneletLayer:
            attrs = ll.attributes
            if "name" in attrs:
                out[str(attrs["name"])] = int(ll.id)
        return out

    @cached_property
    def _index(self) -> _MatchIndex:
        return _MatchIndex.build(self)


def load_map(path) -> LaneletMap:
    """Read a Lanelet2 OSM map in the INTERACTION frame (nodes projected with ``UtmProjector(Origin(0, 0))``).

    Parameters
    ----------
    path : str or os.PathLike     the ``.osm`` file

    Returns
    -------
    lmap : LaneletMap             FileNotFoundError, or ValueError naming the file and the reason for a file that
                                  lanelet2 would misread or read partly (file-formats page, Lanelet2 maps)
    """
    lanelet2 = _lanelet2()
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(errno.ENOENT, "Lanelet2 map not found", str(path))
    if not path.is_file():
        raise ValueError(f"{path}: not a file")
    _check_nodes(path)
    try:
        lmap, errors = lanelet2.io.loadRobust(str(path), projector())
    except Exception as exc:  # lanelet2 raises RuntimeError for XML it cannot parse
        raise ValueError(f"{path}: not a readable Lanelet2 map: {exc}") from exc
    errors = [str(e).strip() for e in errors if str(e).strip()]
    if errors:
        detail = "; ".join(errors[:6]) + (f"; ... ({len(errors)} messages)" if len(errors) > 6 else "")
        raise ValueError(f"{path}: lanelet2 reported errors, the map would be incomplete: {detail}")
    if len(lmap.laneletLayer) == 0:
        raise ValueError(f"{path}: the map has no lanelets")
    _check_lanelets(path, lmap)

    rules = lanelet2.traffic_rules.create(
        lanelet2.traffic_rules.Locations.Germany, lanelet2.traffic_rules.Participants.Vehicle
    )
    graph = lanelet2.routing.RoutingGraph(lmap, rules)
    centerlines = {}
    for ll in lmap.laneletLayer:
        line = np.array([[p.x, p.y] for p in ll.centerline], dtype=float).reshape(-1, 2)
        line.setflags(write=False)
        centerlines[int(ll.id)] = line
    return LaneletMap(path=path, map=lmap, routing_graph=graph, traffic_rules=rules,
                      centerlines=centerlines)


def _check_nodes(path: Path) -> None:
    """``ValueError`` naming the file and the node unless the file is XML whose every ``<node>`` has an integer
    ``id`` and finite ``lat`` in [-90, 90] and ``lon`` in [-180, 180] degrees.

    lanelet2 reads a coordinate that is not a number (``lat="abc"``) or is missing as 0 without a word, which
    moves the node by metres to kilometres; this check runs first.
    """
    import xml.parsers.expat as expat

    def doctype(*_) -> None:  # in any encoding the parser reads (UTF-8, UTF-16, ...), before any entity is used
        raise ValueError(f"{path}: the file has a DTD (<!DOCTYPE ...>); lanelet2 does not expand its entities, so "
                         "coordinates written with them would be read differently: write the values themselves")

    def start(tag: str, attrs: dict) -> None:
        if tag != "node":
            return
        node_id = attrs.get("id")
        if node_id is None or not _INTEGER.fullmatch(node_id):
            raise ValueError(f"{path}: a <node> has id {node_id!r}; ids must be integers (ASCII digits)")
        for attr, bound in (("lat", 90.0), ("lon", 180.0)):
            text = attrs.get(attr)
            if text is None:
                raise ValueError(f"{path}: node {node_id} has no {attr} attribute; nodes need lat and lon in degrees")
            value = float(text) if _DECIMAL.fullmatch(text) else math.nan
            if not (math.isfinite(value) and -bound <= value <= bound):
                raise ValueError(f"{path}: node {node_id} has {attr}={text!r}; expected a number of degrees in "
                                 f"[-{bound:g}, {bound:g}] written with ASCII digits, an optional sign, point and "
                                 "exponent (no digit separators)")

    parser = expat.ParserCreate()
    parser.StartDoctypeDeclHandler = doctype
    parser.StartElementHandler = start
    try:
        with open(path, "rb") as f:
            parser.ParseFile(f)
    except expat.ExpatError as exc:
        raise ValueError(f"{path}: not a readable Lanelet2 map: not well-formed XML: {exc}") from None


def _check_lanelets(path: Path, lmap) -> None:
    """``ValueError`` naming the file and the lanelet unless every lanelet has two borders of at least two nodes
    each that do not lie on the same points (lanelet2 loads such lanelets without a word; their centerline is a
    point or the border itself). Runs before anything computes a centerline."""
    for ll in lmap.laneletLayer:
        left, right = ll.leftBound, ll.rightBound
        for side, bound in (("left", left), ("right", right)):
            if len(bound) < 2:
                raise ValueError(f"{path}: lanelet {ll.id} has a {side} border (line {bound.id}) of {len(bound)} "
                                 "node(s); a border needs at least two")
            xy = np.array([[p.x, p.y] for p in bound], dtype=float)
            if not (np.abs(np.diff(xy, axis=0)) > 1e-9).any():
                raise ValueError(f"{path}: lanelet {ll.id} has a {side} border (line {bound.id}) whose nodes all lie "
                                 "on one point; a border needs at least two distinct points")
        a = np.array([[p.x, p.y] for p in left], dtype=float)
        b = np.array([[p.x, p.y] for p in right], dtype=float)
        same = left.id == right.id or {p.id for p in left} == {p.id for p in right} or (
            a.shape == b.shape and (np.allclose(a, b, rtol=0, atol=1e-9) or np.allclose(a, b[::-1], rtol=0, atol=1e-9)))
        if same:
            raise ValueError(f"{path}: lanelet {ll.id} has its left border (line {left.id}) and its right border "
                             f"(line {right.id}) on the same points; a lanelet needs two distinct borders")


# ----------------------------------------------------------------------------------------------
# polyline geometry (pure numpy)
# ----------------------------------------------------------------------------------------------

def _arc_lengths(line: np.ndarray) -> np.ndarray:
    """Cumulative arc length [m] at each vertex of a (P, 2) polyline."""
    seg = np.hypot(*np.diff(line, axis=0).T) if len(line) > 1 else np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(seg)])


def _project(points: np.ndarray, line: np.ndarray, cum: np.ndarray):
    """Project points onto a polyline.

    Returns distance [m] (m,), arc length of the foot point [m] (m,) and unit tangent there (m, 2).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(line) == 1:
        d = np.hypot(*(points - line[0]).T)
        return d, np.zeros(len(points)), np.tile([1.0, 0.0], (len(points), 1))
    a = line[:-1]
    ab = np.diff(line, axis=0)  # (S, 2)
    len2 = np.einsum("sk,sk->s", ab, ab)
    ap = points[:, None, :] - a[None, :, :]  # (m, S, 2)
    t = np.divide(np.einsum("msk,sk->ms", ap, ab), len2[None, :],
                  out=np.zeros(ap.shape[:2]), where=len2[None, :] > 0)
    np.clip(t, 0.0, 1.0, out=t)
    diff = ap - t[..., None] * ab[None, :, :]
    d2 = np.einsum("msk,msk->ms", diff, diff)
    k = np.argmin(d2, axis=1)
    rows = np.arange(len(points))
    seg_len = np.sqrt(len2)
    s = cum[k] + t[rows, k] * seg_len[k]
    tangent = np.divide(ab[k], seg_len[k, None], out=np.tile([1.0, 0.0], (len(points), 1)),
                        where=seg_len[k, None] > 0)
    return np.sqrt(d2[rows, k]), s, tangent


def _inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test for (m, 2) points and a closed (V, 2) polygon (last != first)."""
    x, y = points[:, 0:1], points[:, 1:2]
    xi, yi = polygon[None, :, 0], polygon[None, :, 1]
    xj, yj = np.roll(polygon[:, 0], 1)[None], np.roll(polygon[:, 1], 1)[None]
    crosses = (yi > y) != (yj > y)
    x_cross = xi + np.divide((y - yi) * (xj - xi), yj - yi, out=np.zeros(crosses.shape), where=crosses)
    return (np.count_nonzero(crosses & (x < x_cross), axis=1) % 2) == 1


def _slice(line: np.ndarray, cum: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of a polyline between arc lengths s0 <= s1 [m], endpoints interpolated."""
    s0 = float(np.clip(s0, 0.0, cum[-1]))
    s1 = float(np.clip(s1, s0, cum[-1]))
    inner = line[(cum > s0) & (cum < s1)]
    ends = np.column_stack([np.interp([s0, s1], cum, line[:, 0]), np.interp([s0, s1], cum, line[:, 1])])
    return np.vstack([ends[:1], inner, ends[1:]])


def _drop_duplicates(line: np.ndarray) -> np.ndarray:
    if len(line) < 2:
        return line
    step = np.hypot(*np.diff(line, axis=0).T)
    return line[np.concatenate([[True], step > _DUPLICATE])]


# ----------------------------------------------------------------------------------------------
# route matching
# ----------------------------------------------------------------------------------------------

Node = tuple[int, bool]  # (lanelet id, driven against the lanelet's own direction)


@dataclass(frozen=True)
class _MatchIndex:
    """Arrays the matcher needs, built once per map: passable directed lanelets and the graph over them."""

    nodes: tuple[Node, ...]
    lines: tuple[np.ndarray, ...]  # per node, in driving direction
    cums: tuple[np.ndarray, ...]
    lanelet_ids: tuple[int, ...]  # lanelets with at least one passable direction
    polygons: dict[int, np.ndarray]
    boxes: np.ndarray  # (len(lanelet_ids), 4): xmin, ymin, xmax, ymax of polygon and centerline
    nodes_of: dict[int, tuple[int, ...]]  # lanelet id -> node indices
    graph: Any  # scipy.sparse.csr_matrix (K, K) of edge costs
    relation: dict[tuple[int, int], str]  # (node, node) -> cheapest relation kind

    @classmethod
    def build(cls, lmap: LaneletMap) -> _MatchIndex:
        from scipy.sparse import csr_matrix

        rules, graph = lmap.traffic_rules, lmap.routing_graph
        nodes: list[Node] = []
        objects = []
        for ll in sorted(lmap.map.laneletLayer, key=lambda x: x.id):
            for obj in (ll, ll.invert()):  # the inverted one is passable only if not one-way
                if rules.canPass(obj):
                    nodes.append((int(ll.id), bool(obj.inverted())))
                    objects.append(obj)
        index = {node: i for i, node in enumerate(nodes)}
        lines, cums = [], []
        for lanelet_id, inv in nodes:
            line = lmap.centerlines[lanelet_id]
            line = line[::-1].copy() if inv else line
            lines.append(line)
            cums.append(_arc_lengths(line))
        lanelet_ids = tuple(sorted({n[0] for n in nodes}))
        polygons, boxes = {}, []
        for lanelet_id in lanelet_ids:
            poly = np.array([[p.x, p.y] for p in lmap.map.laneletLayer[lanelet_id].polygon2d()], dtype=float)
            polygons[lanelet_id] = poly.reshape(-1, 2)
            both = np.vstack([polygons[lanelet_id], lmap.centerlines[lanelet_id]])
            boxes.append([*both.min(axis=0), *both.max(axis=0)])
        nodes_of: dict[int, list[int]] = {}
        for i, (lanelet_id, _) in enumerate(nodes):
            nodes_of.setdefault(lanelet_id, []).append(i)

        relation: dict[tuple[int, int], str] = {}

        def add(i: int, other, kind: str) -> None:
            if other is None:
                return
            j = index.get((int(other.id), bool(other.inverted())))
            if j is None or j == i:
                return
            old = relation.get((i, j))
            if old is None or _RELATION_COSTS[kind] < _RELATION_COSTS[old]:
                relation[(i, j)] = kind

        for i, obj in enumerate(objects):
            for nxt in graph.following(obj):
                add(i, nxt, "successor")
            add(i, graph.left(obj), "left")
            add(i, graph.right(obj), "right")
            add(i, graph.adjacentLeft(obj), "adjacent_left")
            add(i, graph.adjacentRight(obj), "adjacent_right")
        k = len(nodes)
        if relation:
            ij = np.array(list(relation), dtype=np.int64)
            cost = np.array([_RELATION_COSTS[v] for v in relation.values()])
            csr = csr_matrix((cost, (ij[:, 0], ij[:, 1])), shape=(k, k))
        else:
            csr = csr_matrix((k, k))
        return cls(nodes=tuple(nodes), lines=tuple(lines), cums=tuple(cums), lanelet_ids=lanelet_ids,
                   polygons=polygons, boxes=np.array(boxes, dtype=float).reshape(-1, 4),
                   nodes_of={key: tuple(v) for key, v in nodes_of.items()}, graph=csr, relation=relation)


@dataclass(frozen=True)
class RouteMatch:
    """The lanelet route a track drove (`match_route`).

    Attributes
    ----------
    lanelet_ids : tuple[int, ...]         lanelets in driving order (one appears twice if the track came back)
    inverted : tuple[bool, ...]           per lanelet: driven against its own direction
    relations : tuple[str, ...]           how each lanelet was entered from the one before: ``"successor"``,
                                          ``"left"``, ``"right"``, ``"adjacent_left"`` or ``"adjacent_right"``
    centerline : numpy.ndarray            (P, 2) x, y [m]: the route's centerlines, joined where the track changes lane
    point_route_index : numpy.ndarray     (n,) int: index in ``lanelet_ids`` of each point; -1 off-map or unconnected
    offsets : numpy.ndarray               (n,) distance [m] of each track point from ``centerline``
    max_offset : float                    the ``max_offset`` [m] of the match
    n_off_map : int                       points farther than ``max_offset`` from every lanelet and outside every one
    unconnected : numpy.ndarray           (n,) bool: on-map points no path through the routing graph joins to the route
    """

    lanelet_ids: tuple[int, ...]
    inverted: tuple[bool, ...]
    relations: tuple[str, ...]
    centerline: np.ndarray = field(repr=False)
    point_route_index: np.ndarray = field(repr=False)
    offsets: np.ndarray = field(repr=False)
    max_offset: float
    n_off_map: int
    unconnected: np.ndarray = field(default=None, repr=False)  # type: ignore[arg-type]

    def __post_init__(self) -> None:
        if self.unconnected is None:
            object.__setattr__(self, "unconnected", np.zeros(len(self.point_route_index), dtype=bool))

    @property
    def n_unconnected(self) -> int:
        """On-map points left out of the route (see ``unconnected``)."""
        return int(np.count_nonzero(self.unconnected))

    @property
    def fraction_within(self) -> float:
        """Fraction of the track's points within ``max_offset`` of ``centerline``."""
        return float(np.mean(self.offsets <= self.max_offset))


def match_route(lmap: LaneletMap, xy, *, max_offset: float = 3.0, psi=None) -> RouteMatch:
    """Find the sequence of lanelets a track drove, by a Viterbi search over candidate lanelets (file-formats page).

    Parameters
    ----------
    lmap : LaneletMap                  from `load_map`
    xy : array_like (n, 2)             track positions x, y [m] in the map frame, in time order
    max_offset : float                 largest distance [m] from a centerline at which a point is on that lanelet
    psi : array_like (n,), optional    heading [rad]; default: the direction of motion over +-2 points

    Returns
    -------
    match : RouteMatch                 ValueError for malformed ``xy`` or ``psi``, ``max_offset`` <= 0, or every
                                       point off-map
    """
    from scipy.sparse.csgraph import dijkstra

    xy = np.asarray(xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) == 0:
        raise ValueError(f"xy must have shape (n, 2) with n >= 1, got {xy.shape}")
    if not np.all(np.isfinite(xy)):
        raise ValueError(f"xy has {np.count_nonzero(~np.isfinite(xy).all(axis=1))} non-finite rows")
    if not (math.isfinite(max_offset) and max_offset > 0):
        raise ValueError(f"max_offset must be a positive number of metres, got {max_offset!r}")
    n = len(xy)
    direction = _directions(xy, psi)

    idx = lmap._index
    # candidates: per node, the points near it, with emission cost and foot-point arc length
    emission = np.full((n, len(idx.nodes)), np.inf)
    lo = xy.min(axis=0) - max_offset
    hi = xy.max(axis=0) + max_offset
    for b, lanelet_id in enumerate(idx.lanelet_ids):
        xmin, ymin, xmax, ymax = idx.boxes[b]
        if xmax < lo[0] or ymax < lo[1] or xmin > hi[0] or ymin > hi[1]:
            continue
        near = ((xy[:, 0] >= xmin - max_offset) & (xy[:, 0] <= xmax + max_offset)
                & (xy[:, 1] >= ymin - max_offset) & (xy[:, 1] <= ymax + max_offset))
        if not near.any():
            continue
        pts = xy[near]
        inside = _inside(pts, idx.polygons[lanelet_id])
        for node in idx.nodes_of[lanelet_id]:
            d, _, tangent = _project(pts, idx.lines[node], idx.cums[node])
            ok = (d <= max_offset) | inside
            cost = (d / max_offset) ** 2
            dirs = direction[near]
            has_dir = np.isfinite(dirs[:, 0])
            cos = np.einsum("mk,mk->m", np.where(has_dir[:, None], dirs, 0.0), tangent)
            cost = cost + np.where(has_dir, _HEADING_WEIGHT * (1.0 - cos) / 2.0, 0.0)
            emission[np.flatnonzero(near)[ok], node] = cost[ok]

    on_map = np.flatnonzero(np.isfinite(emission).any(axis=1))
    n_off = n - len(on_map)
    if len(on_map) == 0:
        raise ValueError(
            f"all {n} of {n} points are off-map: more than {max_offset} m from every lanelet centerline "
            f"and outside every lanelet of {lmap.path.name}"
        )
    cands = [np.flatnonzero(np.isfinite(emission[t])) for t in on_map]
    sources = np.unique(np.concatenate(cands))
    dist, pred = dijkstra(idx.graph, directed=True, indices=sources, return_predecessors=True)
    row = {int(s): r for r, s in enumerate(sources)}
    matched = _viterbi_with_skips(emission[on_map][:, sources], dist[:, sources], _COST_UNCONNECTED)
    keep = matched >= 0
    unconnected = np.zeros(n, dtype=bool)
    unconnected[on_map[~keep]] = True
    on_map = on_map[keep]
    path_nodes = [int(sources[m]) for m in matched[keep]]

    # expand into the route, filling in lanelets between consecutive points from the graph
    route = [path_nodes[0]]
    relations: list[str] = []
    switch: list[np.ndarray | None] = [None]  # per route entry: where it was entered by a lateral move
    point_route_index = np.full(n, -1, dtype=np.int64)
    point_route_index[on_map[0]] = 0
    for step in range(1, len(on_map)):
        u, v = path_nodes[step - 1], path_nodes[step]
        if u != v:
            chain = [v]
            p = pred[row[u]]
            while chain[-1] != u:
                chain.append(int(p[chain[-1]]))
            chain.reverse()
            crossing = 0.5 * (xy[on_map[step - 1]] + xy[on_map[step]])
            for a, b in zip(chain[:-1], chain[1:]):
                kind = idx.relation[(a, b)]
                route.append(b)
                relations.append(kind)
                switch.append(None if kind == "successor" else crossing)
        point_route_index[on_map[step]] = len(route) - 1

    centerline = _route_centerline(idx, route, switch)
    offsets, _, _ = _project(xy, centerline, _arc_lengths(centerline))
    return RouteMatch(
        lanelet_ids=tuple(idx.nodes[r][0] for r in route),
        inverted=tuple(idx.nodes[r][1] for r in route),
        relations=tuple(relations),
        centerline=centerline,
        point_route_index=point_route_index,
        offsets=offsets,
        max_offset=float(max_offset),
        n_off_map=int(n_off),
        unconnected=unconnected,
    )


def _viterbi_with_skips(emission: np.ndarray, dist: np.ndarray, skip_cost: float) -> np.ndarray:
    """The cheapest assignment of points to nodes, where a point may also be left out (the state is the node of the
    last matched point, so a left-out point does not break the chain).

    Parameters
    ----------
    emission : array (T, S)   cost of point t on node j; inf where j is not a candidate of t
    dist : array (S, S)       cost of moving from node i to node j (0 on the diagonal, inf without a path)
    skip_cost : float         cost of leaving one point out

    Returns
    -------
    nodes : array (T,) int    the node of each point, -1 where left out (at least one matched if any has a candidate)
    """
    T, S = emission.shape
    none = S  # state: no point matched yet
    cost = np.full(S + 1, np.inf)
    cost[none] = 0.0
    back = np.full((T, S + 1), -1, dtype=np.int64)  # matched from this state; -1: point t left out
    for t in range(T):
        cand = np.flatnonzero(np.isfinite(emission[t]))
        skipped = cost + skip_cost
        new = skipped.copy()
        if len(cand):
            trans = np.vstack([cost[:S, None] + dist[:, cand], np.full((1, len(cand)), cost[none])])
            best = np.argmin(trans, axis=0)
            matched = trans[best, np.arange(len(cand))] + emission[t, cand]
            take = matched <= skipped[cand]
            new[cand[take]] = matched[take]
            back[t, cand[take]] = best[take]
        cost = new
    out = np.full(T, -1, dtype=np.int64)
    if not np.isfinite(cost[:S]).any():
        return out
    state = int(np.argmin(cost[:S]))
    for t in range(T - 1, -1, -1):
        if state == none:
            break
        prev = int(back[t, state])
        if prev >= 0:
            out[t] = state
            state = prev
    return out


def _directions(xy: np.ndarray, psi) -> np.ndarray:
    """Unit direction of travel per point (n, 2); rows of NaN where unknown."""
    n = len(xy)
    if psi is not None:
        psi = np.asarray(psi, dtype=float)
        if psi.shape != (n,):
            raise ValueError(f"psi must have shape ({n},) like xy, got {psi.shape}")
        if not np.all(np.isfinite(psi)):
            raise ValueError(f"psi has {np.count_nonzero(~np.isfinite(psi))} non-finite values")
        return np.column_stack([np.cos(psi), np.sin(psi)])
    i = np.arange(n)
    disp = xy[np.minimum(i + _HEADING_WINDOW, n - 1)] - xy[np.maximum(i - _HEADING_WINDOW, 0)]
    norm = np.hypot(*disp.T)
    moving = norm >= _MIN_MOTION
    out = np.full((n, 2), np.nan)
    out[moving] = disp[moving] / norm[moving, None]
    return out


def _route_centerline(idx: _MatchIndex, route: Sequence[int], switch: Sequence[np.ndarray | None]) -> np.ndarray:
    """Concatenate route centerlines; at lateral moves cut both lanes where the track crossed."""
    start = [0.0] * len(route)
    end = [float(idx.cums[r][-1]) for r in route]
    for k in range(1, len(route)):
        if switch[k] is None:
            continue
        q = switch[k][None, :]  # type: ignore[index]
        a, b = route[k - 1], route[k]
        end[k - 1] = float(_project(q, idx.lines[a], idx.cums[a])[1][0])
        start[k] = float(_project(q, idx.lines[b], idx.cums[b])[1][0])
    parts = [_slice(idx.lines[r], idx.cums[r], start[k], max(start[k], end[k])) for k, r in enumerate(route)]
    return _drop_duplicates(np.vstack(parts))


# ----------------------------------------------------------------------------------------------
# writing
# ----------------------------------------------------------------------------------------------

def write_map(
    centerlines: Mapping[str, np.ndarray],
    successors: Mapping[str, Sequence[str]],
    path,
    *,
    lane_width: float = 3.5,
) -> dict[str, int]:
    """Write lanes of a simulated scene as a Lanelet2 OSM map in the INTERACTION frame (file-formats page).

    Parameters
    ----------
    centerlines : mapping str -> array_like (P, 2)   lane name -> centerline x, y [m] in driving direction, P >= 2;
                                                     lanelet ids are 1, 2, ... in this order
    successors : mapping str -> sequence of str      lane name -> the lanes that follow it (within `JOINT_TOLERANCE`)
    path : str or os.PathLike                        the ``.osm`` file, written atomically
    lane_width : float                               distance [m] between a lane's boundaries, > 0

    Returns
    -------
    ids : dict[str, int]                             lane name -> lanelet id (`LaneletMap.ids_by_name`); ValueError
                                                     for malformed lanes, or unknown or distant successors
    """
    lanelet2 = _lanelet2()
    if not (math.isfinite(lane_width) and lane_width > 0):
        raise ValueError(f"lane_width must be a positive number of metres, got {lane_width!r}")
    lines = _checked_centerlines(centerlines)
    links = _checked_successors(successors, lines)
    half = 0.5 * lane_width

    # joints: union of lane ends and the starts of their successors
    for a, b in links:
        gap = float(np.hypot(*(lines[a][-1] - lines[b][0])))
        if gap > JOINT_TOLERANCE:
            raise ValueError(
                f"lane {a!r} ends {gap:.3f} m from the start of its successor {b!r}; "
                f"they must meet within {JOINT_TOLERANCE} m"
            )
    joints = joined_ends(links)
    members = joint_members(joints)

    def end_tangent(key) -> np.ndarray:
        kind, name = key
        seg = lines[name][1] - lines[name][0] if kind == "start" else lines[name][-1] - lines[name][-2]
        return seg / np.hypot(*seg)

    joint_offset: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}  # root -> (point, left offset)
    for root, keys in members.items():
        tangents = np.array([end_tangent(k) for k in keys])
        mean = tangents.sum(axis=0)
        norm = float(np.hypot(*mean))
        if norm < 1e-6 * len(keys):
            raise ValueError(f"lanes {sorted({k[1] for k in keys})} meet head-on; no boundary can join them")
        mean /= norm
        normal = np.array([-mean[1], mean[0]])
        cos = min(float(np.dot(normal, [-t[1], t[0]])) for t in tangents)
        scale = min(1.0 / max(cos, 1.0 / _MAX_MITER), _MAX_MITER)
        kind, name = keys[0]
        point = lines[name][0] if kind == "start" else lines[name][-1]
        joint_offset[root] = (point, half * scale * normal)

    names = list(lines)
    lanelet_ids = {name: i + 1 for i, name in enumerate(names)}
    next_id = len(names) + 1
    way_ids = {}
    for name in names:
        way_ids[name] = (next_id, next_id + 1)  # left, right
        next_id += 2

    proj = projector()
    node_xy: dict[int, np.ndarray] = {}
    joint_nodes: dict[tuple[str, str], tuple[int, int]] = {}
    way_nodes: dict[str, tuple[list[int], list[int]]] = {}

    def new_node(p: np.ndarray) -> int:
        nonlocal next_id
        node_xy[next_id] = p
        next_id += 1
        return next_id - 1

    for name in names:
        line = lines[name]
        offsets = _left_offsets(line, half)
        left, right = [], []
        for i, p in enumerate(line):
            key = (("start", name) if i == 0
                   else ("end", name) if i == len(line) - 1 else None)
            if key is not None and key in joints:
                root = joints[key]
                if root not in joint_nodes:
                    jp, jo = joint_offset[root]
                    joint_nodes[root] = (new_node(jp + jo), new_node(jp - jo))
                lid, rid = joint_nodes[root]
            else:
                lid, rid = new_node(p + offsets[i]), new_node(p - offsets[i])
            left.append(lid)
            right.append(rid)
        way_nodes[name] = (left, right)

    out = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6" generator="pirl_sim">']
    for node_id, p in node_xy.items():
        gps = proj.reverse(lanelet2.core.BasicPoint3d(float(p[0]), float(p[1]), 0.0))
        out.append(f'  <node id="{node_id}" visible="true" version="1" lat="{gps.lat:.12f}" lon="{gps.lon:.12f}" />')
    for name in names:
        for way_id, refs in zip(way_ids[name], way_nodes[name]):
            out.append(f'  <way id="{way_id}" visible="true" version="1">')
            out.extend(f'    <nd ref="{r}" />' for r in refs)
            out.append('    <tag k="type" v="line_thin" />')
            out.append('    <tag k="subtype" v="solid" />')
            out.append("  </way>")
    for name in names:
        left_way, right_way = way_ids[name]
        out.append(f'  <relation id="{lanelet_ids[name]}" visible="true" version="1">')
        out.append(f'    <member type="way" ref="{left_way}" role="left" />')
        out.append(f'    <member type="way" ref="{right_way}" role="right" />')
        for k, v in (("type", "lanelet"), ("subtype", "road"), ("location", "urban"), ("one_way", "yes"),
                     ("name", name)):
            out.append(f"    <tag k={quoteattr(k)} v={quoteattr(v)} />")
        out.append("  </relation>")
    out.append("</osm>")
    atomic_write_text(path, "\n".join(out) + "\n")
    return lanelet_ids


def _checked_centerlines(centerlines: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    if not isinstance(centerlines, Mapping) or len(centerlines) == 0:
        raise ValueError("centerlines must be a non-empty mapping of lane name -> (P, 2) array")
    lines = {}
    for name, line in centerlines.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"lane names must be non-empty strings, got {name!r}")
        arr = np.asarray(line, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < 2:
            raise ValueError(f"centerline of lane {name!r} must have shape (P, 2) with P >= 2, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"centerline of lane {name!r} has non-finite values")
        step = np.hypot(*np.diff(arr, axis=0).T)
        if np.any(step <= 1e-9):
            raise ValueError(f"centerline of lane {name!r} repeats a point (after index "
                             f"{int(np.flatnonzero(step <= 1e-9)[0])})")
        lines[name] = arr
    return lines


def _checked_successors(successors: Mapping[str, Sequence[str]], lines: Mapping[str, np.ndarray]):
    links = []  # type: ignore[var-annotated]
    for a, nexts in successors.items():
        if isinstance(nexts, str):
            raise ValueError(f"successors[{a!r}] must be a list of lane names, got the string {nexts!r}")
        unknown = [x for x in [a, *nexts] if x not in lines]
        if unknown:
            raise ValueError(f"successors name lanes without a centerline: {unknown}")
        links.extend((a, b) for b in nexts)
    return links


def _left_offsets(line: np.ndarray, half: float) -> np.ndarray:
    """Per vertex, the vector [m] from the centerline to the left boundary (miter joins)."""
    seg = np.diff(line, axis=0)
    tangent = seg / np.hypot(*seg.T)[:, None]
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    out = np.empty_like(line)
    out[0], out[-1] = normal[0], normal[-1]
    if len(line) > 2:
        mean = normal[:-1] + normal[1:]
        norm = np.hypot(*mean.T)
        bisector = np.divide(mean, norm[:, None], out=normal[1:].copy(), where=norm[:, None] > 1e-9)
        cos = np.einsum("sk,sk->s", bisector, normal[1:])
        scale = 1.0 / np.maximum(cos, 1.0 / _MAX_MITER)
        out[1:-1] = bisector * scale[:, None]
    return half * out
