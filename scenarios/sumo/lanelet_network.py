"""SUMO networks of real roundabouts: a Lanelet2 map's lanelets as SUMO edges, its routing graph as their
connections, built with netconvert, and the map's entry-to-exit routes.

Each chain of lanelets becomes a one-lane edge whose shape is the chain's centre line: a lanelet with exactly one
successor that has exactly one predecessor is joined with it (`lanelet_edges`), and the edge is named after the chain's
first lanelet (`edge_id`); lanelet ends that the routing graph joins (a lanelet's end and its successors' starts)
become one node; each successor relation between chains becomes a connection. Routes (`lanelet_routes`) are given
on these edges; `lanelet_paths` gives them lanelet by lanelet, and `route_lanelets` maps edges back to lanelets.
Lanelets on a cycle of the routing graph (the circulating lanes) have priority over the others, so entering
vehicles yield to the ring. Coordinates are kept as in the map (the INTERACTION frame), so recorded tracks lie on the simulated lanes.
"""

from __future__ import annotations

import functools
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
from .imports import sumo_module

__all__ = ["LaneletNetwork", "network_from_lanelet2", "lanelet_routes", "lanelet_paths", "lanelet_edges",
           "route_lanelets", "map_routes", "lanelet_route_set", "ring_lanelets", "lane_distances", "edge_id"]

_NETCONVERT_TIMEOUT_S = 120.0
_DEFAULT_WIDTH = 3.5  # [m] a lanelet whose bounds give no width


def edge_id(lanelet_id: int) -> str:
    """The name of the SUMO edge that starts with a lanelet: ``ll<id>`` (an edge of a chain of lanelets is named
    after the chain's first lanelet, `lanelet_edges`)."""
    return f"ll{int(lanelet_id)}"


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
        Every entry-to-exit route: (route id, its edge ids in driving order), from `lanelet_routes`.
    lanelets : dict of str to tuple of int
        Edge id -> the lanelets it is made of, in driving order (`lanelet_edges`).
    """

    net: Path
    nodes: Path
    edges: Path
    connections: Path
    routes: tuple[tuple[str, tuple[str, ...]], ...]
    lanelets: dict[str, tuple[int, ...]] = field(default_factory=dict)


def _successors(lmap) -> dict[int, list[int]]:
    """Lanelet id -> ids of the lanelets that follow it in the map's routing graph (only lanelets with centre lines)."""
    out = {}
    layer = lmap.map.laneletLayer
    for lid in lmap.centerlines:
        out[lid] = sorted(int(n.id) for n in lmap.routing_graph.following(layer[lid]) if int(n.id) in lmap.centerlines)
    return out


def _width(lmap, lid: int) -> float:
    ll = lmap.map.laneletLayer[lid]
    left = np.array([(p.x, p.y) for p in ll.leftBound])
    right = np.array([(p.x, p.y) for p in ll.rightBound])
    if len(left) < 2 or len(right) < 2:
        return _DEFAULT_WIDTH
    d = [np.min(np.hypot(*(right - p).T)) for p in left]
    w = float(np.median(d))
    return w if 2.0 <= w <= 8.0 else _DEFAULT_WIDTH


def _chains(succ: dict[int, list[int]], joined: bool = True) -> dict[int, tuple[int, ...]]:
    """First lanelet -> the chain of lanelets it starts: a lanelet with exactly one successor that has exactly one
    predecessor is followed by it in its chain (``joined`` False: every lanelet its own chain). A chain that would
    close on itself (a cycle without branches) is cut before its first lanelet comes round again."""
    if not joined:
        return {lid: (lid,) for lid in succ}
    pred: dict[int, list[int]] = {lid: [] for lid in succ}
    for a, nexts in succ.items():
        for b in nexts:
            pred[b].append(a)

    def joins(a: int) -> bool:
        return len(succ[a]) == 1 and len(pred[succ[a][0]]) == 1

    heads = [lid for lid in sorted(succ) if not (len(pred[lid]) == 1 and joins(pred[lid][0]))]
    out: dict[int, tuple[int, ...]] = {}
    covered: set[int] = set()
    for head in heads + sorted(succ):  # then what no head reaches: cycles without branches
        if head in covered:
            continue
        chain = [head]
        while joins(chain[-1]) and succ[chain[-1]][0] != head and succ[chain[-1]][0] not in covered:
            chain.append(succ[chain[-1]][0])
        out[head] = tuple(chain)
        covered.update(chain)
    return _no_loops(out, *_ends(succ))


