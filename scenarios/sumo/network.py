"""Parametric single- or multi-lane roundabouts as SUMO networks, and reference paths along their routes.

A :class:`RoundaboutSpec` describes the roundabout (lengths in metres, angles counter-clockwise from +x,
right-hand traffic: a counter-clockwise ring of ``radius`` with ``n_arms`` arms, each an ``arm{i}_in`` and an
``arm{i}_out`` edge meeting the ring in node ``ring{i}``). ``build_network`` writes the plain-XML files and runs
netconvert (coordinates kept as written, junction-internal lanes kept), ``route_centerline`` gives a route's
continuous reference path through the junctions, ``routes`` lists every entry-to-exit route and
``validate_route`` checks one against a built network (sumolib).

The geometry is described in the documentation's "SUMO roundabouts" page (network).
"""

from __future__ import annotations

import math
import os
import subprocess
import tempfile
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from pirl_sim.io.atomic import atomic_write_text
from pirl_sim.joints import joined_ends, joint_members

from ..planning import route_id
from .imports import sumo_module

__all__ = [
    "RoundaboutSpec",
    "NetworkFiles",
    "build_network",
    "routes",
    "route_id",
    "route_edges",
    "validate_route",
    "route_centerline",
    "route_set",
    "load_net",
    "lane_graph",
    "LANE_JOINT_SNAP",
]

_NETCONVERT_TIMEOUT_S = 120.0  # [s] a roundabout converts in well under a second
_DUPLICATE_TOL = 1e-3  # [m] consecutive shape points closer than this are one point
_RING_SAGITTA = 0.035  # [m] largest distance between the ring edges' chords and the circle
_MIN_RING_EDGE = 1.0  # [m] shortest ring edge left between two arm junctions
LANE_JOINT_SNAP = 0.05  #: [m] largest gap between a lane's end and its successor's start that lane_graph closes
#: allowed ranges of the roundabout's geometry (`RoundaboutSpec`), [low, high]: beyond, netconvert and the route
#: paths take minutes or the geometry is no roundabout
GEOMETRY_RANGES = {"radius": (5.0, 500.0), "approach_length": (1.0, 2000.0), "lane_width": (2.0, 10.0),
                   "splitter_width": (0.0, 50.0), "junction_radius": (0.5, 100.0), "n_arms": (3, 12),
                   "lanes": (1, 6), "ring_segments": (3, 1024)}


