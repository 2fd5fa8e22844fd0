"""SUMO networks of real roundabouts: a Lanelet2 map's lanelets as SUMO edges, its routing graph as their
connections, built with netconvert, and the map's entry-to-exit routes.

Each chain of lanelets (`pirl_sim.scenarios.lanelet_graph.lanelet_chains`) becomes a one-lane edge whose shape is the
chain's centre line, named after the chain's first lanelet (`~pirl_sim.scenarios.lanelet_graph.edge_id`); lanelet
ends that the routing graph joins become one node; each successor relation between chains becomes a connection.
Routes (`~pirl_sim.scenarios.lanelet_graph.lanelet_routes`) are given on these edges.
Lanelets on a cycle of the routing graph (the circulating lanes) have priority over the others, so entering
vehicles yield to the ring. Coordinates are kept as in the map (the INTERACTION frame), so recorded tracks lie on the simulated lanes.
"""

from __future__ import annotations

import math
import os
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from pirl_sim.io.atomic import atomic_write_text
from pirl_sim.joints import joined_ends
from ..lanelet_graph import (cycle_lanelets, chain_route, edge_id, lanelet_chains, lanelet_paths, lanelet_width,
                             successors)
from .imports import sumo_module

__all__ = ["LaneletNetwork", "network_from_lanelet2", "lane_distances"]

_NETCONVERT_TIMEOUT_S = 120.0


@dataclass(frozen=True)
class LaneletNetwork:
    """A SUMO network built from a Lanelet2 map.

    Attributes
    ----------
    net : pathlib.Path
        The ``*.net.xml`` netconvert wrote (with junction-internal lanes).
    nodes, edges, connections : pathlib.Path
        The plain-XML inputs netconvert read.
    routes : tuple of (str, tuple of str)
        Every entry-to-exit route: (route id, its edge ids in driving order), from `~pirl_sim.scenarios.lanelet_graph.lanelet_routes`.
    lanelets : dict of str to tuple of int
        Edge id -> the lanelets it is made of, in driving order (`~pirl_sim.scenarios.lanelet_graph.lanelet_edges`).
    """

    net: Path
    nodes: Path
    edges: Path
    connections: Path
    routes: tuple[tuple[str, tuple[str, ...]], ...]
    lanelets: dict[str, tuple[int, ...]] = field(default_factory=dict)


def _nodes(lmap, succ, tolerance: float):
    """Union of lanelet ends (`pirl_sim.joints.joined_ends`): (node of each lanelet's start, node of each end, node
    positions); nodes are named ``n<k>`` in the order of their representative ends' text."""
    lines = lmap.centerlines
    links = [(lid, s) for lid, nexts in succ.items() for s in nexts]
    for lid, s in links:
        gap = float(np.hypot(*(lines[lid][-1] - lines[s][0])))
        if gap > tolerance:
            raise ValueError(f"map {lmap.path}: lanelet {lid} ends {gap:.2f} m from the start of its successor "
                             f"{s} (more than {tolerance} m): the routing graph joins lanelets that do not meet")
    joints = joined_ends(links)

    def find(key):
        return joints.get(key, key)

    groups: dict = {}
    for lid in lines:
        for end in ("start", "end"):
            groups.setdefault(find((end, lid)), []).append(lines[lid][0 if end == "start" else -1])
    names = {root: f"n{k}" for k, root in enumerate(sorted(groups, key=str))}
    pos = {names[r]: np.mean(p, axis=0) for r, p in groups.items()}
    start = {lid: names[find(("start", lid))] for lid in lines}
    end = {lid: names[find(("end", lid))] for lid in lines}  # type: ignore[assignment]
    return start, end, pos


def _arc(line: np.ndarray) -> np.ndarray:
    """Arc length [m] at each vertex of a polyline, shape (n,)."""
    return np.r_[0.0, np.cumsum(np.hypot(*np.diff(line, axis=0).T))]


def _fmt(v: float) -> str:
    return f"{v:.3f}"


def _shape(points: np.ndarray) -> str:
    return " ".join(f"{_fmt(x)},{_fmt(y)}" for x, y in points)