def _ends(succ: dict[int, list[int]]) -> tuple[dict[int, object], dict[int, object]]:
    """The node of each lanelet's start and of its end, as the routing graph joins them (a lanelet's end and its
    successors' starts are one node): lanelet id -> a key of its node (`pirl_sim.joints.joined_ends`)."""
    joints = joined_ends((lid, s) for lid, nexts in succ.items() for s in nexts)
    return ({lid: joints.get(("start", lid), ("start", lid)) for lid in succ},
            {lid: joints.get(("end", lid), ("end", lid)) for lid in succ})


def lanelet_edges(lmap, *, merge_chains: bool = True) -> dict[str, tuple[int, ...]]:
    """The SUMO edges of a map: edge id -> the lanelets it is made of, in driving order.

    Parameters
    ----------
    lmap : pirl_sim.io.lanelet2_map.LaneletMap or path
    merge_chains : bool
        True: a chain of lanelets, each but the last with exactly one successor that has exactly one predecessor,
        is one edge named after its first lanelet (`edge_id`); False: every lanelet is an edge.

    Returns
    -------
    dict of str to tuple of int
    """
    lmap = _loaded(lmap)
    return {edge_id(head): chain for head, chain in sorted(_chains(_successors(lmap), merge_chains).items())}


def _loaded(lmap):
    from pirl_sim.io.lanelet2_map import LaneletMap, load_map

    return lmap if isinstance(lmap, LaneletMap) else load_map(lmap)


def _edge_route(chains: dict[int, tuple[int, ...]], lanelets) -> tuple[str, ...]:
    """The edges of a sequence of lanelets, consecutive repeats dropped."""
    head = {lid: h for h, chain in chains.items() for lid in chain}
    out: list[str] = []
    for lid in lanelets:
        e = edge_id(head[int(lid)])
        if not out or out[-1] != e:
            out.append(e)
    return tuple(out)


def route_lanelets(lmap, edges, *, merge_chains: bool = True) -> tuple[int, ...]:
    """The lanelets of a route, in driving order.

    Parameters
    ----------
    lmap : pirl_sim.io.lanelet2_map.LaneletMap or path
    edges : sequence of str
        Edge ids ``ll<lanelet id>``: the edges of `lanelet_routes` (a chain's first lanelet stands for the chain),
        or one per lanelet (each lanelet of a chain is then taken once).
    merge_chains : bool     as `lanelet_edges` takes it

    Returns
    -------
    tuple of int            ValueError for an edge that names no lanelet of the map
    """
    lmap = _loaded(lmap)
    chains = _chains(_successors(lmap), merge_chains)
    return _route_lanelets(lmap, chains, edges)


def _route_lanelets(lmap, chains, edges, rid: str | None = None) -> tuple[int, ...]:
    head = {lid: h for h, chain in chains.items() for lid in chain}
    ids = [int(e[2:]) if isinstance(e, str) and e.startswith("ll") and e[2:].isdigit() else None for e in edges]
    missing = [e for e, i in zip(edges, ids) if i not in head]
    if missing:
        raise ValueError(f"{'route ' + repr(rid) + ': ' if rid is not None else ''}edge(s) {missing} name no lanelet "
                         f"of {lmap.path} (edges are ll<id>)")
    heads: list[int] = []
    for i in ids:
        if not heads or heads[-1] != head[i]:
            heads.append(head[i])
    return tuple(lid for h in heads for lid in chains[h])


