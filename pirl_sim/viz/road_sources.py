"""Roads to draw from the project's maps: Lanelet2 OSM maps, SUMO networks and highway-env's roundabout.

Each builder returns a :class:`pirl_sim.viz.road.Road` in the frame of the tracks recorded on that road:
the INTERACTION frame for Lanelet2 maps (:func:`pirl_sim.io.lanelet2_map.load_map`), SUMO's network
coordinates, highway-env's coordinates (y down on its own screen; drawn here with y up). The map libraries
(lanelet2, sumolib, highway-env) are imported only by the builder that needs them.
"""

from __future__ import annotations

import math
import os

import numpy as np

from .road import Road

__all__ = ["road_from_lanelet2", "road_from_sumo", "road_from_highway", "offset_polyline"]

_HIGHWAY_STEP = 0.5  # [m] spacing of the points sampled along highway-env lanes
_MAX_MITER = 4.0  # largest factor by which an offset vertex is pushed out at a sharp corner


def offset_polyline(line, offset: float) -> np.ndarray:
    """The polyline moved sideways by ``offset`` [m], positive to the left of its direction.

    Parameters
    ----------
    line : array_like (P, 2)     x, y [m], P >= 2, consecutive points distinct (else ValueError)
    offset : float               lateral distance [m]; at a vertex the segments' normals are averaged (mitred,
                                 limited to 4x at sharp corners)

    Returns
    -------
    moved : numpy.ndarray (P, 2)   [m]
    """
    pts = np.asarray(line, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ValueError(f"line must be a (P, 2) polyline with P >= 2, got shape {np.shape(line)}")
    seg = np.diff(pts, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    if np.any(length <= 0):
        raise ValueError(f"line has coincident consecutive points (at index {int(np.argmin(length))})")
    normal = np.column_stack([-seg[:, 1], seg[:, 0]]) / length[:, None]  # left normals of the segments
    vert = np.vstack([normal[:1], normal[:-1] + normal[1:], normal[-1:]])
    norm = np.hypot(vert[:, 0], vert[:, 1])
    norm[norm < 1e-12] = 1.0
    vert /= norm[:, None]
    # mitre: scale so that the offset is `offset` from both neighbouring segments
    cos_half = np.ones(len(pts))
    cos_half[1:-1] = np.einsum("ij,ij->i", vert[1:-1], normal[:-1])
    scale = 1.0 / np.clip(cos_half, 1.0 / _MAX_MITER, None)
    return pts + offset * scale[:, None] * vert


def _drop_duplicates(pts: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    keep = np.concatenate(([True], np.hypot(*np.diff(pts, axis=0).T) > tol))
    return pts[keep]


# ----------------------------------------------------------------------------------------------
# Lanelet2
# ----------------------------------------------------------------------------------------------

def _lanelet_style(attributes) -> str:
    kind = str(attributes["type"]) if "type" in attributes else ""
    subtype = str(attributes["subtype"]) if "subtype" in attributes else ""
    if kind == "virtual" or not kind:
        return "virtual"
    if "dashed" in subtype:
        return "dashed"
    return "solid"


def road_from_lanelet2(lanelet_map) -> Road:
    """The lanes of a Lanelet2 map: every lanelet's left and right bound, and its centre line.

    Parameters
    ----------
    lanelet_map : str, os.PathLike or pirl_sim.io.lanelet2_map.LaneletMap   an INTERACTION-style ``.osm`` file
        (read with `pirl_sim.io.lanelet2_map.load_map`) or a map it returned

    Returns
    -------
    road : Road
        A bound shared by two lanelets appears once, styled by its tags ("Drawing scenes" page). ValueError for a
        map without lanelets or unreadable, TypeError, ImportError without lanelet2 (``pirl_sim[maps]``).
    """
    from pirl_sim.io.lanelet2_map import LaneletMap, load_map

    if isinstance(lanelet_map, (str, os.PathLike)):
        lanelet_map = load_map(lanelet_map)  # raises ValueError for a map without lanelets
    if not isinstance(lanelet_map, LaneletMap):
        raise TypeError("lanelet_map must be a path to a Lanelet2 .osm file or a pirl_sim.io.lanelet2_map.LaneletMap, "
                        f"got {type(lanelet_map).__name__}")
    layer = lanelet_map.map.laneletLayer
    if len(layer) == 0:
        raise ValueError(f"{lanelet_map.path}: the map has no lanelets, so there are no lanes to draw")
    boundaries, styles, seen = [], [], set()
    for ll in sorted(layer, key=lambda x: x.id):
        for bound in (ll.leftBound, ll.rightBound):
            if bound.id in seen:
                continue
            seen.add(bound.id)
            pts = _drop_duplicates(np.array([[p.x, p.y] for p in bound], dtype=float).reshape(-1, 2))
            if len(pts) >= 2:
                boundaries.append(pts)
                styles.append(_lanelet_style(bound.attributes))
    centerlines = [line for _, line in sorted(lanelet_map.centerlines.items()) if len(line) >= 2]
    return Road(tuple(boundaries), tuple(styles), tuple(centerlines), source=str(lanelet_map.path))


# ----------------------------------------------------------------------------------------------
# SUMO
# ----------------------------------------------------------------------------------------------

def road_from_sumo(net, *, internal: bool = True) -> Road:
    """The lanes of a SUMO network: each lane's centre line and its two borders (lane width from the network).

    Parameters
    ----------
    net : str, os.PathLike, pirl_sim.scenarios.sumo.NetworkFiles or sumolib.net.Net   a ``.net.xml`` file or network
    internal : bool                    draw junction-internal lanes too, with virtual borders

    Returns
    -------
    road : Road                        outer borders of an edge ``"solid"``, borders between its lanes ``"dashed"``;
                                       ValueError without lanes, ImportError without sumolib (``pirl_sim[sumo]``)
    """
    from pirl_sim.scenarios.sumo.network import load_net

    net = load_net(net)
    boundaries, styles, centerlines = [], [], []
    for edge in sorted(net.getEdges(withInternal=internal), key=lambda e: e.getID()):
        is_internal = edge.getID().startswith(":")
        lanes = edge.getLanes()
        for lane in lanes:
            pts = _drop_duplicates(np.asarray(lane.getShape(), dtype=float)[:, :2], 1e-3)
            if len(pts) < 2:
                continue
            centerlines.append(pts)
            half = 0.5 * float(lane.getWidth())
            index = lane.getIndex()
            if is_internal:
                sides = [(half, "virtual"), (-half, "virtual")]
            else:
                sides = [(half, "solid" if index == len(lanes) - 1 else "dashed")]
                if index == 0:
                    sides.append((-half, "solid"))
            for offset, style in sides:
                boundaries.append(offset_polyline(pts, offset))
                styles.append(style)
    if not centerlines:
        raise ValueError("the SUMO network has no lanes to draw")
    return Road(tuple(boundaries), tuple(styles), tuple(centerlines), source="SUMO network")


# ----------------------------------------------------------------------------------------------
# highway-env
# ----------------------------------------------------------------------------------------------

def road_from_highway(network=None, *, geometry=None) -> Road:
    """The lanes of highway-env's roundabout (`pirl_sim.scenarios.highway.network`).

    Parameters
    ----------
    network : highway_env.road.road.RoadNetwork, optional   default: the scenario's roundabout of ``geometry``
    geometry : pirl_sim.scenarios.highway.network.RoundaboutGeometry, optional   the roundabout to build without
        ``network`` (default radius 20 m); not with ``network``

    Returns
    -------
    road : Road      lane borders every 0.5 m at +-half the lane's width, styled by highway-env's line types;
                     ValueError / TypeError for both arguments or no lanes, ImportError without highway-env
    """
    from highway_env.road.lane import LineType

    if network is not None and geometry is not None:
        raise ValueError("give either network or geometry, not both")
    if network is None:
        from pirl_sim.scenarios.highway.network import build_network

        network = build_network(geometry)
    graph = getattr(network, "graph", None)
    if not isinstance(graph, dict):
        raise TypeError(f"network must be a highway-env RoadNetwork, got {type(network).__name__}")
    style_of = {LineType.STRIPED: "dashed", LineType.NONE: "virtual"}
    boundaries, styles, centerlines = [], [], []
    for a in sorted(graph):
        for b in sorted(graph[a]):
            for lane in graph[a][b]:
                n = max(2, int(math.ceil(lane.length / _HIGHWAY_STEP)) + 1)
                s = np.linspace(0.0, lane.length, n)
                half = np.array([0.5 * lane.width_at(si) for si in s])
                centerlines.append(np.array([lane.position(si, 0.0) for si in s]))
                for side, sign in ((0, -1.0), (1, 1.0)):
                    boundaries.append(np.array([lane.position(si, sign * hi) for si, hi in zip(s, half)]))
                    styles.append(style_of.get(lane.line_types[side], "solid"))
    if not centerlines:
        raise ValueError("the highway-env network has no lanes to draw")
    return Road(tuple(boundaries), tuple(styles), tuple(centerlines), source="highway-env roundabout")
