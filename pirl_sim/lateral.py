"""Lateral offsets of predictions along a reference path: hold the last offset, or follow the driven mean path.

The roundabout model predicts motion *along* a path (s, v, a); the lateral offset d [m] across it comes from one
of the rules of `predict_offsets`, shared by every path-based predictor (baselines and learners alike):
``"hold"`` (the last offset, the paper's choice), ``"mean-path"`` (the median offset training tracks of the same
route drove at the predicted arc length, `MeanOffsetProfile`, plus the car's own deviation from it at the start),
``"plane"`` (as mean-path, pooled over every training track that drove there where the route's own are too few,
`MeanOffsetProfile.fit_plane`) and ``"neighbours"`` (as plane, the deviation changing as it did after the
nearest training windows, `NeighbourOffsets`). Offsets of a recorded track are read at its observed arc lengths
(`observed_s`).

The rules are explained in the documentation's "The cost model and its features" page (lateral offsets).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

__all__ = ["LATERAL_MODELS", "MeanOffsetProfile", "NeighbourOffsets", "observed_s", "predict_offsets"]

LATERAL_MODELS = ("hold", "mean-path", "plane", "neighbours")


@dataclass(frozen=True)
class MeanOffsetProfile:
    """Median lateral offset [m] per route (segment) and arc-length bin, from training tracks.

    Parameters
    ----------
    bin_width : float [m]   arc-length bins
    min_count : int         a bin needs offsets of at least this many samples
    smooth : int            bins on each side averaged into each bin's value (bins without data skipped)
    """

    bin_width: float = 1.0
    min_count: int = 3
    smooth: int = 2
    _table: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not np.isfinite(self.bin_width) or self.bin_width <= 0:
            raise ValueError(f"bin_width must be > 0 m, got {self.bin_width!r}")
        for name in ("min_count", "smooth"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (1 if name == "min_count" else 0):
                raise ValueError(f"{name} must be a whole number >= {1 if name == 'min_count' else 0}, got {v!r}")

    def fit(self, segment: np.ndarray, s: np.ndarray, d: np.ndarray) -> "MeanOffsetProfile":
        """Fit on samples: route index (n,), composite arc length s (n,) [m], offset d (n,) [m].

        Returns a new fitted profile (this one is not changed)."""
        segment = np.asarray(segment)
        s, d = np.asarray(s, dtype=float), np.asarray(d, dtype=float)
        if not (segment.shape == s.shape == d.shape) or s.ndim != 1:
            raise ValueError(f"segment, s and d must be 1-D of one length, got {segment.shape}, {s.shape}, {d.shape}")
        ok = np.isfinite(s) & np.isfinite(d)
        if not ok.all():
            raise ValueError(f"s and d must be finite; {int((~ok).sum())} of {len(s)} samples are not")
        table: dict[int, dict[int, float]] = {}
        bins = np.floor(s / self.bin_width).astype(np.int64)
        for seg in np.unique(segment):
            on = segment == seg
            b, dd = bins[on], d[on]
            order = np.argsort(b, kind="stable")
            b, dd = b[order], dd[order]
            keys, starts = np.unique(b, return_index=True)
            medians = {int(k): float(np.median(part)) for k, part in zip(keys, np.split(dd, starts[1:]))
                       if len(part) >= self.min_count}
            table[int(seg)] = medians
        out = MeanOffsetProfile(self.bin_width, self.min_count, self.smooth)
        object.__setattr__(out, "_table", table)
        return out

    def fit_plane(self, path, xy: np.ndarray, *, min_speed_step: float = 0.1, window: float = 2.0,
                  max_offset: float = 4.0, max_angle: float = 0.5, margin: float = 20.0) -> "MeanOffsetProfile":
        """Fit on samples in the plane, pooled over routes: each bin gets the median offset of the training samples near
        its centreline point that move along it (bins with fewer than ``min_count`` samples stay empty).

        Parameters
        ----------
        path : ReferencePath or pirl_sim.driving.CompositePath   the routes (a ReferencePath is route 0)
        xy : list of arrays (n_i, 2) [m]   training tracks' positions, one array per track, in time order
        min_speed_step : float [m]   a sample counts when its track moved at least this far per step around it
        window, max_offset : float [m]   samples within +- window along and +- max_offset across a bin's point
        max_angle : float [rad]      ... whose heading is within this angle of the route's
        margin : float [m]           bins also this far beyond each route's ends (predictions run past them); returns
                                     a new fitted profile
        """
        from scipy.spatial import cKDTree

        from pirl_sim.paths import ReferencePath

        limits = {"window": window, "max_offset": max_offset, "max_angle": max_angle}
        for name, v in {**limits, "margin": margin, "min_speed_step": min_speed_step}.items():
            if not np.isfinite(v) or v < 0 or (v == 0 and name in limits):
                raise ValueError(f"{name} must be a finite number > 0 (margin, min_speed_step >= 0), got {v!r}")
        points, headings = [], []
        for i, track in enumerate(xy):
            track = np.asarray(track, dtype=float)
            if track.ndim != 2 or track.shape[1] != 2 or not np.all(np.isfinite(track)):
                raise ValueError(f"xy[{i}] must be a finite (n, 2) array of positions, got shape {track.shape}")
            if len(track) < 2:
                continue
            step = np.gradient(track, axis=0)
            norm = np.linalg.norm(step, axis=1)
            moving = norm >= max(min_speed_step, 1e-9)
            points.append(track[moving])
            headings.append(step[moving] / norm[moving, None])
        if not points or not sum(len(p) for p in points):
            raise ValueError("fit_plane needs moving training samples; every track stood still or was empty")
        pts, hdg = np.concatenate(points), np.concatenate(headings)
        tree = cKDTree(pts)
        radius = float(np.hypot(window, max_offset))
        cos_max = float(np.cos(max_angle))
        routes = [path] if isinstance(path, ReferencePath) else list(path.segments)
        offsets = np.zeros(1) if isinstance(path, ReferencePath) else np.asarray(path.offsets)
        table: dict[int, dict[int, float]] = {}
        for k, route in enumerate(routes):
            first = int(np.floor((offsets[k] - margin) / self.bin_width))
            last = int(np.floor((offsets[k] + route.length + margin) / self.bin_width))
            bins = np.arange(first, last + 1)
            local = (bins + 0.5) * self.bin_width - offsets[k]
            centre = route.to_cartesian(local, np.zeros_like(local), extrapolate=True)
            normal = route.to_cartesian(local, np.ones_like(local), extrapolate=True) - centre
            tangent = np.stack([normal[:, 1], -normal[:, 0]], axis=1)
            medians = {}
            for b, c, n, tg, near in zip(bins, centre, normal, tangent, tree.query_ball_point(centre, radius)):
                if len(near) < self.min_count:
                    continue
                rel = pts[near] - c
                lat = rel @ n
                ok = (np.abs(rel @ tg) <= window) & (np.abs(lat) <= max_offset) & (hdg[near] @ tg >= cos_max)
                if ok.sum() >= self.min_count:
                    medians[int(b)] = float(np.median(lat[ok]))
            table[k] = medians
        out = MeanOffsetProfile(self.bin_width, self.min_count, self.smooth)
        object.__setattr__(out, "_table", table)
        return out

    def backed_by(self, other: "MeanOffsetProfile") -> "MeanOffsetProfile":
        """This fitted profile, with ``other``'s bins where this one has none (same bins required): e.g. the
        per-route profile backed by the pooled one."""
        if (self.bin_width, self.smooth) != (other.bin_width, other.smooth):
            raise ValueError("backed_by needs profiles with the same bin_width and smooth")
        table = {seg: {**other._table.get(seg, {}), **self._table.get(seg, {})}
                 for seg in set(self._table) | set(other._table)}
        out = MeanOffsetProfile(self.bin_width, self.min_count, self.smooth)
        object.__setattr__(out, "_table", table)
        return out

    @property
    def fitted(self) -> bool:
        return bool(self._table)

    def __call__(self, segment: int, s: np.ndarray) -> np.ndarray:
        """dbar at arc lengths s (any shape) [m] on route ``segment``; NaN where no bin within ``smooth`` has
        data."""
        if not self.fitted:
            raise ValueError("MeanOffsetProfile is not fitted: call fit(segment, s, d) first")
        s = np.asarray(s, dtype=float)
        medians = self._table.get(int(segment), {})
        out = np.full(s.shape, np.nan)
        if not medians:
            return out
        b = np.floor(s / self.bin_width).astype(np.int64)
        for idx in np.ndindex(s.shape):
            vals = [medians[k] for k in range(b[idx] - self.smooth, b[idx] + self.smooth + 1) if k in medians]
            if vals:
                out[idx] = float(np.mean(vals))
        return out


def observed_s(track) -> np.ndarray:
    """Arc lengths (n_steps + 1,) [m] at which a track's offsets ``d`` were observed: its metadata's ``s_obs``
    (recorded tracks: the projection of each recorded position), else its states' s (exact simulated states).
    A recorded track's states come from a smoother that also saw the steps after each one; the offset at a step
    belongs to the observed arc length, and a window's history must not depend on its future."""
    s_obs = track.metadata.get("s_obs")
    if s_obs is None:
        return track.states[:, 0]
    s_obs = np.asarray(s_obs, dtype=float)
    if s_obs.shape != track.states[:, 0].shape:
        raise ValueError(f"metadata s_obs has shape {s_obs.shape}, the track {track.states[:, 0].shape}: pass whole "
                         "recorded pieces, not windows cut from them")
    return s_obs