def lanelet_paths(lmap, *, max_routes: int = 10_000) -> list[tuple[str, tuple[int, ...]]]:
    """Every route from a lanelet without predecessor to one without successor, without repeating a lanelet, as
    lanelet ids.

    Returns
    -------
    list of (route id, lanelet ids)
        Route ids ``r<first lanelet>_<last lanelet>`` (``_<k>`` added when several routes join the same pair),
        sorted.

    Raises
    ------
    ValueError
        If the map has no lanelets, no route from an entry to an exit, or more than ``max_routes`` routes.
    """
    lmap = _loaded(lmap)
    succ = _successors(lmap)
    if not succ:
        raise ValueError(f"map {lmap.path}: no lanelets with centre lines")
    has_pred = {s for v in succ.values() for s in v}
    entries = [lid for lid in sorted(succ) if lid not in has_pred]
    found: list[tuple[int, ...]] = []
    for start in entries:
        stack = [(start, (start,))]
        while stack:
            lid, path = stack.pop()
            nxt = [s for s in succ[lid] if s not in path]
            if not succ[lid]:
                found.append(path)
                if len(found) > max_routes:
                    raise ValueError(f"map {lmap.path}: more than {max_routes} entry-to-exit routes")
            stack.extend((s, path + (s,)) for s in reversed(nxt))  # type: ignore[misc]
    if not found:
        raise ValueError(f"map {lmap.path}: no route leads from an entry lanelet (no predecessor) to an exit "
                         "lanelet (no successor): is it a roundabout map with entries and exits?")
    found.sort()
    out, seen = [], {}  # type: ignore[var-annotated]
    for path in found:  # type: ignore[assignment]
        key = f"r{path[0]}_{path[-1]}"
        seen[key] = seen.get(key, 0) + 1
        out.append((key if seen[key] == 1 else f"{key}_{seen[key] - 1}", tuple(path)))
    return out


def lanelet_routes(lmap, *, max_routes: int = 10_000, merge_chains: bool = True) -> list[tuple[str, tuple[str, ...]]]:
    """Every entry-to-exit route of `lanelet_paths` on the network's edges (`lanelet_edges`).

    Parameters
    ----------
    lmap : pirl_sim.io.lanelet2_map.LaneletMap or path
    max_routes : int        as `lanelet_paths` takes it
    merge_chains : bool     as `lanelet_edges` takes it

    Returns
    -------
    list of (route id, edge ids)
        The route ids of `lanelet_paths`; each route's lanelets mapped to the edges they belong to, consecutive
        repeats dropped.

    Raises
    ------
    ValueError
        As `lanelet_paths` raises it.
    """
    lmap = _loaded(lmap)
    chains = _chains(_successors(lmap), merge_chains)
    return [(rid, _edge_route(chains, path)) for rid, path in lanelet_paths(lmap, max_routes=max_routes)]