@dataclass(frozen=True)
class RoundaboutSpec:
    """Geometry and traffic rules of a roundabout (validated on construction; `GEOMETRY_RANGES` bounds every value).

    Attributes
    ----------
    radius : float                     ring centre-line radius [m], in [5, 500]
    n_arms, lanes : int                number of arms (>= 3, evenly spaced); lanes on the ring and every arm edge
    approach_length : float            length of each arm edge [m], > 0
    ring_segments : int                straight pieces of the ring's polygon over the full circle, >= ``n_arms``
    speed_limit : float                on all edges [m/s], > 0
    lane_width, splitter_width : float   [m] > 0; width of the island between an arm's in and out lanes, >= 0
    center, first_arm_deg : (float, float), float   centre of the ring [m]; direction of arm 0 [deg] from +x
    junction_radius : float            netconvert's turning radius between arms and ring [m], > 0
    entry_visibility : float or None   distance [m] before an entry's stop line from which its drivers see the ring,
                                       > 0; None: SUMO's 4.5 m
    """

    radius: float = 20.0
    n_arms: int = 4
    lanes: int = 1
    approach_length: float = 80.0
    ring_segments: int = 64
    speed_limit: float = 13.9
    lane_width: float = 3.5
    splitter_width: float = 1.0
    center: tuple[float, float] = (0.0, 0.0)
    first_arm_deg: float = 0.0
    junction_radius: float = 6.0
    entry_visibility: float | None = None

    def __post_init__(self) -> None:
        for name in ("n_arms", "lanes", "ring_segments"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise ValueError(f"{name} must be an integer, got {v!r}")
        for name in ("radius", "approach_length", "speed_limit", "lane_width", "splitter_width",
                     "first_arm_deg", "junction_radius"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(v):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        for name in ("radius", "approach_length", "speed_limit", "lane_width", "junction_radius"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        v = self.entry_visibility
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))
                              or not math.isfinite(v) or v <= 0):
            raise ValueError(f"entry_visibility must be a distance > 0 m or None, got {v!r}")
        if self.splitter_width < 0:
            raise ValueError(f"splitter_width must be >= 0, got {self.splitter_width!r}")
        if self.n_arms < 3:
            raise ValueError(f"n_arms must be >= 3, got {self.n_arms!r}")
        if self.lanes < 1:
            raise ValueError(f"lanes must be >= 1, got {self.lanes!r}")
        if self.ring_segments < self.n_arms:
            raise ValueError(f"ring_segments must be >= n_arms = {self.n_arms}, got {self.ring_segments!r}")
        c = self.center
        if isinstance(c, str) or not (hasattr(c, "__len__") and len(c) == 2 and all(
                isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                and math.isfinite(v) for v in c)):
            raise ValueError(f"center must be two finite numbers (x, y) [m], got {c!r}")
        object.__setattr__(self, "center", (float(c[0]), float(c[1])))
        ring_width = self.lanes * self.lane_width
        if ring_width >= self.radius:
            raise ValueError(f"radius = {self.radius} m must exceed the ring's width lanes * lane_width = "
                             f"{ring_width} m (the inner edge of the ring would cross the centre)")
        # the ring between neighbouring arms must keep a positive length
        sector = 2.0 * math.pi / self.n_arms
        if 2.0 * self.arm_half_angle >= 0.75 * sector:
            raise ValueError(
                f"arms too wide for the ring: with radius = {self.radius} m, n_arms = {self.n_arms}, "
                f"lanes = {self.lanes}, lane_width = {self.lane_width} m, splitter_width = "
                f"{self.splitter_width} m each arm takes {math.degrees(2 * self.arm_half_angle):.1f} deg "
                f"of the ring's {math.degrees(sector):.1f} deg per arm; use a larger radius or fewer arms")
        for name, (low, high) in GEOMETRY_RANGES.items():
            v = getattr(self, name)
            if not low <= v <= high:
                unit = "" if name in ("n_arms", "lanes", "ring_segments") else " m"
                raise ValueError(f"{name} must be in [{low:g}, {high:g}]{unit}, got {v!r}")

    @property
    def arm_offset(self) -> float:
        """Lateral distance [m] from an arm's axis to the centre line of its in (and out) edge."""
        return 0.5 * self.splitter_width + 0.5 * self.lanes * self.lane_width

    @property
    def arm_half_angle(self) -> float:
        """Angle [rad] on the ring between an arm's axis and where its in (or out) edge meets the circle."""
        ratio = self.arm_offset / self.radius
        return math.asin(ratio) if ratio < 1.0 else math.pi / 2

    def arm_angle(self, arm: int) -> float:
        """Direction of arm ``arm`` [rad], counter-clockwise from +x."""
        return math.radians(self.first_arm_deg) + 2.0 * math.pi * arm / self.n_arms


@dataclass(frozen=True)
class NetworkFiles:
    """Paths written by :func:`build_network`.

    Attributes
    ----------
    nodes, edges, connections : pathlib.Path
        The plain-XML ``*.nod.xml``, ``*.edg.xml`` and ``*.con.xml`` inputs.
    net : pathlib.Path
        The ``*.net.xml`` written by netconvert.
    spec : RoundaboutSpec
        The geometry they were built from.
    """

    nodes: Path
    edges: Path
    connections: Path
    net: Path
    spec: RoundaboutSpec


# ----------------------------------------------------------------------------------------------
# names and routes
# ----------------------------------------------------------------------------------------------

def _in(i: int) -> str:
    return f"arm{i}_in"


def _out(i: int) -> str:
    return f"arm{i}_out"


def _ring(i: int, n: int) -> str:
    return f"ring{i}_{(i + 1) % n}"


def _ring_node(i: int) -> str:
    return f"ring{i}"


def _check_arm(spec: RoundaboutSpec, arm, name: str) -> int:
    if isinstance(arm, bool) or not isinstance(arm, (int, np.integer)) or not 0 <= arm < spec.n_arms:
        raise ValueError(f"{name} must be an arm index in [0, {spec.n_arms - 1}], got {arm!r}")
    return int(arm)


