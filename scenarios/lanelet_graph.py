"""The lanelet graph of a Lanelet2 roundabout map, as both simulators build on it: lanelets, their successors, chains
and nodes, the entry-to-exit routes and the ring.

A chain of lanelets (`lanelet_chains`) is a lanelet followed by its one successor as long as that successor has
exactly one predecessor; it is named after its first lanelet, ``ll<id>`` (`edge_id`): a SUMO network makes each
chain an edge (`pirl_sim.scenarios.sumo.lanelet_network`), and routes name their chains that way in both simulators.
Lanelet ends that the routing graph joins (a lanelet's end and its successors' starts) are one node
(`node_keys`). Routes run from a lanelet without predecessor to one without successor (`lanelet_paths`, by
lanelet; `lanelet_routes`, by chain); the ring is the lanelets on a cycle of the routing graph (`ring_lanelets`).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from pirl_sim.joints import joined_ends

__all__ = ["edge_id", "successors", "lanelet_width", "lanelet_chains", "node_keys", "loaded_map", "chain_route",
           "lanelet_edges", "route_lanelets", "lanelet_paths", "lanelet_routes", "map_routes", "map_file_version",
           "lanelet_route_set", "ring_lanelets", "cycle_lanelets"]

DEFAULT_WIDTH = 3.5  # [m] a lanelet whose bounds give no width


def edge_id(lanelet_id: int) -> str:
    """The name of the SUMO edge that starts with a lanelet: ``ll<id>`` (an edge of a chain of lanelets is named
    after the chain's first lanelet, `lanelet_edges`)."""
    return f"ll{int(lanelet_id)}"



def successors(lmap) -> dict[int, list[int]]:
    """Lanelet id -> ids of the lanelets that follow it in the map's routing graph (only lanelets with centre lines)."""
    out = {}
    layer = lmap.map.laneletLayer
    for lid in lmap.centerlines:
        out[lid] = sorted(int(n.id) for n in lmap.routing_graph.following(layer[lid]) if int(n.id) in lmap.centerlines)
    return out


def lanelet_width(lmap, lid: int) -> float:
    """[m] a lanelet's width: the median distance from its left bound's points to its right bound, `DEFAULT_WIDTH`
    where the bounds give none in [2, 8] m."""
    ll = lmap.map.laneletLayer[lid]
    left = np.array([(p.x, p.y) for p in ll.leftBound])
    right = np.array([(p.x, p.y) for p in ll.rightBound])
    if len(left) < 2 or len(right) < 2:
        return DEFAULT_WIDTH
    d = [np.min(np.hypot(*(right - p).T)) for p in left]
    w = float(np.median(d))
    return w if 2.0 <= w <= 8.0 else DEFAULT_WIDTH


def lanelet_chains(succ: dict[int, list[int]], joined: bool = True) -> dict[int, tuple[int, ...]]:
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
    return _no_loops(out, *node_keys(succ))


def node_keys(succ: dict[int, list[int]]) -> tuple[dict[int, object], dict[int, object]]:
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
    lmap = loaded_map(lmap)
    return {edge_id(head): chain for head, chain in sorted(lanelet_chains(successors(lmap), merge_chains).items())}


def loaded_map(lmap):
    """``lmap`` as a `pirl_sim.io.lanelet2_map.LaneletMap` (a path is loaded)."""
    from pirl_sim.io.lanelet2_map import LaneletMap, load_map

    return lmap if isinstance(lmap, LaneletMap) else load_map(lmap)


def chain_route(chains: dict[int, tuple[int, ...]], lanelets) -> tuple[str, ...]:
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
    lmap = loaded_map(lmap)
    chains = lanelet_chains(successors(lmap), merge_chains)
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
    lmap = loaded_map(lmap)
    succ = successors(lmap)
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
    lmap = loaded_map(lmap)
    chains = lanelet_chains(successors(lmap), merge_chains)
    return [(rid, chain_route(chains, path)) for rid, path in lanelet_paths(lmap, max_routes=max_routes)]


def map_routes(path) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """`lanelet_routes` of the Lanelet2 map at ``path``, read once per version of the file in a process.

    Raises
    ------
    FileNotFoundError, ValueError
        As `pirl_sim.io.lanelet2_map.load_map` and `lanelet_routes` raise them.
    """
    return _map_routes(*map_file_version(path))


def map_file_version(path) -> tuple[str, int, int]:
    """(resolved path, modification time [ns], size [bytes]) of a Lanelet2 map file: the key of a cache that
    rereads the file when it changes. FileNotFoundError if it is not a file."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"Lanelet2 map not found: {p}")
    st = p.stat()
    return str(p.resolve()), st.st_mtime_ns, st.st_size


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

    from .drivers import ROUTE_SPACING, RouteSet

    if not isinstance(lmap, LaneletMap):
        lmap = load_map(lmap)
    items = list(routes.items()) if isinstance(routes, dict) else list(routes)
    chains = lanelet_chains(successors(lmap))
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
    return cycle_lanelets(successors(lmap))


def cycle_lanelets(succ: dict[int, list[int]]) -> set[int]:
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
