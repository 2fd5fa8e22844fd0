"""Yielding at conflict points: where another car will cross or merge into a car's path ahead.

Per recorded step of a car (the *ego*), whether it has to yield and the gap [m] to the point it has to stop
before (inf when it need not yield), from what the recording shows at that frame: other matched cars are
extrapolated along their own paths for ``horizon`` seconds, the first point of the ego's path within
``look_ahead`` metres they come within ``radius`` of is a conflict, and the ego yields to cars on its left unless
it passes ``clearance`` seconds ahead of them; ``obstacle="stop"`` (a standing obstacle at the point) or
``"merge"`` (default: a virtual vehicle ahead that reaches the point when the other car does).
`pirl_sim.scenarios.replay.load_replay` with ``features="following"`` treats a yield gap as a standing vehicle
ahead.

The rule is explained in the documentation's "Simulators and data" page (recorded tracks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ConflictRule", "TrackMotion", "yield_gaps", "OBSTACLES"]

OBSTACLES = ("merge", "stop")


@dataclass(frozen=True)
class ConflictRule:
    """When a car yields to another (module doc).

    Attributes
    ----------
    look_ahead : float [m]   the ego's path searched ahead
    horizon : float [s]      other cars extrapolated this long
    radius : float [m]       paths closer than this conflict
    clearance : float [s]    the ego goes first when it passes this long before the other car arrives
    stop_margin : float [m]  yield gap = distance to the conflict point - stop_margin
    min_speed : float [m/s]  slower cars are not approaching
    obstacle : {"merge", "stop"}  what the ego yields to (module doc)
    """

    look_ahead: float = 40.0
    horizon: float = 4.0
    radius: float = 1.5
    clearance: float = 1.5
    stop_margin: float = 3.0
    min_speed: float = 1.0
    obstacle: str = "merge"

    def __post_init__(self) -> None:
        if self.obstacle not in OBSTACLES:
            raise ValueError(f"obstacle must be one of {OBSTACLES}, got {self.obstacle!r}")
        for name in ("look_ahead", "horizon", "radius", "clearance", "stop_margin", "min_speed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if self.look_ahead <= 0 or self.horizon <= 0 or self.radius <= 0:
            raise ValueError("look_ahead, horizon and radius must be > 0")


@dataclass(frozen=True, eq=False)
class TrackMotion:
    """One recorded car at its frames: frames (n,), arc length s (n,) [m] on its path, speed v (n,) [m/s],
    position xy (n, 2) [m], heading psi (n,) [rad], and its path (a `pirl_sim.paths.ReferencePath`)."""

    frames: np.ndarray
    s: np.ndarray
    v: np.ndarray
    xy: np.ndarray
    psi: np.ndarray
    path: object

    def __post_init__(self) -> None:
        n = len(self.frames)
        for name in ("s", "v", "psi"):
            if np.shape(getattr(self, name)) != (n,):
                raise ValueError(f"{name} must have shape ({n},) like frames, got {np.shape(getattr(self, name))}")
        if np.shape(self.xy) != (n, 2):
            raise ValueError(f"xy must have shape ({n}, 2), got {np.shape(self.xy)}")


class _Grid:
    """A path tabulated every 0.5 m (beyond its ends too) for fast look-ups of points at arc lengths."""

    def __init__(self, path, extra: float) -> None:
        self.s = np.arange(-extra, path.length + extra, 0.5)
        xy = path.to_cartesian(self.s, np.zeros_like(self.s), extrapolate=True)
        self.x, self.y = xy[:, 0], xy[:, 1]

    def points(self, s: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(s, self.s, self.x), np.interp(s, self.s, self.y)], axis=-1)


def yield_gaps(tracks: list[TrackMotion], rule: ConflictRule = ConflictRule(),
               which: list[np.ndarray] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Yield gap [m] and the speed [m/s] of what the car yields to, for every track at its frames (gap inf and
    speed NaN where it need not yield), for cars recorded together.

    Parameters
    ----------
    tracks : list of TrackMotion, one recording (their frames on one clock)
    rule : ConflictRule
    which : list of int arrays, optional
        Per track, the indices of its frames to evaluate (others stay inf); default all.

    Returns
    -------
    list of (gap (n_i,) [m], speed (n_i,) [m/s])
    """
    if not isinstance(rule, ConflictRule):
        raise TypeError(f"rule must be a ConflictRule, got {type(rule).__name__}")
    extra = rule.look_ahead + 30.0 * rule.horizon
    grids: dict[int, _Grid] = {}
    for t in tracks:
        if id(t.path) not in grids:
            grids[id(t.path)] = _Grid(t.path, extra)
    at_frame: dict[int, list[tuple[int, int]]] = {}
    for i, t in enumerate(tracks):
        for k, f in enumerate(np.asarray(t.frames).tolist()):
            at_frame.setdefault(int(f), []).append((i, k))
    ahead = np.arange(1.0, rule.look_ahead + 0.5, 1.0)  # (A,)
    times = np.arange(0.0, rule.horizon + 1e-9, 0.2)  # (T,)
    out = []
    for i, ego in enumerate(tracks):
        gaps = np.full(len(ego.frames), np.inf)
        speeds = np.full(len(ego.frames), np.nan)
        idx = np.arange(len(ego.frames)) if which is None else np.asarray(which[i], dtype=int)
        grid_i = grids[id(ego.path)]
        for k in idx:
            others = [(j, kj) for j, kj in at_frame.get(int(ego.frames[k]), []) if j != i]
            if not others:
                continue
            head = np.array([np.cos(ego.psi[k]), np.sin(ego.psi[k])])
            P = grid_i.points(ego.s[k] + ahead)  # (A, 2)
            on_path = grid_i.points(ego.s[k] + np.arange(-30.0, rule.look_ahead + 0.5, 1.0))
            best, best_v = np.inf, np.nan
            for j, kj in others:
                o = tracks[j]
                if o.v[kj] < rule.min_speed:
                    continue
                rel = o.xy[kj] - ego.xy[k]
                if head[0] * rel[1] - head[1] * rel[0] <= 0:  # on the right (or straight ahead/behind)
                    continue
                if np.min(np.hypot(*(on_path - o.xy[kj]).T)) < rule.radius:  # already on the ego's path
                    continue
                Q = grids[id(o.path)].points(o.s[kj] + o.v[kj] * times)  # (T, 2)
                D = np.linalg.norm(Q[:, None, :] - P[None, :, :], axis=-1)  # (T, A)
                hit = D < rule.radius
                if not hit.any():
                    continue
                a_first = int(np.argmax(hit.any(axis=0)))  # nearest conflicting point on the ego's path
                t_j = times[int(np.argmax(hit[:, a_first]))]
                t_i = ahead[a_first] / max(float(ego.v[k]), 0.5)
                if t_i + rule.clearance <= t_j:  # the ego passes well before the other car arrives
                    continue
                if rule.obstacle == "stop":
                    gap, speed = max(ahead[a_first] - rule.stop_margin, 0.0), 0.0
                else:
                    gap, speed = ahead[a_first] - o.v[kj] * t_j - rule.stop_margin, float(o.v[kj])
                if gap < best:
                    best, best_v = gap, speed
            gaps[k], speeds[k] = best, best_v
        out.append((gaps, speeds))
    return out