def route_edges(spec: RoundaboutSpec, entry_arm: int, exit_arm: int) -> list[str]:
    """Edge ids from arm ``entry_arm`` counter-clockwise round the ring to arm ``exit_arm``.

    Parameters
    ----------
    spec : RoundaboutSpec
    entry_arm, exit_arm : int      different arm indices in ``[0, n_arms)`` (else ValueError); ``entry_arm + 1`` is
                                   the first exit (a right turn)

    Returns
    -------
    edges : list of str            ``[arm{entry}_in, ring{entry}_{entry+1}, ..., ring{exit-1}_{exit}, arm{exit}_out]``
    """
    n = spec.n_arms
    entry_arm = _check_arm(spec, entry_arm, "entry_arm")
    exit_arm = _check_arm(spec, exit_arm, "exit_arm")
    if entry_arm == exit_arm:
        raise ValueError(f"exit_arm must differ from entry_arm (no U-turn routes), got arm {entry_arm} for both")
    edges = [_in(entry_arm)]
    i = entry_arm
    while i != exit_arm:
        edges.append(_ring(i, n))
        i = (i + 1) % n
    edges.append(_out(exit_arm))
    return edges


def routes(spec: RoundaboutSpec) -> list[tuple[str, list[str]]]:
    """Every route from each entry arm to each other exit arm.

    Parameters
    ----------
    spec : RoundaboutSpec

    Returns
    -------
    list of (str, list of str)
        ``(route_id(i, j), route_edges(spec, i, j))`` for all ``i != j``, ordered by entry arm and then by
        how far round the ring the exit is (first exit first). With 4 arms the three routes per entry are
        the right turn, the through route and the left turn.
    """
    n = spec.n_arms
    return [(route_id(i, (i + k) % n), route_edges(spec, i, (i + k) % n))
            for i in range(n) for k in range(1, n)]


# ----------------------------------------------------------------------------------------------
# plain XML and netconvert
# ----------------------------------------------------------------------------------------------

def _fmt(v: float) -> str:
    return f"{v:.3f}"


def _pt(p) -> str:
    return f"{_fmt(p[0])},{_fmt(p[1])}"


def _ring_point(spec: RoundaboutSpec, angle: float) -> np.ndarray:
    cx, cy = spec.center
    return np.array([cx + spec.radius * math.cos(angle), cy + spec.radius * math.sin(angle)])


def _lane_radius(spec: RoundaboutSpec, lane: int) -> float:
    """Radius [m] of ring lane ``lane`` (0 = rightmost = outermost for counter-clockwise driving)."""
    return spec.radius + (0.5 * (spec.lanes - 1) - lane) * spec.lane_width


def _arc_points(spec: RoundaboutSpec, radius: float, a0: float, a1: float, max_step: float) -> str:
    pieces = max(1, math.ceil(radius * abs(a1 - a0) / max_step))
    cx, cy = spec.center
    return " ".join(_pt((cx + radius * math.cos(a), cy + radius * math.sin(a)))
                    for a in np.linspace(a0, a1, pieces + 1))