def map_routes(path) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """`lanelet_routes` of the Lanelet2 map at ``path``, read once per version of the file in a process.

    Raises
    ------
    FileNotFoundError, ValueError
        As `pirl_sim.io.lanelet2_map.load_map` and `lanelet_routes` raise them.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"Lanelet2 map not found: {p}")
    st = p.stat()
    return _map_routes(str(p.resolve()), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=8)
def _map_routes(path: str, mtime_ns: int, size: int) -> tuple[tuple[str, tuple[str, ...]], ...]:
    from pirl_sim.io.lanelet2_map import load_map

    return tuple(lanelet_routes(load_map(path)))


def lanelet_route_set(lmap, routes, *, smoothing: float | None = None, speed_smoothing: float = 0.0):
    """Reference paths of routes along the map's lanelet centre lines (the lines `pirl_sim.io.lanelet2_map.match_route`
    joins for a recorded track), not along SUMO's lanes, whose shapes netconvert cuts back at junctions.

    Parameters
    ----------
    lmap : pirl_sim.io.lanelet2_map.LaneletMap or path
    routes : mapping or iterable of (route id, edge ids ``ll<lanelet id>``)   as `route_lanelets` reads them
    smoothing, speed_smoothing : float      as `pirl_sim.scenarios.sumo.network.route_set` takes them [m]

    Returns
    -------
    routes : pirl_sim.scenarios.drivers.RouteSet    ValueError for an edge that names no lanelet of the map
    """
    from pirl_sim.io.lanelet2_map import LaneletMap, load_map
    from pirl_sim.paths import DEFAULT_SMOOTHING, ReferencePath

    from ..drivers import ROUTE_SPACING, RouteSet

    if not isinstance(lmap, LaneletMap):
        lmap = load_map(lmap)
    items = list(routes.items()) if isinstance(routes, dict) else list(routes)
    chains = _chains(_successors(lmap))
    paths = []
    for rid, edges in items:
        ids = _route_lanelets(lmap, chains, edges, rid)
        line = np.vstack([lmap.centerlines[i] for i in ids])
        keep = np.concatenate(([True], np.hypot(*np.diff(line, axis=0).T) >= 1e-3))
        paths.append(ReferencePath.from_polyline(line[keep], smoothing=DEFAULT_SMOOTHING if smoothing is None
                                                 else smoothing))
    return RouteSet(tuple(rid for rid, _ in items), tuple(paths), ROUTE_SPACING, speed_smoothing)


def ring_lanelets(lmap) -> set[int]:
    """Ids of the lanelets on a cycle of the map's routing graph: a roundabout's circulating lanes (none: the map
    has no roundabout)."""
    return _ring_lanelets(_successors(lmap))


def _ring_lanelets(succ: dict[int, list[int]]) -> set[int]:
    """Lanelets on a cycle of the routing graph (a roundabout's circulating lanes)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    ids = sorted(succ)
    index = {lid: k for k, lid in enumerate(ids)}
    pairs = [(index[a], index[b]) for a, nexts in succ.items() for b in nexts]
    rows, cols = (list(x) for x in zip(*pairs)) if pairs else ([], [])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(ids), len(ids)))
    _, labels = connected_components(graph, directed=True, connection="strong")
    sizes = np.bincount(labels)
    return {lid for lid, lab in zip(ids, labels) if sizes[lab] > 1}


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
        True: each chain of lanelets (`lanelet_edges`) is one edge. netconvert grows a junction at a shallow merge
        or diverge until the lanes stop overlapping; on one short lanelet per edge that swallows whole lanelets and
        turns what is left of an edge backwards, while on a chain's edge the junction only cuts it back. False:
        one edge per lanelet (routes then as `lanelet_routes` with ``merge_chains=False`` gives them).

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
    succ = _successors(lmap)
    paths = lanelet_paths(lmap)
    start, end, pos = _nodes(lmap, succ, join_tolerance)
    for lid in sorted(succ):
        if start[lid] == end[lid]:
            raise ValueError(f"map {lmap.path}: lanelet {lid} starts and ends at the same node")
    chains = _chains(succ, merge_chains)
    routes = [(rid, _edge_route(chains, path)) for rid, path in paths]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    widths = {lid: _width(lmap, lid) for lid in lmap.centerlines}
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
    ring = _ring_lanelets(succ)
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


def _no_loops(chains: dict[int, tuple[int, ...]], start: dict, end: dict) -> dict[int, tuple[int, ...]]:
    """The chains, each that would start and end at the same node (a ring joined into one edge) cut in two."""
    out = {}
    for head, chain in chains.items():
        while len(chain) > 1 and start[chain[0]] == end[chain[-1]]:
            k = len(chain) // 2
            out[chain[k]] = chain[k:]
            chain = chain[:k]
        out[head] = chain
    return dict(sorted(out.items()))


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
