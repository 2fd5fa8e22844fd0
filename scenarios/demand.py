"""Traffic demand read from a recording: each recorded vehicle's route through a Lanelet2 map and its departure
time (log replay), and per entry the departure rate and the probabilities of its routes (sampled demand)."""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["Departure", "RecordedDemand", "demand_from_tracks"]


@dataclass(frozen=True)
class Departure:
    """One vehicle of the demand: when it enters its route, and its size.

    Attributes
    ----------
    time_s : float                 departure time [s] at the route's first lanelet
    route : tuple of int           lanelet ids from an entry to an exit
    length, width : float          vehicle size [m]
    track_id : int or None         the recorded track it comes from (None when sampled)
    """

    time_s: float
    route: tuple[int, ...]
    length: float = 4.5
    width: float = 1.8
    track_id: int | None = None


@dataclass(frozen=True)
class RecordedDemand:
    """The departures of a recording and the span they cover.

    Attributes
    ----------
    departures : tuple of Departure   sorted by time
    duration_s : float                the recording's span [s]
    unmatched : int                   recorded tracks that fit no route of the map (left out)
    """

    departures: tuple[Departure, ...]
    duration_s: float
    unmatched: int = 0

    def __post_init__(self):
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(f"duration_s must be a finite number of seconds > 0, got {self.duration_s!r}")

    def rates(self) -> dict[int, float]:
        """Entry lanelet -> departures per hour."""
        counts = Counter(d.route[0] for d in self.departures)
        return {e: 3600.0 * n / self.duration_s for e, n in sorted(counts.items())}

    def route_probabilities(self) -> dict[int, dict[tuple[int, ...], float]]:
        """Entry lanelet -> {route: share of that entry's departures}."""
        by_entry: dict[int, Counter] = defaultdict(Counter)
        for d in self.departures:
            by_entry[d.route[0]][d.route] += 1
        return {e: {r: n / sum(c.values()) for r, n in sorted(c.items())} for e, c in sorted(by_entry.items())}

    def sample(self, rng: np.random.Generator, duration_s: float | None = None) -> tuple[Departure, ...]:
        """Departures drawn at the recorded rates (a Poisson process per entry) on routes drawn with the recorded
        probabilities, with sizes drawn from the recorded vehicles', over ``duration_s`` [s] (default the
        recording's)."""
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        duration = self.duration_s if duration_s is None else float(duration_s)
        if not (math.isfinite(duration) and duration > 0):
            raise ValueError(f"duration_s must be a finite number of seconds > 0, got {duration_s!r}")
        sizes = np.array([(d.length, d.width) for d in self.departures])
        out = []  # type: ignore[var-annotated]
        shares = self.route_probabilities()
        for entry, rate in self.rates().items():
            routes = shares[entry]
            keys = list(routes)
            n = rng.poisson(rate * duration / 3600.0)
            times = np.sort(rng.uniform(0.0, duration, n))
            picks = rng.choice(len(keys), size=n, p=np.array([routes[k] for k in keys]))
            size = sizes[rng.integers(0, len(sizes), n)]
            out.extend(Departure(float(t), keys[k], float(s[0]), float(s[1])) for t, k, s in zip(times, picks, size))
        return tuple(sorted(out, key=lambda d: (d.time_s, d.route)))


def _in_order(route: tuple[int, ...], lanelets: list[int]) -> int:
    """How many of ``lanelets`` appear in ``route`` in their order (a greedy subsequence match)."""
    pos, hits = 0, 0
    for lid in lanelets:
        try:
            pos = route.index(lid, pos) + 1
            hits += 1
        except ValueError:
            continue
    return hits


def demand_from_tracks(tracks: pd.DataFrame, lmap, routes, *, min_share: float = 0.5) -> RecordedDemand:
    """The demand of a recording on a map's routes: each track's best-matching route and departure time ("Realism of
    simulated traffic" page: SUMO's drivers on FT's own geometry and demand, which says how they are found).

    Parameters
    ----------
    tracks : pandas.DataFrame       INTERACTION vehicle columns (`pirl_sim.io.interaction.read_tracks`)
    lmap : pirl_sim.io.lanelet2_map.LaneletMap
    routes : sequence of sequence of int   entry-to-exit lanelet routes (e.g. from
                                           `pirl_sim.scenarios.lanelet_graph.lanelet_paths`)
    min_share : float               a track whose best route holds less of its matched lanelets counts as unmatched

    Returns
    -------
    RecordedDemand
    """
    from pirl_sim.io.interaction import split_tracks
    from pirl_sim.io.lanelet2_map import match_route

    routes = [tuple(int(x) for x in r) for r in routes]
    if not routes:
        raise ValueError("demand_from_tracks: no routes given")
    if not 0.0 < min_share <= 1.0:
        raise ValueError(f"min_share must be in (0, 1], got {min_share!r}")
    t_all = tracks["timestamp_ms"].to_numpy(dtype=float) / 1000.0
    if len(t_all) == 0:
        raise ValueError("demand_from_tracks: the table has no rows")
    lines = lmap.centerlines
    out, unmatched = [], 0
    for track_id, rows in split_tracks(tracks).items():
        xy = rows[["x", "y"]].to_numpy(dtype=float)
        if len(xy) < 2:
            unmatched += 1
            continue
        psi = rows["psi_rad"].to_numpy(dtype=float) if "psi_rad" in rows else None
        try:
            match = match_route(lmap, xy, psi=psi)
        except ValueError:
            unmatched += 1
            continue
        ids = [int(i) for i, inv in zip(match.lanelet_ids, match.inverted) if not inv]
        if not ids:
            unmatched += 1
            continue
        best = max(routes, key=lambda r: (_in_order(r, ids), -len(r)))
        if _in_order(best, ids) < min_share * len(ids):
            unmatched += 1
            continue
        path = np.concatenate([lines[i] for i in best])
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
        s0 = float(cum[np.argmin(np.hypot(*(path - xy[0]).T))])
        v0 = float(np.hypot(rows["vx"].iloc[0], rows["vy"].iloc[0]))
        t0 = float(rows["timestamp_ms"].iloc[0]) / 1000.0 - s0 / max(v0, 3.0)
        out.append(Departure(t0, best, float(rows["length"].iloc[0]), float(rows["width"].iloc[0]), int(track_id)))
    if not out:
        raise ValueError(f"no recorded track fits a route of map {lmap.path} ({unmatched} tracks tried): does the "
                         "recording belong to this map?")
    start = min(d.time_s for d in out)
    shifted = tuple(sorted((Departure(d.time_s - start, d.route, d.length, d.width, d.track_id) for d in out),
                           key=lambda d: (d.time_s, d.route)))
    duration = max(float(t_all.max()) - start, 1.0)
    return RecordedDemand(shifted, duration, unmatched)