def network_from_lanelet2(lmap, out_dir, *, name: str = "lanelets", junction_radius: float = 1.0,
                          speed: float = 13.89, join_tolerance: float = 0.5,
                          merge_chains: bool = True) -> LaneletNetwork:
    """Write a SUMO network of a Lanelet2 map ("SUMO roundabouts" page: Real roundabouts from Lanelet2 maps).

    Parameters
    ----------
    lmap : pirl_sim.io.lanelet2_map.LaneletMap or path   the map (a path: `pirl_sim.io.lanelet2_map.load_map`)
    out_dir : path              folder for ``{name}.nod.xml``, ``.edg.xml``, ``.con.xml`` and ``.net.xml`` (created)
    junction_radius : float     netconvert's default junction radius [m] (how far edges are cut back at a node)
    speed : float               speed limit of every edge [m/s]
    join_tolerance : float      largest distance [m] between a lanelet's end and a successor's start
    merge_chains : bool
        True: each chain of lanelets (`~pirl_sim.scenarios.lanelet_graph.lanelet_edges`) is one edge. netconvert grows a junction at a shallow merge
        or diverge until the lanes stop overlapping; on one short lanelet per edge that swallows whole lanelets and
        turns what is left of an edge backwards, while on a chain's edge the junction only cuts it back. False:
        one edge per lanelet (routes then as `~pirl_sim.scenarios.lanelet_graph.lanelet_routes` with ``merge_chains=False`` gives them).

    Returns
    -------
    network : LaneletNetwork    ValueError for a bad parameter, map or successors; RuntimeError if netconvert fails
    """
    sumolib = sumo_module("sumolib")

    from pirl_sim.io.lanelet2_map import LaneletMap, load_map

    checks = [("junction_radius", junction_radius, 0.0), ("speed", speed, 0.0), ("join_tolerance", join_tolerance, 0.0)]
    for label, v, lo in checks:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= lo:
            raise ValueError(f"{label} must be a finite number > {lo}, got {v!r}")
    if not isinstance(lmap, LaneletMap):
        lmap = load_map(lmap)
    succ = successors(lmap)
    paths = lanelet_paths(lmap)
    start, end, pos = _nodes(lmap, succ, join_tolerance)
    for lid in sorted(succ):
        if start[lid] == end[lid]:
            raise ValueError(f"map {lmap.path}: lanelet {lid} starts and ends at the same node")
    chains = lanelet_chains(succ, merge_chains)
    routes = [(rid, chain_route(chains, path)) for rid, path in paths]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    widths = {lid: lanelet_width(lmap, lid) for lid in lmap.centerlines}
    lines, edge_widths = {}, {}
    for head, chain in chains.items():
        parts = [lmap.centerlines[chain[0]]] + [lmap.centerlines[lid][1:] for lid in chain[1:]]
        line = np.vstack(parts)
        keep = np.r_[True, np.hypot(*np.diff(line, axis=0).T) >= 1e-3]
        lines[head] = line[keep]
        lengths = np.array([max(_arc(lmap.centerlines[lid])[-1], 1e-6) for lid in chain])
        edge_widths[head] = float(np.dot(lengths, [widths[lid] for lid in chain]) / lengths.sum())
    e_start = {h: start[c[0]] for h, c in chains.items()}
    e_end = {h: end[c[-1]] for h, c in chains.items()}
    used = set(e_start.values()) | set(e_end.values())
    pos = {n: p for n, p in pos.items() if n in used}  # the joints inside a chain are no nodes
    nod = "<nodes>\n" + "".join(f'  <node id="{n}" x="{_fmt(p[0])}" y="{_fmt(p[1])}" type="priority"/>\n'
                                for n, p in sorted(pos.items())) + "</nodes>\n"
    edg = ["<edges>\n"]
    ring = cycle_lanelets(succ)
    for head, line in sorted(lines.items()):
        edg.append(f'  <edge id={quoteattr(edge_id(head))} from="{e_start[head]}" to="{e_end[head]}" numLanes="1" '
                   f'spreadType="center" priority="{2 if head in ring else 1}" speed="{_fmt(speed)}" '
                   f'width="{_fmt(edge_widths[head])}" shape="{_shape(line)}"/>\n')
    edg.append("</edges>\n")
    con = ["<connections>\n"]
    for head, chain in sorted(chains.items()):
        con.extend(f'  <connection from="{edge_id(head)}" to="{edge_id(s)}" fromLane="0" toLane="0"/>\n'
                   for s in succ[chain[-1]])
    con.append("</connections>\n")
    nod_p = atomic_write_text(out_dir / f"{name}.nod.xml", nod)
    edg_p = atomic_write_text(out_dir / f"{name}.edg.xml", "".join(edg))
    con_p = atomic_write_text(out_dir / f"{name}.con.xml", "".join(con))
    net = out_dir / f"{name}.net.xml"
    fd, tmp = tempfile.mkstemp(prefix=f".{net.name}.", suffix=".tmp.net.xml", dir=out_dir)
    os.close(fd)
    cmd = [sumolib.checkBinary("netconvert"), "--node-files", str(nod_p), "--edge-files", str(edg_p),
           "--connection-files", str(con_p), "--output-file", tmp, "--offset.disable-normalization", "true",
           "--no-turnarounds", "true", "--no-internal-links", "false", "--junctions.corner-detail", "5",
           "--junctions.internal-link-detail", "20", "--default.junctions.radius", _fmt(junction_radius),
           "--geometry.remove", "false", "--xml-validation", "never"]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=_NETCONVERT_TIMEOUT_S)
        if proc.returncode != 0:
            raise RuntimeError(f"netconvert failed (exit code {proc.returncode}) for {lmap.path}:\n"
                               f"{proc.stderr.strip() or proc.stdout.strip()}")
        os.chmod(tmp, 0o644)
        os.replace(tmp, net)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return LaneletNetwork(net=net, nodes=nod_p, edges=edg_p, connections=con_p, routes=tuple(routes),
                          lanelets={edge_id(h): c for h, c in sorted(chains.items())})


def lane_distances(net, xy, *, spacing: float = 0.5) -> np.ndarray:
    """Distance [m] from each point to the nearest lane of a SUMO network (junction-internal lanes included).

    Parameters
    ----------
    net : path or sumolib.net.Net
    xy : array_like, shape (n, 2)
        Points [m] in the network's frame.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    sumolib = sumo_module("sumolib")

    from pirl_sim.paths import polyline_distances

    if isinstance(net, (str, os.PathLike)):
        net = sumolib.net.readNet(str(net), withInternal=True)
    xy = np.asarray(xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        raise ValueError(f"xy must be finite points of shape (n, 2), got shape {xy.shape}")
    lanes = [np.asarray(lane.getShape(), dtype=float)[:, :2]
             for edge in net.getEdges(withInternal=True) for lane in edge.getLanes()]
    return polyline_distances(lanes, xy, spacing=spacing)
