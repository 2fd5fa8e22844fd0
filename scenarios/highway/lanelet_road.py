"""highway-env roads of real roundabouts: a Lanelet2 map's lanelets as highway-env lanes, its routes as `RouteLanes`.

Each lanelet with a centre line becomes one highway-env lane along that centre line (`CenterlineLane`, the lanelet's
width from its bounds), between two nodes: lanelet ends that the map's routing graph joins (a lanelet's end and its
successors' starts) are one node, as in the SUMO network of the same map
(`pirl_sim.scenarios.sumo.lanelet_network`). Routes are the map's entry-to-exit routes with the ids SUMO uses
(`~pirl_sim.scenarios.lanelet_graph.lanelet_paths`), so a population plan, ``route_weights`` and a
calibrated scenario mean the same in both simulators. The ring is the lanelets on a cycle of the routing graph
(`~pirl_sim.scenarios.lanelet_graph.ring_lanelets`); a route joins it at its first ring lanelet, where the
traffic's gap acceptance applies (`~.traffic.RoundaboutTraffic`). Coordinates stay the map's, so recorded tracks lie
on the simulated lanes.

The road is described in the documentation's "highway-env roundabouts" page (real roundabouts).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .network import RouteLanes

__all__ = ["CenterlineLane", "MapRoad", "lanelet_road", "map_road"]

LaneKey = tuple[str, str]


def _lane_base():
    from highway_env.road.lane import AbstractLane

    return AbstractLane


class CenterlineLane(_lane_base()):  # type: ignore[misc]
    """A highway-env lane along a polyline: its centre line exactly, however short or closely sampled.

    highway-env's own ``PolyLaneFixedWidth`` resamples its points 1 m apart (a lanelet shorter than 1 m cannot be
    built) and projects onto the last sample ahead of a point; this lane projects onto the nearest segment.

    Parameters
    ----------
    points : array_like, shape (P, 2)   x, y [m] in driving direction, P >= 2, consecutive points distinct
    width : float                       [m]
    line_types : tuple of LineType, optional   how highway-env draws its sides (default: not drawn)

    Longitudinal coordinates run along the polyline from its first point [m] and continue along the first and last
    segments beyond the ends; lateral coordinates are positive to the left of the driving direction in the x-right,
    y-up frame (highway-env's convention: ``(-dy, dx)``). The heading [rad] is interpolated between the segments'
    midpoints.
    """

    def __init__(self, points, width: float, line_types=None) -> None:
        from highway_env.road.lane import LineType

        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] != 2 or not np.isfinite(pts).all():
            raise ValueError(f"points must be a finite (P >= 2, 2) array, got shape {pts.shape}")
        seg = np.diff(pts, axis=0)
        lengths = np.hypot(seg[:, 0], seg[:, 1])
        if not (lengths > 0).all():
            raise ValueError("points must not repeat one after another")
        self._p = pts[:-1]
        self._u = seg / lengths[:, None]
        self._len = lengths
        self._s = np.concatenate(([0.0], np.cumsum(lengths)))
        self.length = float(self._s[-1])
        heading = np.unwrap(np.arctan2(self._u[:, 1], self._u[:, 0]))
        self._mid = self._s[:-1] + 0.5 * lengths
        self._heading = heading
        self.width = float(width)
        self.line_types = list(line_types) if line_types is not None else [LineType.NONE, LineType.NONE]
        self.forbidden = False
        self.speed_limit = 20.0
        self.priority = 0

    def _segment(self, longitudinal: float) -> int:
        k = int(np.searchsorted(self._s, longitudinal, side="right")) - 1
        return min(max(k, 0), len(self._len) - 1)

    def position(self, longitudinal: float, lateral: float) -> np.ndarray:
        i = self._segment(longitudinal)
        u = self._u[i]
        return self._p[i] + (longitudinal - self._s[i]) * u + lateral * np.array([-u[1], u[0]])

    def heading_at(self, longitudinal: float) -> float:
        return float(np.interp(longitudinal, self._mid, self._heading))

    def width_at(self, longitudinal: float) -> float:
        return self.width

    def local_coordinates(self, position) -> tuple[float, float]:
        d = np.asarray(position, dtype=float)[:2] - self._p
        along = d[:, 0] * self._u[:, 0] + d[:, 1] * self._u[:, 1]
        t = np.clip(along, 0.0, self._len)
        gap = (d[:, 0] - t * self._u[:, 0]) ** 2 + (d[:, 1] - t * self._u[:, 1]) ** 2
        i = int(np.argmin(gap))
        lon = along[i] if (i == 0 and along[i] < 0) or (i == len(self._len) - 1 and along[i] > self._len[i]) else t[i]
        lat = self._u[i, 0] * d[i, 1] - self._u[i, 1] * d[i, 0]
        return float(self._s[i] + lon), float(lat)

    def to_config(self) -> dict:
        return {"class_path": f"{type(self).__module__}.{type(self).__name__}",
                "config": {"points": self._points().tolist(), "width": self.width}}

    def _points(self) -> np.ndarray:
        return np.vstack([self._p, self._p[-1] + self._len[-1] * self._u[-1]])


@dataclass(frozen=True, eq=False)
class MapRoad:
    """A Lanelet2 map as a highway-env road.

    Attributes
    ----------
    network : highway_env.road.road.RoadNetwork   one lane per lanelet, from node to node
    routes : dict of str to RouteLanes            every entry-to-exit route, by id (sorted)
    ring : frozenset of (str, str)                the lanes (from, to) of the roundabout's ring
    lanelets : dict of str to tuple of int        route id -> its lanelets in driving order
    lane_of : dict of int to (str, str)           lanelet id -> its lane (from, to)
    """

    network: object
    routes: dict[str, RouteLanes]
    ring: frozenset[LaneKey]
    lanelets: dict[str, tuple[int, ...]]
    lane_of: dict[int, LaneKey]


def _node_names(succ: dict[int, list[int]]) -> tuple[dict[int, str], dict[int, str]]:
    """(node of each lanelet's start, node of its end): ``n<k>``, numbered in the order of the sorted lanelet ids."""
    from ..lanelet_graph import node_keys

    start, end = node_keys(succ)
    names: dict = {}
    for lid in sorted(succ):
        for key in (start[lid], end[lid]):
            names.setdefault(key, f"n{len(names)}")
    return {lid: names[start[lid]] for lid in succ}, {lid: names[end[lid]] for lid in succ}


def lanelet_road(lmap) -> MapRoad:
    """The highway-env road of a Lanelet2 map (see the module docstring).

    Parameters
    ----------
    lmap : pirl_sim.io.lanelet2_map.LaneletMap or path

    Returns
    -------
    MapRoad

    Raises
    ------
    ValueError
        If the map has no roundabout (no cycle of lanelets), no entry-to-exit route, two lanelets between the same
        two nodes, or a lanelet off the ring between two ring nodes (the traffic's rules could not tell it from
        the ring).
    """
    from highway_env.road.road import RoadNetwork

    from ..lanelet_graph import lanelet_paths, lanelet_width, loaded_map, ring_lanelets, successors

    lmap = loaded_map(lmap)
    succ = successors(lmap)
    ring_ids = ring_lanelets(lmap)
    if not ring_ids:
        raise ValueError(f"map {lmap.path}: no roundabout: no lanelets form a cycle of the routing graph")
    start, end = _node_names(succ)
    lane_of = {lid: (start[lid], end[lid]) for lid in sorted(succ)}
    seen: dict[LaneKey, int] = {}
    for lid, key in lane_of.items():
        if key in seen:
            raise ValueError(f"map {lmap.path}: lanelets {seen[key]} and {lid} both lead from node {key[0]} to "
                             f"{key[1]}; a highway-env road holds one lane between two nodes here")
        seen[key] = lid
    ring_nodes = {n for lid in ring_ids for n in lane_of[lid]}
    off_ring = [lid for lid, (a, b) in lane_of.items() if lid not in ring_ids and a in ring_nodes and b in ring_nodes]
    if off_ring:
        raise ValueError(f"map {lmap.path}: lanelet(s) {off_ring} lead from the ring back to the ring without being "
                         "part of it; such a map is not supported on highway-env")
    network = RoadNetwork()
    for lid, (a, b) in lane_of.items():
        points = lmap.centerlines[lid]
        keep = np.concatenate(([True], np.hypot(*np.diff(points, axis=0).T) >= 1e-3))
        network.add_lane(a, b, CenterlineLane(points[keep], lanelet_width(lmap, lid)))
    routes: dict[str, RouteLanes] = {}
    lanelets: dict[str, tuple[int, ...]] = {}
    for rid, path in lanelet_paths(lmap):
        lanes = tuple((*lane_of[lid], 0) for lid in path)
        lengths = np.array([network.get_lane(ix).length for ix in lanes])
        offsets = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
        for arr in (lengths, offsets):
            arr.setflags(write=False)
        first_ring = next((k for k, lid in enumerate(path) if lid in ring_ids), None)
        if first_ring is None or first_ring == 0:  # never joins the ring (a bypass), or starts on it
            entry, merge = -1, lanes[0][0]
        else:
            entry, merge = first_ring - 1, lanes[first_ring][0]
        routes[rid] = RouteLanes(rid, lanes, lengths, offsets, entry, merge)
        lanelets[rid] = tuple(path)
    ring = frozenset(lane_of[lid] for lid in ring_ids)
    return MapRoad(network, dict(sorted(routes.items())), ring, dict(sorted(lanelets.items())), lane_of)


def map_road(path) -> MapRoad:
    """`lanelet_road` of the Lanelet2 map at ``path``, built once per version of the file in a process (shared:
    nothing may change it).

    Raises
    ------
    FileNotFoundError, ValueError
        As `pirl_sim.io.lanelet2_map.load_map` and `lanelet_road` raise them.
    """
    from ..lanelet_graph import map_file_version

    return _map_road(*map_file_version(path))


@functools.lru_cache(maxsize=4)
def _map_road(path: str, mtime_ns: int, size: int) -> MapRoad:
    return lanelet_road(path)
