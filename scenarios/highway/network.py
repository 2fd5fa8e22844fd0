"""highway-env's roundabout as routes: the road network, the route catalogue, reference paths and the map.

The road is highway-env's ``roundabout-generic-v0`` with one ring lane (:func:`build_network` of a
`RoundaboutGeometry`: ring radius [m], four arms). Arms are numbered in driving order round the ring
(:data:`ARMS`: 0 south, 1 east, 2 north, 3 west) and routes carry the SUMO scenario's ids (``"arm{i}_to_arm{j}"``,
:func:`route_catalogue`), so one population plan means the same in both simulators. :func:`route_set` gives the
routes' smoothed reference paths (``smoothing``, ``speed_smoothing`` [m]). Coordinates are highway-env's (x right,
y down on its screen) and recordings keep them.

The geometry and its kinks are described in the documentation's "highway-env roundabouts" page.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from types import SimpleNamespace

import numpy as np

from pirl_sim.paths import DEFAULT_SMOOTHING, ReferencePath

from ..drivers import ROUTE_SPACING, RouteSet
from ..planning import route_id

__all__ = [
    "ARMS",
    "ARM_NAMES",
    "LANE_WIDTH",
    "RoundaboutGeometry",
    "RouteLanes",
    "build_network",
    "route_catalogue",
    "route_polyline",
    "route_set",
    "route_path",
    "lane_curvature",
    "lane_graph",
    "lane_name",
    "ring_lanes",
]

ARMS: tuple[str, ...] = ("s", "e", "n", "w")  #: highway-env's arm letters, in driving order round the ring
ARM_NAMES: tuple[str, ...] = ("south", "east", "north", "west")
LANE_WIDTH = 4.0  #: [m] highway-env's ``AbstractLane.DEFAULT_WIDTH``
_SAMPLE_STEP = 0.5  # [m] polyline spacing when lanes are sampled
_MIN_RADIUS, _MAX_RADIUS = 10.0, 80.0  # [m] radii for which the generic geometry stays sensible

LaneIndex = tuple[str, str, int]


@dataclass(frozen=True)
class RoundaboutGeometry:
    """The roundabout: highway-env's ``roundabout-generic-v0`` with one ring lane.

    Attributes
    ----------
    radius : float
        Ring centerline radius [m], in [10, 80] (highway-env's ``roundabout_radius``; default 20 as there).
    """

    radius: float = 20.0

    def __post_init__(self) -> None:
        r = self.radius
        if isinstance(r, bool) or not isinstance(r, (int, float, np.integer, np.floating)) or not math.isfinite(r) \
                or not _MIN_RADIUS <= r <= _MAX_RADIUS:
            raise ValueError(f"radius must be a number of metres in [{_MIN_RADIUS:g}, {_MAX_RADIUS:g}], got {r!r}")
        object.__setattr__(self, "radius", float(r))


def build_network(geometry: RoundaboutGeometry | None = None):
    """highway-env's :class:`~highway_env.road.road.RoadNetwork` of ``roundabout-generic-v0``, one ring lane.

    Built by the environment's own ``_make_road`` (``RoundaboutGenericEnv``), so the lanes are exactly
    highway-env's.
    """
    from highway_env.envs.roundabout_env import RoundaboutGenericEnv

    geometry = RoundaboutGeometry() if geometry is None else geometry
    if not isinstance(geometry, RoundaboutGeometry):
        raise TypeError(f"geometry must be a RoundaboutGeometry, got {type(geometry).__name__}")
    stub = SimpleNamespace(config={"roundabout_radius": geometry.radius, "roundabout_lanes": 1,
                                   "show_trajectories": False, "neighbour_vehicles_connected_lanes": False},
                           np_random=None)
    RoundaboutGenericEnv._make_road(stub)
    return stub.road.network


def lane_name(index: LaneIndex | tuple[str, str]) -> str:
    """Map name of a highway-env lane: ``"<from>_<to>"`` (one lane per road here)."""
    return f"{index[0]}_{index[1]}"


@dataclass(frozen=True, eq=False)
class RouteLanes:
    """One route through the network as highway-env lanes, with a route coordinate (arc length of the lanes).

    Attributes
    ----------
    route_id : str
    lanes : tuple of LaneIndex      ``(from, to, 0)`` in driving order
    lengths : numpy.ndarray         each lane's length [m] (highway-env's ``lane.length``: the chord for sine lanes)
    offsets : numpy.ndarray         route coordinate [m] of each lane's start (cumulative lengths)
    entry_lane : int                position in ``lanes`` of the entry's S-bend (ends where the route joins the ring);
                                    -1: the route never enters the ring from an entry (a bypass)
    merge_node : str                the ring node where the route joins the ring (e.g. ``"se"``; a bypass: its first
                                    node)
    """

    route_id: str
    lanes: tuple[LaneIndex, ...]
    lengths: np.ndarray
    offsets: np.ndarray
    entry_lane: int
    merge_node: str

    @cached_property
    def position_of(self) -> dict[tuple[str, str], int]:
        """(from, to) -> position in :attr:`lanes`."""
        return {(a, b): k for k, (a, b, _) in enumerate(self.lanes)}

    @cached_property
    def start_pos(self) -> dict[str, int]:
        """Node -> position in :attr:`lanes` of the lane starting there."""
        return {a: k for k, (a, _, _) in enumerate(self.lanes)}

    @property
    def length(self) -> float:
        """Route length [m] in the route coordinate."""
        return float(self.offsets[-1] + self.lengths[-1])

    @property
    def merge_s(self) -> float:
        """Route coordinate [m] of the merge node (end of the entry lane)."""
        return float(self.offsets[self.entry_lane + 1])


def route_catalogue(network, *, u_turns: bool = False) -> dict[str, RouteLanes]:
    """Every entry-to-exit route, keyed by :func:`~pirl_sim.scenarios.planning.route_id`.

    Ordered by entry arm, then by how far round the ring the exit is (first exit first), as
    :func:`pirl_sim.scenarios.sumo.network.routes`: with 4 arms the right turn, the through route and the
    left turn of each entry. ``u_turns=True`` adds the full turn back to the entry's own arm.
    """
    out: dict[str, RouteLanes] = {}
    n = len(ARMS)
    offsets = range(1, n + 1) if u_turns else range(1, n)
    for i in range(n):
        for k in offsets:
            j = (i + k) % n
            nodes = _ring_path(network, ARMS[i], ARMS[j])
            lanes = tuple((nodes[m], nodes[m + 1], 0) for m in range(len(nodes) - 1))
            lengths = np.array([network.get_lane(ix).length for ix in lanes])
            offs = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
            entry = 1  # "<a>er" -> "<a>es" (straight), then "<a>es" -> "<a>e" (S-bend)
            rid = route_id(i, j)
            for arr in (lengths, offs):
                arr.setflags(write=False)
            out[rid] = RouteLanes(rid, lanes, lengths, offs, entry, lanes[entry][1])
    return out


def ring_lanes(network) -> frozenset[tuple[str, str]]:
    """The lanes (from, to) of a road's roundabout ring: those on a cycle of the lane graph (on highway-env's
    roundabout the lanes between its two-letter ring nodes; on a map's road its ring lanelets)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    lanes = [(a, b) for a, tos in network.graph.items() for b in tos]
    nodes = sorted({n for lane in lanes for n in lane})
    index = {n: k for k, n in enumerate(nodes)}
    rows, cols = [index[a] for a, _ in lanes], [index[b] for _, b in lanes]
    graph = coo_matrix((np.ones(len(lanes)), (rows, cols)), shape=(len(nodes), len(nodes)))
    _, label = connected_components(graph, directed=True, connection="strong")
    return frozenset((a, b) for a, b in lanes if a != b and label[index[a]] == label[index[b]])