def _plain_xml(spec: RoundaboutSpec) -> tuple[str, str, str]:
    """Node, edge and connection plain-XML text for ``spec``."""
    n = spec.n_arms
    cx, cy = spec.center
    c = np.array([cx, cy])
    d = spec.arm_offset
    half = spec.arm_half_angle
    along = spec.radius * math.cos(half)  # distance from the centre, along the arm axis, to the ring
    full = 2.0 * math.pi
    common = (f'numLanes="{spec.lanes}" speed="{_fmt(spec.speed_limit)}" width="{_fmt(spec.lane_width)}" '
              f'spreadType="center"')
    nodes: list[str] = []
    edges: list[str] = []
    cons: list[str] = []

    for i in range(n):
        a = spec.arm_angle(i)
        u = np.array([math.cos(a), math.sin(a)])  # outwards along the arm
        left = np.array([-u[1], u[0]])  # left of u: the in edge's side
        ring = _ring_point(spec, a)
        far = c + (along + spec.approach_length) * u
        nodes += [
            f'    <node id="{_ring_node(i)}" x="{_fmt(ring[0])}" y="{_fmt(ring[1])}" type="priority"/>',
            f'    <node id="arm{i}_start" x="{_fmt((far + d * left)[0])}" y="{_fmt((far + d * left)[1])}"/>',
            f'    <node id="arm{i}_end" x="{_fmt((far - d * left)[0])}" y="{_fmt((far - d * left)[1])}"/>',
        ]
        # the arm edges run parallel to the axis and end / start where their centre line meets the ring
        edges += [
            f'    <edge id="{_in(i)}" from="arm{i}_start" to="{_ring_node(i)}" priority="1" {common} '
            f'shape="{_pt(far + d * left)} {_pt(c + along * u + d * left)}"/>',
            f'    <edge id="{_out(i)}" from="{_ring_node(i)}" to="arm{i}_end" priority="1" {common} '
            f'shape="{_pt(c + along * u - d * left)} {_pt(far - d * left)}"/>',
        ]
    for i in range(n):
        a0 = spec.arm_angle(i)
        a1 = a0 + full / n
        # chords short enough that they leave the circle (which the ring's connections follow) by at most
        # _RING_SAGITTA: on a large ring, ring_segments alone would leave gaps between lanes at every junction
        chord = math.sqrt(8.0 * spec.radius * _RING_SAGITTA)
        pieces = max(1, round(spec.ring_segments / n), math.ceil(spec.radius * (a1 - a0) / chord))
        shape = " ".join(_pt(_ring_point(spec, a)) for a in np.linspace(a0, a1, pieces + 1))
        edges.append(f'    <edge id="{_ring(i, n)}" from="{_ring_node(i)}" to="{_ring_node((i + 1) % n)}" '
                     f'priority="2" {common} shape="{shape}"/>')
    edges.append(f'    <roundabout nodes={quoteattr(" ".join(_ring_node(i) for i in range(n)))} '
                 f'edges={quoteattr(" ".join(_ring(i, n) for i in range(n)))}/>')

    # Ring -> ring connections through each ring node get the circle as custom shape (netconvert trims
    # it to the junction). netconvert's own shape for such a gentle bend is a cubic Bezier whose control
    # points sit min(5 m, chord / 2) out, which bulges ~0.2 m outwards over the junction and makes the
    # heading wobble. Entries and exits keep netconvert's shapes (quadratic Beziers through the
    # intersection of the lanes' directions). Declaring an edge's connections stops netconvert from
    # guessing its others, so the exits are declared too.
    span = min(0.45 * full / n, 3.0 * half + spec.junction_radius / spec.radius)  # [rad] beyond the junction
    for i in range(n):
        prev = _ring((i - 1) % n, n)
        at = spec.arm_angle(i)
        for lane in range(spec.lanes):
            shape = _arc_points(spec, _lane_radius(spec, lane), at - span, at + span, 0.5)
            cons.append(f'    <connection from="{prev}" to="{_ring(i, n)}" fromLane="{lane}" toLane="{lane}" '
                        f'shape="{shape}"/>')
            cons.append(f'    <connection from="{prev}" to="{_out(i)}" fromLane="{lane}" toLane="{lane}"/>')
        if spec.entry_visibility is not None:  # declared entries: lane k joins ring lane k
            for lane in range(spec.lanes):
                cons.append(f'    <connection from="{_in(i)}" to="{_ring(i, n)}" fromLane="{lane}" '
                            f'toLane="{lane}" visibility="{_fmt(spec.entry_visibility)}"/>')

    header = '<?xml version="1.0" encoding="UTF-8"?>\n'
    comment = f"<!-- pirl_sim roundabout: {spec!r} -->\n"
    nod = header + comment + "<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n"
    edg = header + comment + "<edges>\n" + "\n".join(edges) + "\n</edges>\n"
    con = header + comment + "<connections>\n" + "\n".join(cons) + "\n</connections>\n"
    return nod, edg, con


