"""Where lanes of a highway-env road meet away from the ring's merges: crossings and merges, with who goes first.

A road built from a real roundabout's map (:mod:`~pirl_sim.scenarios.highway.lanelet_road`) has lanes that meet
outside the ring: an entry that crosses an exit, two entries that merge before the ring, a bypass that merges into an
exit. highway-env's vehicles know only the vehicle ahead on their own lane, so without a rule they drive into each
other there.
`lane_conflicts` finds these points: **crossings**, where the centre lines of two lanes without a node in common cross
at least ``min_angle`` degrees apart and away from both lanes' ends, and **merges**, where two lanes end at the same node and
neither is a ring lane (an entry joining the ring is the traffic's gap acceptance), or one ends on the other away from
its ends. Each side of a conflict has a
*rank*: 1 on the ring and after it on every route through the lane (exits), 0 before it (entries, bypasses), so
that entering traffic yields to traffic leaving the ring; two sides of equal rank go in order of arrival
(`~.traffic.RoundaboutTraffic`). highway-env's own roundabout has none.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .network import RouteLanes

__all__ = ["LaneConflict", "lane_conflicts", "route_conflicts"]

LaneKey = tuple[str, str]


@dataclass(frozen=True)
class LaneConflict:
    """Two lanes that meet: at lane coordinate ``s_a`` [m] of ``lane_a`` and ``s_b`` of ``lane_b``.

    Attributes
    ----------
    lane_a, lane_b : (str, str)   the lanes (from, to)
    s_a, s_b : float              [m] where they meet, on each (a merge: each lane's length)
    kind : {"crossing", "merge"}
    angle : float                 [deg] between the lanes' directions there (a merge: at their ends)
    rank_a, rank_b : int          1: on or after the ring on the routes through it; 0: before it (module doc)
    """

    lane_a: LaneKey
    lane_b: LaneKey
    s_a: float
    s_b: float
    kind: str
    angle: float
    rank_a: int
    rank_b: int


def _points(lane, step: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A lane's centre line every ``step`` [m] or closer: (points (P, 2), their lane coordinates (P,))."""
    n = max(2, int(math.ceil(lane.length / step)) + 1)
    s = np.linspace(0.0, lane.length, n)
    return np.array([lane.position(x, 0.0) for x in s]), s


def _crossings(pa, sa, pb, sb) -> list[tuple[float, float, float]]:
    """(s on a, s on b, angle [deg]) where the polylines cross (every pair of segments at once)."""
    if (pa.min(axis=0) > pb.max(axis=0)).any() or (pb.min(axis=0) > pa.max(axis=0)).any():
        return []  # bounding boxes apart
    ra, rb = np.diff(pa, axis=0)[:, None, :], np.diff(pb, axis=0)[None, :, :]
    c = pb[None, :-1, :] - pa[:-1, None, :]
    den = ra[..., 0] * rb[..., 1] - ra[..., 1] * rb[..., 0]
    ok = np.abs(den) > 1e-12
    safe = np.where(ok, den, 1.0)
    t = (c[..., 0] * rb[..., 1] - c[..., 1] * rb[..., 0]) / safe
    u = (c[..., 0] * ra[..., 1] - c[..., 1] * ra[..., 0]) / safe
    out = []
    for i, j in zip(*np.nonzero(ok & (t >= 0) & (t < 1) & (u >= 0) & (u < 1))):
        da, db = pa[i + 1] - pa[i], pb[j + 1] - pb[j]
        ang = abs((math.atan2(da[1], da[0]) - math.atan2(db[1], db[0]) + math.pi) % (2 * math.pi) - math.pi)
        out.append((float(sa[i] + t[i, j] * (sa[i + 1] - sa[i])), float(sb[j] + u[i, j] * (sb[j + 1] - sb[j])),
                    math.degrees(ang)))
    return out


def _joins(la, lb, end_clearance: float, tolerance: float = 0.5) -> tuple[float, float, float] | None:
    """(s on a, s on b, angle [deg]) where one lane ends on the other away from the other's ends (a merge into the
    middle of a lane, without a node of the map there), or None."""
    for first, second, swap in ((la, lb, False), (lb, la, True)):
        s, lat = second.local_coordinates(first.position(first.length, 0.0))
        if abs(lat) <= tolerance and end_clearance <= s <= second.length - end_clearance:
            ang = abs((first.heading_at(first.length) - second.heading_at(s) + math.pi) % (2 * math.pi) - math.pi)
            pair = (float(s), float(first.length)) if swap else (float(first.length), float(s))
            return (*pair, math.degrees(ang))
    return None


def _ranks(routes: Mapping[str, RouteLanes], ring: frozenset) -> dict[LaneKey, int]:
    """Lane -> 1 if it is on the ring or after it on every route through it, else 0."""
    rank: dict[LaneKey, int] = {}
    for route in routes.values():
        for k, ix in enumerate(route.lanes):
            after = route.entry_lane >= 0 and (k > route.entry_lane or ix[:2] in ring)
            rank[ix[:2]] = min(rank.get(ix[:2], 1), int(after))
    return rank


def lane_conflicts(network, routes: Mapping[str, RouteLanes], ring: frozenset, *, min_angle: float = 20.0,
                   end_clearance: float = 1.0) -> tuple[LaneConflict, ...]:
    """The crossings and merges of the lanes that ``routes`` drive (see the module docstring).

    Parameters
    ----------
    network : highway_env.road.road.RoadNetwork
    routes : mapping of route id to RouteLanes
    ring : frozenset of (str, str)     the ring's lanes (`~.network.ring_lanes`)
    min_angle : float                  [deg] shallower crossings (neighbouring lanes that touch) are left out
    end_clearance : float              [m] crossings closer than this to an end of either lane are left out (the
                                       lanes meet at a node there, which the routes' order already settles)

    Returns
    -------
    tuple of LaneConflict              in the order of the lanes' names
    """
    if not 0.0 <= min_angle < 180.0:
        raise ValueError(f"min_angle must be in [0, 180) degrees, got {min_angle!r}")
    rank = _ranks(routes, ring)
    lanes = sorted(rank)
    geo = {key: _points(network.get_lane((*key, 0))) for key in lanes}
    out: list[LaneConflict] = []
    for i, a in enumerate(lanes):
        la = network.get_lane((*a, 0))
        for b in lanes[i + 1:]:
            lb = network.get_lane((*b, 0))
            if a[1] == b[1] and a not in ring and b not in ring:  # a merge off the ring
                ha, hb = la.heading_at(la.length), lb.heading_at(lb.length)
                ang = math.degrees(abs((ha - hb + math.pi) % (2 * math.pi) - math.pi))
                out.append(LaneConflict(a, b, float(la.length), float(lb.length), "merge", ang, rank[a], rank[b]))
                continue
            if set(a) & set(b):
                continue  # lanes that share a node meet there: the routes' order settles it (a merge: above)
            joins = _joins(la, lb, end_clearance)
            if joins is not None:
                sa, sb, ang = joins
                out.append(LaneConflict(a, b, sa, sb, "merge", ang, rank[a], rank[b]))
                continue
            for sa, sb, ang in _crossings(*geo[a], *geo[b]):
                if ang < min_angle or min(sa, la.length - sa, sb, lb.length - sb) < end_clearance:
                    continue
                out.append(LaneConflict(a, b, float(sa), float(sb), "crossing", ang, rank[a], rank[b]))
    return tuple(out)


def route_conflicts(routes: Mapping[str, RouteLanes], conflicts: tuple[LaneConflict, ...]
                    ) -> dict[str, tuple[tuple[float, int, int, int], ...]]:
    """Route id -> its conflicts ahead as (route coordinate [m], conflict index, side 0/1, rank), by coordinate;
    a conflict whose both lanes a route drives (a route that crosses itself) is left out of that route's."""
    out: dict[str, tuple[tuple[float, int, int, int], ...]] = {}
    for rid, route in routes.items():
        rows = []
        for c, con in enumerate(conflicts):
            ka, kb = route.position_of.get(con.lane_a), route.position_of.get(con.lane_b)
            if (ka is None) == (kb is None):
                continue
            side, k, s = (0, ka, con.s_a) if ka is not None else (1, kb, con.s_b)
            rows.append((float(route.offsets[k] + s), c, side, con.rank_a if side == 0 else con.rank_b))
        out[rid] = tuple(sorted(rows))
    return out
