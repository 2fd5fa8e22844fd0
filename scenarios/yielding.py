"""Yielding at the conflict points of known routes: where a car has to stop for traffic that will cross its path.

Simulated vehicles drive on known routes, so where two routes meet is a property of the routes, found once:
:class:`ConflictTable` holds, for every ordered pair of routes (a, b), the first point of route a within
``radius`` of route b's path (a's local arc length there, and b's), unless the two start together (cars on one
lane follow each other instead: `pirl_sim.scenarios.leaders`). :func:`yield_gaps` then applies the rule of
`pirl_sim.scenarios.conflicts` (the recorded tracks' rule, there on map-matched paths) at one instant: a car
yields to another car coming from its left that will reach the conflict point within ``horizon`` seconds, at
``min_speed`` or faster, unless the car itself reaches the point ``clearance`` seconds earlier (at its speed, at
least 0.5 m/s); what it yields to is a standing obstacle ``stop_margin`` metres before the point. The simulated
drivers who weigh ``yielding`` plan with that obstacle, and the learner finds the same one in the recording.
"""

from __future__ import annotations

import numpy as np

from .conflicts import ConflictRule

__all__ = ["ConflictTable", "yield_gaps", "STOP_RULE"]

#: the simulated drivers' rule: `ConflictRule`'s defaults with a standing obstacle before the conflict point
STOP_RULE = ConflictRule(obstacle="stop")
_GRID = 0.5  # [m] spacing of the path points searched for the first contact
_MIN_SPEED_TIME = 0.5  # [m/s] the own speed below which the time to the point is taken at this speed


class ConflictTable:
    """First contact points of every ordered pair of routes of a route set.

    Parameters
    ----------
    routes : RouteSet        (`pirl_sim.scenarios.drivers.RouteSet`)
    radius : float [m]       paths closer than this conflict (`ConflictRule.radius`)

    Attributes
    ----------
    s_own, s_other : arrays (R, R) [m]   ``[a, b]``: local arc length of route a's first point within ``radius``
                                         of route b's path, and of b's nearest point there (NaN: no conflict)
    """

    def __init__(self, routes, radius: float = STOP_RULE.radius) -> None:
        n = len(routes.route_ids)
        pts = []
        for path in routes.paths:
            s = np.arange(0.0, path.length + _GRID / 2, _GRID)
            pts.append((s, path.to_cartesian(s, np.zeros_like(s), extrapolate=True)))
        from scipy.spatial import cKDTree

        trees = [cKDTree(p) for _, p in pts]
        self.s_own = np.full((n, n), np.nan)
        self.s_other = np.full((n, n), np.nan)
        for a in range(n):
            sa, pa = pts[a]
            for b in range(n):
                if a == b:
                    continue
                d, nearest = trees[b].query(pa)  # each point of a: distance to b's nearest point, and which
                near = d < radius
                if not near.any() or near[0]:  # apart, or starting together (one lane: following, not yielding)
                    continue
                k = int(np.argmax(near))
                self.s_own[a, b], self.s_other[a, b] = sa[k], pts[b][0][nearest[k]]


def yield_gaps(table: ConflictTable, route: np.ndarray, s: np.ndarray, speed: np.ndarray, xy: np.ndarray,
               psi: np.ndarray, egos: np.ndarray, rule: ConflictRule = STOP_RULE) -> np.ndarray:
    """Gap [m] from each of the ``egos`` to the standing obstacle it yields to now (inf where it need not yield).

    Parameters
    ----------
    table : ConflictTable
    route : int array (n,)      route index of every vehicle (-1: unknown, never yielded to)
    s : array (n,) [m]          local arc length of every vehicle on its route
    speed : array (n,) [m/s]
    xy : array (n, 2) [m]       centre positions
    psi : array (n,) [rad]      headings
    egos : int array (m,)       the vehicles (indices into the arrays) whose gaps are asked for
    rule : ConflictRule         look_ahead, horizon, clearance, stop_margin, min_speed (its ``obstacle`` is "stop")

    Returns
    -------
    gap : array (m,) [m]        >= 0; the obstacle stands still
    """
    route = np.asarray(route, dtype=np.int64)
    egos = np.asarray(egos, dtype=np.int64)
    out = np.full(len(egos), np.inf)
    if len(route) < 2 or not len(egos):
        return out
    ri, rj = route[egos][:, None], route[None, :]
    known = (ri >= 0) & (rj >= 0)
    sa = np.where(known, table.s_own[np.maximum(ri, 0), np.maximum(rj, 0)], np.nan)  # (m, n)
    sb = np.where(known, table.s_other[np.maximum(ri, 0), np.maximum(rj, 0)], np.nan)
    d_own = sa - s[egos][:, None]
    d_other = sb - s[None, :]
    v_other = np.broadcast_to(speed[None, :], d_own.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_other = d_other / v_other
        t_own = d_own / np.maximum(speed[egos], _MIN_SPEED_TIME)[:, None]
        head = np.column_stack([np.cos(psi[egos]), np.sin(psi[egos])])
        rel = xy[None, :, :] - xy[egos][:, None, :]
        left = head[:, None, 0] * rel[..., 1] - head[:, None, 1] * rel[..., 0] > 0
        conflict = ((d_own >= 1.0) & (d_own <= rule.look_ahead) & (d_other > 0) & (v_other >= rule.min_speed)
                    & (t_other <= rule.horizon) & left & (t_own + rule.clearance > t_other))
    conflict[np.arange(len(egos)), egos] = False
    gap = np.where(conflict, np.maximum(d_own - rule.stop_margin, 0.0), np.inf)
    return gap.min(axis=1)