def build_network(spec: RoundaboutSpec, out_dir, *, name: str = "roundabout") -> NetworkFiles:
    """Write ``{name}.nod.xml``, ``{name}.edg.xml`` and, through netconvert, ``{name}.net.xml``, each atomically.

    Parameters
    ----------
    spec : RoundaboutSpec
    out_dir : str or os.PathLike     created if missing
    name : str                       file name stem

    Returns
    -------
    files : NetworkFiles             ValueError for overlapping junctions of neighbouring arms (the message says
                                     what to change), RuntimeError when netconvert fails
    """
    sumolib = sumo_module("sumolib")  # heavy optional dependency, imported lazily

    if not isinstance(spec, RoundaboutSpec):
        raise TypeError(f"spec must be a RoundaboutSpec, got {type(spec).__name__}")
    if not name or any(ch in name for ch in "/\\"):
        raise ValueError(f"name must be a plain file name stem, got {name!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    nod_text, edg_text, con_text = _plain_xml(spec)
    nod = atomic_write_text(out_dir / f"{name}.nod.xml", nod_text)
    edg = atomic_write_text(out_dir / f"{name}.edg.xml", edg_text)
    con = atomic_write_text(out_dir / f"{name}.con.xml", con_text)
    net = out_dir / f"{name}.net.xml"
    fd, tmp = tempfile.mkstemp(prefix=f".{net.name}.", suffix=".tmp.net.xml", dir=out_dir)
    os.close(fd)
    cmd = [
        sumolib.checkBinary("netconvert"),
        "--node-files", str(nod),
        "--edge-files", str(edg),
        "--connection-files", str(con),
        "--output-file", tmp,
        "--offset.disable-normalization", "true",
        "--no-turnarounds", "true",
        "--no-internal-links", "false",
        "--output.street-names", "false",
        "--junctions.corner-detail", "5",
        "--junctions.internal-link-detail", "20",  # smooth curves through junctions (default 5 points)
        "--default.junctions.radius", _fmt(spec.junction_radius),
                "--xml-validation", "never",
    ]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=_NETCONVERT_TIMEOUT_S)
        if proc.returncode != 0:
            raise RuntimeError(f"netconvert failed (exit code {proc.returncode}) for {spec!r}:\n"
                               f"{proc.stderr.strip() or proc.stdout.strip()}")
        _check_built(spec, tmp)
        for line in proc.stderr.splitlines():
            if line.startswith("Warning:") and "SUMO_HOME" not in line:
                warnings.warn(f"netconvert: {line[len('Warning:'):].strip()}", UserWarning, stacklevel=2)
        os.chmod(tmp, 0o644)
        os.replace(tmp, net)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return NetworkFiles(nodes=nod, edges=edg, connections=con, net=net, spec=spec)


def _check_built(spec: RoundaboutSpec, net_path) -> None:
    """Reject a built network whose arm junctions touch (a ring edge shorter than ``_MIN_RING_EDGE``)."""
    net = load_net(net_path)
    n = spec.n_arms
    shortest = min(net.getEdge(_ring(i, n)).getLength() for i in range(n))
    if shortest < _MIN_RING_EDGE:
        raise ValueError(
            f"the junctions of neighbouring arms overlap: with radius = {spec.radius} m, n_arms = {n}, "
            f"lanes = {spec.lanes} and junction_radius = {spec.junction_radius} m netconvert leaves "
            f"{shortest:.2f} m of ring between them (< {_MIN_RING_EDGE} m); use a larger radius, fewer "
            "arms or a smaller junction_radius")


# ----------------------------------------------------------------------------------------------
# reading networks back
# ----------------------------------------------------------------------------------------------

def load_net(net):
    """A ``sumolib.net.Net`` with internal (junction) lanes, from a path, NetworkFiles or a loaded net."""
    sumolib = sumo_module("sumolib")

    if isinstance(net, NetworkFiles):
        net = net.net
    if isinstance(net, (str, os.PathLike)):
        path = Path(net)
        if not path.is_file():
            raise FileNotFoundError(f"no SUMO network file at {path}")
        return sumolib.net.readNet(str(path), withInternal=True)
    if hasattr(net, "getEdge") and hasattr(net, "hasEdge"):
        return net
    raise TypeError(f"net must be a path, NetworkFiles or sumolib Net, got {type(net).__name__}")