def predict_offsets(kind: str, d0: float, segment: int, s0: float, s_pred: np.ndarray,
                    profile: MeanOffsetProfile | None = None) -> np.ndarray:
    """Lateral offsets [m] at the predicted arc lengths ``s_pred`` (H,) of one window (module doc).

    Parameters
    ----------
    kind : {"hold", "mean-path", "plane"}  (``"neighbours"`` needs the window's history:
                         `NeighbourOffsets.predict`)
    d0 : float [m]       last observed offset
    segment : int        the track's route
    s0 : float [m]       arc length at the start of the prediction
    s_pred : array (H,)  predicted arc lengths [m]
    profile : fitted MeanOffsetProfile (``"mean-path"``: `MeanOffsetProfile.fit`; ``"plane"``: ``fit_plane``)
    """
    if kind not in LATERAL_MODELS:
        raise ValueError(f"lateral model must be one of {LATERAL_MODELS}, got {kind!r}")
    s_pred = np.asarray(s_pred, dtype=float)
    held = np.full(s_pred.shape, float(d0))
    if kind == "hold":
        return held
    if kind == "neighbours":
        raise ValueError("lateral model 'neighbours' predicts from the window's history: use NeighbourOffsets.predict")
    if profile is None:
        raise ValueError(f"lateral model {kind!r} needs a fitted MeanOffsetProfile")
    base = profile(segment, np.concatenate([[s0], s_pred.ravel()]))
    if not np.all(np.isfinite(base)):
        return held
    return base[1:].reshape(s_pred.shape) + (float(d0) - base[0])