def _ring_path(network, entry: str, exit_: str) -> list[str]:
    """Nodes from entry arm ``entry`` round the ring to exit arm ``exit_`` (a full turn when they are equal)."""
    start = [f"{entry}er", f"{entry}es", f"{entry}e"]
    node = start[-1]
    nodes = list(start)
    target = f"{exit_}x"
    for _ in range(2 * len(ARMS) + 1):
        nxt = [t for t in network.graph[node] if len(t) == 2]  # the ring: two-letter nodes
        if len(nxt) != 1:
            raise ValueError(f"ring node {node!r} has ring successors {nxt}; expected exactly one")
        node = nxt[0]
        nodes.append(node)
        if node == target:
            return nodes + [f"{exit_}xs", f"{exit_}xr"]
    raise ValueError(f"no way round the ring from arm {entry!r} to arm {exit_!r}")


def _lane_points(lane, step: float = _SAMPLE_STEP) -> np.ndarray:
    n = max(2, int(math.ceil(lane.length / step)) + 1)
    return np.array([lane.position(s, 0.0) for s in np.linspace(0.0, lane.length, n)])


def route_polyline(network, route: RouteLanes, step: float = _SAMPLE_STEP) -> np.ndarray:
    """The route's lane centerlines end to end, (P, 2) [m], points about ``step`` apart (joints once)."""
    parts = [_lane_points(network.get_lane(ix), step) for ix in route.lanes]
    return np.vstack([parts[0]] + [p[1:] for p in parts[1:]])