def validate_route(net, edges, *, route_id: str | None = None) -> list[str]:
    """Check that ``edges`` is a drivable route of ``net``; return it as a list.

    ValueError (naming the route and the offending edges) for an empty route, an unknown or internal edge, or two
    consecutive edges that are not connected.

    Parameters
    ----------
    net : str, os.PathLike, NetworkFiles or sumolib.net.Net
    edges : sequence of str        normal (not junction-internal) edge ids in driving order
    route_id : str, optional       named in error messages
    """
    label = f"route {route_id!r}" if route_id is not None else "route"
    if isinstance(edges, str):
        raise ValueError(f"{label}: edges must be a sequence of edge ids, got the string {edges!r}")
    edges = list(edges)
    if not edges:
        raise ValueError(f"{label} is empty")
    net = load_net(net)
    for e in edges:
        if not isinstance(e, str) or not net.hasEdge(e) or net.getEdge(e).getFunction() == "internal":
            known = sorted(x.getID() for x in net.getEdges(withInternal=False))
            raise ValueError(f"{label} is unreachable: unknown edge {e!r} (the network's edges: "
                             f"{', '.join(known)})")
    for a, b in zip(edges[:-1], edges[1:]):
        if net.getEdge(b) not in net.getEdge(a).getOutgoing():
            reachable = sorted(x.getID() for x in net.getEdge(a).getOutgoing())
            raise ValueError(f"{label} is unreachable: edge {a!r} does not lead to {b!r} "
                             f"(it leads to: {', '.join(reachable) or 'nothing'})")
    return edges


def _pick_connection(conns, prefer_from_lane: int | None):
    if prefer_from_lane is not None:
        for c in conns:
            if c.getFromLane().getIndex() == prefer_from_lane:
                return c
    return min(conns, key=lambda c: (c.getFromLane().getIndex(), c.getToLane().getIndex()))


def _densify(shape, max_spacing: float | None) -> np.ndarray:
    """Points of ``shape`` (K, 2) with straight pieces longer than ``max_spacing`` [m] subdivided."""
    shape = np.asarray(shape, dtype=float)[:, :2]
    if max_spacing is None or len(shape) < 2:
        return shape
    out = [shape[:1]]
    for a, b in zip(shape[:-1], shape[1:]):
        n = max(1, math.ceil(float(np.hypot(*(b - a))) / max_spacing))
        t = np.arange(1, n + 1)[:, None] / n
        out.append(a + t * (b - a))
    return np.concatenate(out)


def route_centerline(net, route_edges, *, route_id: str | None = None,
                     max_spacing: float | None = 1.0) -> np.ndarray:
    """Reference path along a route: lane shapes joined through the junction-internal lanes (SUMO page).

    Parameters
    ----------
    net : str, os.PathLike, NetworkFiles or sumolib.net.Net   a network built with internal links
    route_edges : sequence of str
    route_id : str, optional           named in error messages
    max_spacing : float or None        largest distance [m] between points within one lane shape; None: SUMO's points

    Returns
    -------
    xy : numpy.ndarray (P, 2)          x, y [m] in network coordinates, in driving order; ValueError for a route that
                                       is not drivable (`validate_route`), no internal lanes or ``max_spacing`` <= 0
    """
    if max_spacing is not None and not (math.isfinite(max_spacing) and max_spacing > 0):
        raise ValueError(f"max_spacing must be a positive number of metres or None, got {max_spacing!r}")
    net = load_net(net)
    edges = validate_route(net, route_edges, route_id=route_id)
    pieces: list[np.ndarray] = []
    lane_index: int | None = None
    for k, eid in enumerate(edges):
        edge = net.getEdge(eid)
        if k + 1 == len(edges):
            idx = lane_index if lane_index is not None and lane_index < edge.getLaneNumber() else 0
            pieces.append(_densify(edge.getLane(idx).getShape(), max_spacing))
            break
        conn = _pick_connection(edge.getOutgoing()[net.getEdge(edges[k + 1])], lane_index)
        pieces.append(_densify(conn.getFromLane().getShape(), max_spacing))
        via = conn.getViaLaneID()
        if not via:
            raise ValueError(f"the network has no internal lane between {eid!r} and {edges[k + 1]!r}; "
                             "build it with internal links (netconvert's default)")
        lane = net.getLane(via)
        for _ in range(64):  # an internal lane may be split at an internal junction: follow the chain
            pieces.append(_densify(lane.getShape(), max_spacing))
            onward = [c for c in lane.getOutgoing() if c.getTo().getID() == edges[k + 1]]
            if not onward or not onward[0].getViaLaneID():
                break
            lane = net.getLane(onward[0].getViaLaneID())
        lane_index = conn.getToLane().getIndex()
    arr = np.concatenate(pieces)
    keep = np.ones(len(arr), dtype=bool)
    last = arr[0]
    for i in range(1, len(arr)):
        if np.hypot(*(arr[i] - last)) < _DUPLICATE_TOL:
            keep[i] = False
        else:
            last = arr[i]
    return arr[keep]