@dataclass(frozen=True)
class NeighbourOffsets:
    """Lateral offsets from the mean path plus the change of deviation of the nearest training windows
    (module doc, ``"neighbours"``; the look-up: "The cost model and its features" page).

    Parameters
    ----------
    n_neighbors : int             training windows averaged per prediction (inverse distance)
    stride : int [steps]          between training windows along a track
    heading_time : float [s]      the heading is taken over this much of the history
    deviation_times : tuple of float [s]  the deviation is also looked up this long before the window's end
    position_scale : float [m]    a distance in the plane of this much counts as 1 in the look-up
    heading_weight : float        the unit heading vector's weight in the look-up
    offset_scale : float [m]      a deviation difference of this much counts as 1
    """

    n_neighbors: int = 20
    stride: int = 2
    heading_time: float = 0.5
    deviation_times: tuple = (0.5, 1.0)
    position_scale: float = 5.0
    heading_weight: float = 3.0
    offset_scale: float = 1.0
    _fit: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("n_neighbors", "stride"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be a whole number >= 1, got {v!r}")
        for name in ("heading_time", "position_scale", "heading_weight", "offset_scale"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v) \
                    or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        try:
            times = tuple(float(t) for t in self.deviation_times)
        except (TypeError, ValueError):
            raise TypeError(f"deviation_times must be a sequence of durations [s], got {self.deviation_times!r}") \
                from None
        if any(not np.isfinite(t) or t <= 0 for t in times):
            raise ValueError(f"deviation_times must be finite durations > 0 [s], got {self.deviation_times!r}")

    def _lookup(self, track, step: int, delta: np.ndarray) -> np.ndarray:
        """Look-up coordinates of the window ending at ``step``; ``delta`` (n_steps + 1,) the track's deviation
        (NaN where the mean path is unknown: the deviation at ``step`` is used there)."""
        xy = np.asarray(track.metadata["xy"], dtype=float)
        back = max(step - max(1, int(round(self.heading_time / track.dt))), 0)
        move = xy[step] - xy[back]
        norm = float(np.hypot(*move))
        heading = move / norm if norm > 1e-6 else np.zeros(2)
        earlier = [delta[max(step - int(round(t / track.dt)), 0)] for t in self.deviation_times]
        earlier = [e if np.isfinite(e) else delta[step] for e in earlier]
        return np.array([xy[step, 0] / self.position_scale, xy[step, 1] / self.position_scale,
                         self.heading_weight * heading[0], self.heading_weight * heading[1],
                         *(np.array([delta[step], *earlier]) / self.offset_scale)])

    @staticmethod
    def _deviation(profile: MeanOffsetProfile, track) -> np.ndarray:
        """delta = d - dbar(s) over a whole track (n_steps + 1,) [m]; NaN where the profile has no data."""
        return np.asarray(track.metadata["d"], dtype=float) - profile(int(track.metadata.get("segment", 0)),
                                                                       observed_s(track))

    def fit(self, profile: MeanOffsetProfile, train, horizon: int) -> "NeighbourOffsets":
        """Fit on training tracks (Trajectory with ``metadata`` "xy" (n+1, 2) [m], "d" (n+1,) [m] and
        "segment") under the fitted mean-path ``profile``, for predictions of ``horizon`` steps.

        Returns a new fitted model (this one is not changed). Windows whose mean path is unknown anywhere
        over their horizon are skipped; ValueError if fewer than ``n_neighbors`` are left."""
        from scipy.spatial import cKDTree

        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
            raise ValueError(f"horizon must be a whole number of steps >= 1, got {horizon!r}")
        if not isinstance(profile, MeanOffsetProfile) or not profile.fitted:
            raise ValueError("NeighbourOffsets.fit needs a fitted MeanOffsetProfile")
        keys, targets = [], []
        for track in train:
            delta = self._deviation(profile, track)
            for step in range(1, len(delta) - horizon, self.stride):
                future = delta[step : step + horizon + 1]
                if np.all(np.isfinite(future)):
                    keys.append(self._lookup(track, step, delta))
                    targets.append(future[1:] - future[0])
        if len(keys) < self.n_neighbors:
            raise ValueError(f"NeighbourOffsets needs at least n_neighbors={self.n_neighbors} training windows "
                             f"of {horizon} steps on the mean path, found {len(keys)}")
        out = dataclasses.replace(self)
        object.__setattr__(out, "_fit", {"profile": profile, "horizon": int(horizon), "tree": cKDTree(np.stack(keys)),
                                         "targets": np.stack(targets)})
        return out

    @property
    def fitted(self) -> bool:
        return bool(self._fit)

    @property
    def profile(self) -> MeanOffsetProfile:
        """The fitted mean path."""
        if not self.fitted:
            raise ValueError("NeighbourOffsets is not fitted: call fit(profile, train, horizon) first")
        return self._fit["profile"]

    def predict(self, tracks, windows, s_pred: np.ndarray) -> np.ndarray:
        """Offsets (W, H) [m] at the predicted arc lengths ``s_pred`` (W, H) of the windows (track index, step):
        the prediction starts after ``step`` of ``tracks[i]``. Held offsets where the mean path is unknown."""
        profile = self.profile
        s_pred = np.asarray(s_pred, dtype=float)
        if s_pred.ndim != 2 or len(s_pred) != len(windows) or s_pred.shape[1] > self._fit["horizon"]:
            raise ValueError(f"s_pred must be (W={len(windows)}, H <= {self._fit['horizon']}), got {s_pred.shape}")
        out = np.empty_like(s_pred)
        keys, rows, deviations = [], [], {}
        for w, (i, step) in enumerate(windows):
            track = tracks[i]
            d0 = float(track.metadata["d"][step])
            s0 = observed_s(track)[step]
            base = profile(int(track.metadata.get("segment", 0)), np.concatenate([[s0], s_pred[w]]))
            if not np.all(np.isfinite(base)):
                out[w] = d0
                continue
            out[w] = base[1:] + (d0 - base[0])
            if i not in deviations:
                deviations[i] = self._deviation(profile, track)
            delta = deviations[i].copy()
            delta[step] = d0 - base[0]
            keys.append(self._lookup(track, step, delta))
            rows.append(w)
        if rows:
            dist, idx = self._fit["tree"].query(np.stack(keys), k=self.n_neighbors)
            dist, idx = dist.reshape(len(rows), -1), idx.reshape(len(rows), -1)
            weights = 1.0 / np.maximum(dist, 1e-9)
            weights /= weights.sum(axis=1, keepdims=True)
            change = np.einsum("wk,wkh->wh", weights, self._fit["targets"][idx][:, :, : s_pred.shape[1]])
            out[rows] += change
        return out