def lane_curvature(network, route: RouteLanes, u) -> np.ndarray:
    """Unsigned curvature [1/m] of the route's lanes at route coordinates ``u`` [m], lane by lane.

    Each lane's own curvature (1/radius on the ring's ``CircularLane`` s, numerically from
    ``heading_at`` on the entries' and exits' ``SineLane`` s, 0 on straight lanes); the heading jumps where
    lanes meet (see the module docstring) are not curvature of any lane and are left out.
    """
    u = np.atleast_1d(np.asarray(u, dtype=float))
    k = np.clip(np.searchsorted(route.offsets, u, side="right") - 1, 0, len(route.lanes) - 1)
    out = np.zeros(u.shape)
    h = 0.05  # [m] central differences
    for m in np.unique(k):
        lane = network.get_lane(route.lanes[m])
        loc = np.clip(u[k == m] - route.offsets[m], h, lane.length - h)
        dpsi = np.array([lane.heading_at(x + h) - lane.heading_at(x - h) for x in loc])
        dpsi = (dpsi + np.pi) % (2 * np.pi) - np.pi
        arc = np.array([np.hypot(*(lane.position(x + h, 0.0) - lane.position(x - h, 0.0))) for x in loc])
        out[k == m] = np.abs(dpsi) / arc
    return out


def route_path(network, route: RouteLanes, *, smoothing: float = DEFAULT_SMOOTHING) -> ReferencePath:
    """The route's reference path: geometry from its lanes, curvature for the desired speed from its lanes.

    ``x, y, heading`` (what Frenet projections use) are the lanes' centerlines sampled every 0.5 m and
    smoothed with ``smoothing`` [m] (:meth:`pirl_sim.paths.ReferencePath.from_polyline`). ``kappa``, which
    only sets the desired speed, is :func:`lane_curvature` (unsigned) at each row, the path's arc length
    mapped onto the route coordinate in proportion: smoothing the geometry would turn each 66 degree
    heading jump into a spike of opposite sign to the ring's curvature, which, smoothed again for the
    desired speed, cancels the ring's curvature and puts a speed-limit peak of ~13.8 m/s where entries
    join the ring (measured). This path's ``kappa`` is therefore **not** the curvature of its ``x, y``
    where lanes meet at an angle.
    """
    geo = ReferencePath.from_polyline(route_polyline(network, route), smoothing=smoothing)
    kappa = lane_curvature(network, route, geo.s * (route.length / geo.length))
    return ReferencePath(s=geo.s, x=geo.x, y=geo.y, heading=geo.heading, kappa=kappa)


def route_set(network, routes: Mapping[str, RouteLanes] | Sequence[RouteLanes], *,
              smoothing: float = DEFAULT_SMOOTHING, speed_smoothing: float = 0.0,
              spacing: float = ROUTE_SPACING) -> RouteSet:
    """Reference paths (:func:`route_path`) of ``routes`` on one global arc-length axis
    (:class:`~pirl_sim.scenarios.drivers.RouteSet`).

    ``smoothing`` [m] smooths each path's geometry, ``speed_smoothing`` [m] the curvature that sets the
    desired speed (see :class:`~pirl_sim.scenarios.drivers.RouteSet`).
    """
    items = list(routes.values()) if isinstance(routes, Mapping) else list(routes)
    paths = tuple(route_path(network, r, smoothing=smoothing) for r in items)
    return RouteSet(tuple(r.route_id for r in items), paths, spacing, speed_smoothing)


def lane_graph(network) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
    """Every lane as a centerline with its successors: what :func:`pirl_sim.io.lanelet2_map.write_map` takes.

    Returns
    -------
    centerlines : dict of str to numpy.ndarray
        :func:`lane_name` -> (P, 2) x, y [m] in driving direction, points ~0.5 m apart, sorted by name.
    successors : dict of str to list of str
        Lane name -> names of the lanes starting where it ends (sorted), for lanes with successors.
    """
    lines: dict[str, np.ndarray] = {}
    succ: dict[str, list[str]] = {}
    for a, tos in network.graph.items():
        for b, lanes in tos.items():
            lines[lane_name((a, b))] = _lane_points(lanes[0])
            nxt = sorted(lane_name((b, c)) for c in network.graph.get(b, {}))
            if nxt:
                succ[lane_name((a, b))] = nxt
    return dict(sorted(lines.items())), dict(sorted(succ.items()))