def route_set(net, routes, *, smoothing: float | None = None, speed_smoothing: float = 0.0,
              spacing: float | None = None):
    """Reference paths along routes of a network (`route_centerline`, smoothed) on one global arc-length axis
    (`~pirl_sim.scenarios.drivers.RouteSet`; ValueError for a route not drivable in ``net``).

    Parameters
    ----------
    net : str, os.PathLike, NetworkFiles or sumolib.net.Net
    routes : mapping or iterable of (route_id, edges)
    smoothing : float, optional     smoothing length [m] of the paths' geometry (default
                                    ``pirl_sim.paths.DEFAULT_SMOOTHING``)
    speed_smoothing : float         further smoothing length [m] of their curvature for the desired speed
    spacing : float, optional       [m] (default ``ROUTE_SPACING``)
    """
    from pirl_sim.paths import DEFAULT_SMOOTHING, ReferencePath

    from ..drivers import ROUTE_SPACING, RouteSet

    net = load_net(net)
    items = list(routes.items()) if isinstance(routes, Mapping) else list(routes)
    paths = tuple(ReferencePath.from_polyline(route_centerline(net, list(edges), route_id=rid),
                                              smoothing=DEFAULT_SMOOTHING if smoothing is None else smoothing)
                  for rid, edges in items)
    return RouteSet(tuple(rid for rid, _ in items), paths, ROUTE_SPACING if spacing is None else spacing,
                    speed_smoothing)


def _drop_points(lines: dict[str, np.ndarray], succ: dict[str, list[str]]) -> None:
    """Leave out (in place) the lanes of one point, shorter than ``_DUPLICATE_TOL`` (netconvert makes such junction
    lanes on real maps): no lanelet can hold them; their predecessors lead to their successors instead."""
    for lid in [k for k, v in lines.items() if len(v) < 2]:
        after = succ.pop(lid, [])
        for k, nexts in succ.items():
            if lid in nexts:
                succ[k] = sorted((set(nexts) - {lid}) | set(after))
        del lines[lid]


def lane_graph(net) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
    """Every lane of a network (junction-internal lanes included) as centerlines with successor links.

    The form `pirl_sim.io.lanelet2_map.write_map` takes; lane ends and starts that meet are moved to their mean
    (ValueError beyond `LANE_JOINT_SNAP`; SUMO page, Network geometry); a lane of no length is left out, its
    predecessors leading to its successors.

    Parameters
    ----------
    net : str, os.PathLike, NetworkFiles or sumolib.net.Net

    Returns
    -------
    centerlines : dict of str to numpy.ndarray     lane id -> (P, 2) x, y [m] in driving direction, sorted by lane id
    successors : dict of str to list of str        lane id -> ids of the lanes that follow it (sorted)
    """
    net = load_net(net)
    lines: dict[str, np.ndarray] = {}
    succ: dict[str, list[str]] = {}
    for edge in net.getEdges(withInternal=True):
        for lane in edge.getLanes():
            lid = lane.getID()
            pts = np.asarray(lane.getShape(), dtype=float)[:, :2]
            keep = np.concatenate(([True], np.hypot(*np.diff(pts, axis=0).T) >= _DUPLICATE_TOL))
            lines[lid] = pts[keep].copy()
            nxt = sorted({c.getViaLaneID() or c.getToLane().getID() for c in lane.getOutgoing()})
            if nxt:
                succ[lid] = nxt
    _drop_points(lines, succ)
    # lane ends and the starts of their successors meet at one point, the mean of theirs
    links = [(a, b) for a, nexts in succ.items() for b in nexts]
    for a, b in links:
        gap = float(np.hypot(*(lines[a][-1] - lines[b][0])))
        if gap > LANE_JOINT_SNAP:
            raise ValueError(f"lane {a!r} ends {gap:.3f} m from the start of its successor {b!r} "
                             f"(more than {LANE_JOINT_SNAP} m)")
    for keys in joint_members(joined_ends(links)).values():
        pts = np.array([lines[name][0 if kind == "start" else -1] for kind, name in keys])
        mean = pts.mean(axis=0)
        for kind, name in keys:
            lines[name][0 if kind == "start" else -1] = mean
    return dict(sorted(lines.items())), dict(sorted(succ.items()))
