"""`ReferencePath`: a smoothed, arc-length-parametrised lane centerline with signed curvature.

`ReferencePath.from_polyline` turns a noisy map polyline into a table ``s, x, y, heading, kappa`` on a uniform
arc-length grid (s [m], heading [rad], kappa [1/m], positive = turning left): a cubic smoothing spline per
coordinate whose smoothing parameter is a length ``ell`` [m] (``smoothing``; a low-pass filter with gain
``1 / (1 + (k * ell)**4)`` at wavenumber k [rad/m]), open paths padded by circular arcs and closed ones by their
periodic continuation before the fit. Queries (`ReferencePath.position`, `heading_at`, `curvature`,
`to_cartesian`, `to_frenet`) interpolate the table linearly; ``to_cartesian(*to_frenet(p)) == p`` to round-off
for ``|d| < 1 / |kappa|``.

The smoothing, its bias and noise are explained in the documentation's "The cost model and its features" page.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from scipy.interpolate import make_smoothing_spline
from scipy.spatial import cKDTree

from .validation import is_positive_int

__all__ = ["ReferencePath", "desired_speed_from_curvature", "polyline_distances"]

DEFAULT_SMOOTHING = 4.0
"""Default smoothing length ``ell`` [m] of `ReferencePath.from_polyline`."""
DEFAULT_A_LAT = 1.8
"""Default comfortable lateral acceleration [m/s^2]."""
DEFAULT_V_MAX = 13.9
"""Default speed cap [m/s] (50 km/h)."""

_DUPLICATE_TOL = 1e-9  # [m] consecutive points closer than this are one point
_CLOSED_TOL = 1e-6  # [m] gap allowed between first and last row of a closed table
TRACK_CANDIDATES = 16  #: table vertices nearest to each point among which ``to_frenet(track=True)`` chooses
TRACK_TIE = 2.0  #: [m] candidate feet within this of the nearest one are equally near (``to_frenet(track=True)``)
TRACK_STEP = 10.0  #: [m] largest change of arc length from one point of a track to the next (``to_frenet(track=True)``)
TRACK_REACQUIRE = 10.0  #: [m] a foot this much nearer than the continued one restarts the track there


def _as_float_array(name: str, value: Any) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a numeric array, got {type(value).__name__}: {exc}") from None
    return arr


def _check_finite(name: str, arr: np.ndarray) -> None:
    if not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{name} must be finite, found {arr[bad]} at index {bad}")


def _positive_number(name: str, value: Any, *, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        allowed = "finite and >= 0" if allow_zero else "finite and > 0"
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return value


def desired_speed_from_curvature(
    kappa: Any,
    dkappa_ds: Any = 0.0,
    *,
    a_lat: float = DEFAULT_A_LAT,
    v_max: float = DEFAULT_V_MAX,
) -> tuple[np.ndarray, np.ndarray]:
    """Curvature-limited speed ``min(sqrt(a_lat / |kappa|), v_max)`` and its slope along the path.

    The cap is active where ``|kappa| <= a_lat / v_max**2``; there the result is ``v_max`` without any division.

    Parameters
    ----------
    kappa : array_like                signed curvature [1/m], any shape
    dkappa_ds : array_like            its derivative along the path [1/m^2], broadcastable with ``kappa``
    a_lat, v_max : float              lateral acceleration [m/s^2] and speed cap [m/s], > 0

    Returns
    -------
    v, dv_ds : ndarray                desired speed [m/s] and its slope [1/s] (0 where the cap is active; the
                                      one-sided value at the kink), of the broadcast shape
    """
    a_lat = _positive_number("a_lat", a_lat)
    v_max = _positive_number("v_max", v_max)
    kappa = _as_float_array("kappa", kappa)
    dkappa_ds = _as_float_array("dkappa_ds", dkappa_ds)
    _check_finite("kappa", kappa)
    _check_finite("dkappa_ds", dkappa_ds)
    kappa, dkappa_ds = np.broadcast_arrays(kappa, dkappa_ds)
    kappa_cap = a_lat / v_max**2
    abs_k = np.maximum(np.abs(kappa), kappa_cap)
    free = np.abs(kappa) > kappa_cap
    v = np.where(free, np.sqrt(a_lat / abs_k), v_max)  # exactly v_max under the cap
    dv_ds = np.where(free, -0.5 * v / abs_k * np.sign(kappa) * dkappa_ds, 0.0)
    return v, dv_ds


@dataclass(frozen=True, eq=False)
class ReferencePath:
    """A reference path tabulated on an arc-length grid, interpolated linearly.

    Build one from a noisy centerline with `from_polyline`; the constructor only validates a table (ValueError,
    TypeError).

    Parameters
    ----------
    s : array (n,)           arc length [m], strictly increasing from 0, n >= 2
    x, y : array (n,)        position [m]
    heading : array (n,)     direction of travel [rad], counter-clockwise from +x, unwrapped
    kappa : array (n,)       signed curvature [1/m], positive turning left
    closed : bool            a loop: the last row is the first point again, and arc lengths wrap modulo `length`
    """

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    kappa: np.ndarray
    closed: bool = False

    def __post_init__(self) -> None:
        names = ("s", "x", "y", "heading", "kappa")
        arrays = {}
        for name in names:
            arr = _as_float_array(name, getattr(self, name))
            if arr.ndim != 1:
                raise ValueError(f"{name} must be one-dimensional, got shape {arr.shape}")
            _check_finite(name, arr)
            arrays[name] = arr
        n = arrays["s"].shape[0]
        for name in names[1:]:
            if arrays[name].shape[0] != n:
                raise ValueError(f"{name} has {arrays[name].shape[0]} entries, s has {n}: lengths must be equal")
        if n < 2:
            raise ValueError(f"a path needs at least 2 table rows, got {n}")
        s = arrays["s"]
        if s[0] != 0.0:
            raise ValueError(f"s must start at 0, got s[0] = {s[0]}")
        steps = np.diff(s)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            raise ValueError(f"s must be strictly increasing, got s[{i}] = {s[i]} >= s[{i + 1}] = {s[i + 1]}")
        if not isinstance(self.closed, (bool, np.bool_)):
            raise TypeError(f"closed must be a bool, got {self.closed!r}")
        if self.closed:
            gap = float(np.hypot(arrays["x"][-1] - arrays["x"][0], arrays["y"][-1] - arrays["y"][0]))
            if gap > _CLOSED_TOL:
                raise ValueError(f"a closed path must end where it starts, last point is {gap} m from the first")
        for name in names:
            arrays[name].setflags(write=False)
            object.__setattr__(self, name, arrays[name])
        object.__setattr__(self, "closed", bool(self.closed))

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_polyline(
        cls,
        points: Any,
        *,
        spacing: float = 0.5,
        smoothing: float = DEFAULT_SMOOTHING,
        closed: bool = False,
    ) -> "ReferencePath":
        """Smooth a centerline polyline and tabulate it by arc length ("The cost model and its features" page).

        Parameters
        ----------
        points : array_like (P, 2)   vertices [m] in driving order; consecutive duplicates (``closed``: a last point
                                     equal to the first) are dropped
        spacing : float              largest grid step [m], > 0; the table's step is ``length / ceil(length / spacing)``
        smoothing : float            smoothing length ``ell`` [m], >= 0; 0 interpolates the resampled polyline
        closed : bool                treat the polyline as a loop (e.g. a roundabout ring)

        Returns
        -------
        path : ReferencePath         ValueError / TypeError for bad points or parameters, or a smoothing length that
                                     folds the curve back on itself
        """
        spacing = _positive_number("spacing", spacing)
        ell = _positive_number("smoothing", smoothing, allow_zero=True)
        if not isinstance(closed, (bool, np.bool_)):
            raise TypeError(f"closed must be a bool, got {closed!r}")
        pts = _as_float_array("points", points)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise ValueError(f"points must have shape (P, 2), got shape {pts.shape}")
        _check_finite("points", pts)

        keep = np.concatenate(([True], np.hypot(*np.diff(pts, axis=0).T) > _DUPLICATE_TOL))
        pts = pts[keep]
        if closed and len(pts) > 1 and np.hypot(*(pts[-1] - pts[0])) <= _DUPLICATE_TOL:
            pts = pts[:-1]
        if len(pts) < 2:
            raise ValueError(f"points must contain at least 2 distinct points, got {len(pts)}")
        if closed:
            if len(pts) < 3:
                raise ValueError(f"a closed path needs at least 3 distinct points, got {len(pts)}")
            pts = np.vstack([pts, pts[:1]])

        # 1. uniform resampling by polyline arc length t
        chord = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))))
        total = float(chord[-1])
        if total < spacing:
            raise ValueError(f"the polyline is {total:.6g} m long, shorter than spacing = {spacing} m")
        m = int(np.ceil(total / spacing - 1e-9)) + 1
        t = np.linspace(0.0, total, m)
        h = total / (m - 1)
        xy = np.column_stack([np.interp(t, chord, pts[:, 0]), np.interp(t, chord, pts[:, 1])])

        # 2. padded smoothing spline per coordinate
        pad = max(12.0 * ell, 4.0 * h)  # the end effect decays like exp(-pad / (sqrt(2) ell)) ~ 2e-4
        if closed:
            t_fit, xy_fit = _pad_periodic(t, xy, pad)
        else:
            t_fit, xy_fit = _pad_arc(t, xy, h, pad, window=max(4.0 * ell, 4.0 * h))
        lam = ell**4 / h
        spl_x = make_smoothing_spline(t_fit, xy_fit[:, 0], lam=lam)
        spl_y = make_smoothing_spline(t_fit, xy_fit[:, 1], lam=lam)

        # 3. true arc length of the smoothed curve, then a uniform table in it
        t_dense = np.linspace(0.0, total, 8 * (m - 1) + 1)
        speed = np.hypot(spl_x(t_dense, 1), spl_y(t_dense, 1))
        if np.min(speed) < 1e-3:  # the polyline doubles back on a scale below ell
            raise ValueError(
                f"smoothing = {ell} m folds this polyline back on itself (it reverses within a few ell); "
                "use a smaller smoothing length or clean the polyline"
            )
        s_dense = np.concatenate(([0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t_dense))))
        length = float(s_dense[-1])
        n = max(int(np.ceil(length / spacing - 1e-9)), 1) + 1
        s_tab = np.linspace(0.0, length, n)
        t_tab = np.interp(s_tab, s_dense, t_dense)
        dx, dy = spl_x(t_tab, 1), spl_y(t_tab, 1)
        ddx, ddy = spl_x(t_tab, 2), spl_y(t_tab, 2)
        x_tab, y_tab = spl_x(t_tab), spl_y(t_tab)
        heading = np.unwrap(np.arctan2(dy, dx))
        kappa = (dx * ddy - dy * ddx) / np.hypot(dx, dy) ** 3
        if closed:  # the fit is periodic up to round-off and the decayed padding error: close it exactly
            x_tab[-1], y_tab[-1], kappa[-1] = x_tab[0], y_tab[0], kappa[0]
            turns = np.round((heading[-1] - heading[0]) / (2 * np.pi))
            heading[-1] = heading[0] + 2 * np.pi * turns
        return cls(s=s_tab, x=x_tab, y=y_tab, heading=heading, kappa=kappa, closed=bool(closed))

    # ------------------------------------------------------------------ table interpolation

    @property
    def length(self) -> float:
        """Arc length of the path [m]."""
        return float(self.s[-1])

    def _locate(self, s: Any, extrapolate: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Segment index, fraction in it, and masks before the start / after the end, for arc lengths s."""
        s = _as_float_array("s", s)
        _check_finite("s", s)
        length = self.length
        if self.closed:
            s = np.mod(s, length)
        elif not extrapolate:
            out = (s < 0.0) | (s > length)
            if np.any(out):
                bad = s[out].flat[0]
                raise ValueError(
                    f"s = {bad} m is outside the path [0, {length:.6g}] m; pass extrapolate=True to extend it "
                    "along the end headings"
                )
        j = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 2)
        ds = self.s[j + 1] - self.s[j]
        u = (s - self.s[j]) / ds
        before, after = s < 0.0, s > length
        return j, u, before, after

    def _interp(self, values: np.ndarray, j: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        step = values[j + 1] - values[j]
        return values[j] + np.clip(u, 0.0, 1.0) * step, step / (self.s[j + 1] - self.s[j])

    def _frame(self, s: Any, extrapolate: bool):
        """Position (..., 2), its s-derivative (..., 2), heading and its s-derivative, with extension."""
        j, u, before, after = self._locate(s, extrapolate)
        x, dx = self._interp(self.x, j, u)
        y, dy = self._interp(self.y, j, u)
        h, dh = self._interp(self.heading, j, u)
        outside = before | after
        if np.any(outside):
            s_arr = np.asarray(s, dtype=float)
            over = np.where(before, s_arr, s_arr - self.length)  # signed distance beyond the end
            h_end = np.where(before, self.heading[0], self.heading[-1])
            c, sn = np.cos(h_end), np.sin(h_end)
            x = np.where(outside, np.where(before, self.x[0], self.x[-1]) + over * c, x)
            y = np.where(outside, np.where(before, self.y[0], self.y[-1]) + over * sn, y)
            dx, dy = np.where(outside, c, dx), np.where(outside, sn, dy)
            h, dh = np.where(outside, h_end, h), np.where(outside, 0.0, dh)
        return np.stack([x, y], axis=-1), np.stack([dx, dy], axis=-1), h, dh

    def position(self, s: Any, *, extrapolate: bool = False) -> np.ndarray:
        """Point on the path at arc length s.

        Parameters
        ----------
        s : array_like           arc length [m] in ``[0, length]`` (closed path: any value, wrapped); else ValueError
        extrapolate : bool       extend an open path beyond its ends as straight lines along the end headings

        Returns
        -------
        xy : ndarray             shape s.shape + (2,), position [m]
        """
        return self._frame(s, extrapolate)[0]

    def heading_at(self, s: Any, *, extrapolate: bool = False) -> np.ndarray:
        """Heading [rad] at arc length s [m], shape s.shape, unwrapped along the table; see `position`."""
        return self._frame(s, extrapolate)[2]

    def curvature(self, s: Any, *, extrapolate: bool = False) -> np.ndarray:
        """Signed curvature [1/m] at arc length s [m], shape s.shape, 0 on the extensions; see `position`."""
        return self._curvature_and_slope(s, extrapolate)[0]

    def _curvature_and_slope(self, s: Any, extrapolate: bool) -> tuple[np.ndarray, np.ndarray]:
        j, u, before, after = self._locate(s, extrapolate)
        k, dk = self._interp(self.kappa, j, u)
        outside = before | after
        return np.where(outside, 0.0, k), np.where(outside, 0.0, dk)

    # ------------------------------------------------------------------ Frenet frame

    def to_cartesian(self, s: Any, d: Any, *, extrapolate: bool = False) -> np.ndarray:
        """Point at arc length s and signed lateral offset d: ``position(s) + d * (-sin(heading), cos(heading))`` [m].

        Parameters
        ----------
        s : array_like              arc length [m]; range rules as in `position`
        d : array_like              lateral offset [m], positive to the left, broadcastable with ``s``
        extrapolate : bool          as in `position`

        Returns
        -------
        xy : ndarray                shape broadcast(s, d).shape + (2,)
        """
        s_arr = _as_float_array("s", s)
        d_arr = _as_float_array("d", d)
        _check_finite("d", d_arr)
        s_arr, d_arr = np.broadcast_arrays(s_arr, d_arr)
        p, _, h, _ = self._frame(s_arr, extrapolate)
        return p + d_arr[..., None] * np.stack([-np.sin(h), np.cos(h)], axis=-1)

    @cached_property
    def _tree(self) -> cKDTree:
        return cKDTree(np.column_stack([self.x, self.y]))

    def _chord_foot(self, q: np.ndarray, i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Best chord projection of points ``q`` (..., 2) on the two table segments next to vertices ``i`` (...):
        (arc length, distance) [m], each of shape i.shape."""
        n = len(self.s)
        verts = np.column_stack([self.x, self.y])
        best_s = np.zeros(i.shape)
        best_dist = np.full(i.shape, np.inf)
        for j in (np.clip(i - 1, 0, n - 2), np.clip(i, 0, n - 2)):
            a, b = verts[j], verts[j + 1]
            ab = b - a
            u = np.clip(np.einsum("...j,...j->...", q - a, ab) / np.einsum("...j,...j->...", ab, ab), 0.0, 1.0)
            dist = np.hypot(*np.moveaxis(q - a - u[..., None] * ab, -1, 0))
            better = dist < best_dist
            best_dist = np.where(better, dist, best_dist)
            best_s = np.where(better, self.s[j] + u * (self.s[j + 1] - self.s[j]), best_s)
        return best_s, best_dist

    def _follow_track(self, q: np.ndarray) -> np.ndarray:
        """Chord-foot arc lengths (n,) [m] of one vehicle's points ``q`` (n, 2) in time order (``to_frenet`` with
        ``track``): the first point's of smallest arc length among its `TRACK_CANDIDATES` nearest vertices' feet
        within `TRACK_TIE` of the nearest; every later point's nearest foot within `TRACK_STEP` of the previous
        arc length, unless the nearest foot anywhere is more than `TRACK_REACQUIRE` nearer (the track was
        placed on the wrong pass)."""
        n = len(self.s)
        _, cand = self._tree.query(q[:1], k=min(TRACK_CANDIDATES, n))
        s0, dist0 = self._chord_foot(q[:1, None, :], cand.reshape(1, -1))
        prev = float(s0[0][dist0[0] <= dist0[0].min() + TRACK_TIE].min())
        glob_s, glob_dist = self._chord_foot(q, self._tree.query(q)[1])
        out = np.empty(len(q))
        out[0] = prev
        for k in range(1, len(q)):
            jump = abs(glob_s[k] - prev)
            if (min(jump, self.length - jump) if self.closed else jump) <= TRACK_STEP:
                out[k] = prev = float(glob_s[k])  # the nearest foot continues the track
                continue
            if self.closed:  # the window wraps around
                gap = np.abs((self.s - prev + 0.5 * self.length) % self.length - 0.5 * self.length)
                idx = np.flatnonzero(gap <= TRACK_STEP + np.max(np.diff(self.s)))
            else:
                lo = max(int(np.searchsorted(self.s, prev - TRACK_STEP)) - 1, 0)
                idx = np.arange(lo, min(int(np.searchsorted(self.s, prev + TRACK_STEP)) + 1, n - 1) + 1)
            s_loc, d_loc = self._chord_foot(q[k], idx)
            j = int(np.argmin(d_loc))
            near = d_loc[j] <= glob_dist[k] + TRACK_REACQUIRE
            out[k] = prev = float(s_loc[j]) if near else float(glob_s[k])
        return out

    def to_frenet(self, xy: Any, *, extrapolate: bool = False, max_iter: int = 50,
                  track: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Project points onto the path: arc length and signed lateral offset.

        Inverts `to_cartesian` for ``|d| < 1 / |kappa|``; the method: "The cost model and its features" page.

        Parameters
        ----------
        xy : array_like (..., 2)    points [m]; with ``track``, (n, 2) in time order
        extrapolate : bool          allow projections onto the straight extensions of an open path (else ValueError)
        max_iter : int              Newton iteration limit (ValueError without convergence)
        track : bool                seek each foot point near the previous one (a path may pass a place twice)

        Returns
        -------
        s, d : ndarray (...)        arc length [m] of the foot point (``[0, length)`` if closed), offset [m], left > 0
        """
        if not is_positive_int(max_iter):
            raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
        q = _as_float_array("xy", xy)
        if q.ndim < 1 or q.shape[-1] != 2:
            raise ValueError(f"xy must have shape (..., 2), got shape {q.shape}")
        _check_finite("xy", q)
        shape = q.shape[:-1]
        q = q.reshape(-1, 2)
        length = self.length

        # initial guess: best chord projection on the two segments next to the nearest vertex (with track: next to
        # the vertex that continues the track, `_follow_track`)
        if track:
            if len(shape) != 1:
                raise ValueError(f"track=True needs xy of shape (n, 2), one vehicle's positions, got {shape + (2,)}")
            best_s = self._follow_track(q)
        else:
            _, i = self._tree.query(q)
            best_s, _ = self._chord_foot(q, i)

        # Newton on f(s) = (q - p(s)) . t(s); f'(s) = -p'(s) . t(s) + h'(s) (q - p(s)) . n(s)
        s = best_s
        seg = float(np.max(np.diff(self.s)))
        for _ in range(max_iter):
            p, dp, h, dh = self._frame(s, True)
            tang = np.stack([np.cos(h), np.sin(h)], axis=-1)
            norm = np.stack([-np.sin(h), np.cos(h)], axis=-1)
            r = q - p
            f = np.einsum("ij,ij->i", r, tang)
            fprime = -np.einsum("ij,ij->i", dp, tang) + dh * np.einsum("ij,ij->i", r, norm)
            step = np.clip(-f / np.minimum(fprime, -0.05), -seg, seg)
            s = s + step
            if self.closed:
                s = np.mod(s, length)
            if np.max(np.abs(step), initial=0.0) <= 1e-12 * max(1.0, length):
                break
        p, _, h, _ = self._frame(s, True)
        residual = np.abs(np.einsum("ij,ij->i", q - p, np.stack([np.cos(h), np.sin(h)], axis=-1)))
        if np.any(residual > 1e-7):
            k = int(np.argmax(residual))
            raise ValueError(
                f"point {q[k].tolist()} has no foot point on the path after {max_iter} Newton steps "
                f"(residual {residual[k]:.3g} m); is it beyond the centre of curvature, |d| >= 1/|kappa|?"
            )

        if not self.closed:
            tol = 1e-9 * max(1.0, length)
            out = (s < -tol) | (s > length + tol)
            if not extrapolate and np.any(out):
                k = int(np.argmax(out))
                raise ValueError(
                    f"point {q[k].tolist()} projects to s = {s[k]:.6g} m, outside the path [0, {length:.6g}] m; "
                    "pass extrapolate=True to use the straight extensions"
                )
            if not extrapolate:
                s = np.clip(s, 0.0, length)
        p, _, h, _ = self._frame(s, True)
        d = np.einsum("ij,ij->i", q - p, np.stack([-np.sin(h), np.cos(h)], axis=-1))
        return s.reshape(shape), d.reshape(shape)

    # ------------------------------------------------------------------ speed feature

    def desired_speed(
        self, s: Any, a_lat: float = DEFAULT_A_LAT, v_max: float = DEFAULT_V_MAX, *, extrapolate: bool = False
    ) -> np.ndarray:
        """Curvature-limited speed ``min(sqrt(a_lat / |kappa(s)|), v_max)`` [m/s], shape s.shape.

        ``kappa == 0`` gives ``v_max`` (no division by zero). See `desired_speed_from_curvature`.
        """
        return self.desired_speed_and_slope(s, a_lat, v_max, extrapolate=extrapolate)[0]

    def desired_speed_and_slope(
        self, s: Any, a_lat: float = DEFAULT_A_LAT, v_max: float = DEFAULT_V_MAX, *, extrapolate: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """Desired speed [m/s] and its exact derivative d v / d s [1/s] under the linear interpolation.

        Parameters
        ----------
        s : array_like           arc length [m]; range rules as in `position`
        a_lat, v_max : float     lateral acceleration [m/s^2] and speed cap [m/s], > 0
        extrapolate : bool       as in `position` (curvature 0, so ``v_max``, on the extensions)

        Returns
        -------
        v, dv_ds : ndarray       shape s.shape; the slope of the table segment at or before s (right-hand derivative
                                 at nodes), 0 where the cap is active
        """
        kappa, dkappa = self._curvature_and_slope(s, extrapolate)
        return desired_speed_from_curvature(kappa, dkappa, a_lat=a_lat, v_max=v_max)


def _pad_arc(t: np.ndarray, xy: np.ndarray, h: float, pad: float, window: float):
    """Extend samples (t, xy) of an open curve by ``pad`` [m] at both ends with circular arcs.

    Each end's last ``window`` [m] get a least-squares cubic in t; the arc starts at the fitted end point
    along the fitted end heading, with the fitted curvature at the middle of the window (where a cubic
    estimates it with the least bias and noise). Constant-curvature padding reproduces lines and circles,
    so the spline's natural end conditions (x'' = 0) act outside [0, t[-1]] and barely reach the path.
    """
    poly = np.polynomial.polynomial
    n_pad = int(np.ceil(pad / h))
    total = t[-1]
    window = min(window, total)
    before, after = -h * np.arange(n_pad, 0, -1), h * np.arange(1, n_pad + 1)
    ends = []
    first, last = t <= window, t >= total - window
    for tau, data, new in ((t[first], xy[first], before), (t[last] - total, xy[last], after)):
        coef = poly.polyfit(tau, data, min(3, len(tau) - 1))
        d1 = poly.polyval(0.0, poly.polyder(coef))
        mid = 0.5 * (tau[0] + tau[-1])
        m1, m2 = poly.polyval(mid, poly.polyder(coef)), poly.polyval(mid, poly.polyder(coef, 2))
        kappa = (m1[0] * m2[1] - m1[1] * m2[0]) / np.hypot(*m1) ** 3
        theta = np.arctan2(d1[1], d1[0])  # type: ignore[index]
        half = 0.5 * kappa * new  # an arc of length L and curvature k has chord L sinc(k L / 2) at angle k L / 2
        chord = new * np.sinc(half / np.pi)
        start = poly.polyval(0.0, coef)
        ends.append(start + np.column_stack([chord * np.cos(theta + half), chord * np.sin(theta + half)]))
    return np.concatenate([before, t, total + after]), np.vstack([ends[0], xy, ends[1]])


def _pad_periodic(t: np.ndarray, xy: np.ndarray, pad: float):
    """Extend samples of a closed curve (last sample = first) by ``pad`` [m] with its periodic copies."""
    total = t[-1]
    base_t, base_xy = t[:-1], xy[:-1]
    reps = int(np.ceil(pad / total))
    shifts = np.arange(-reps, reps + 1)
    all_t = (base_t[None, :] + total * shifts[:, None]).ravel()
    all_xy = np.tile(base_xy, (len(shifts), 1))
    keep = (all_t >= -pad) & (all_t <= total + pad)
    return all_t[keep], all_xy[keep]


def polyline_distances(lines, xy, *, spacing: float = 0.5) -> np.ndarray:
    """Distance [m] from each point to the nearest of several polylines, shape (n,).

    Exact distances to the segments of the polyline points (every ``spacing`` m along each segment) nearest to
    each point. ``lines``: polylines of shape (P, 2), P >= 2; ``xy``: points of shape (n, 2) [m]."""
    from scipy.spatial import cKDTree

    starts, ends, pts, owner = [], [], [], []  # type: ignore[var-annotated]
    for line in lines:
        line = np.asarray(line, dtype=float)
        for p, q in zip(line[:-1], line[1:]):
            k = max(int(np.ceil(np.hypot(*(q - p)) / spacing)), 1)
            pts.append(p + np.linspace(0.0, 1.0, k + 1)[:, None] * (q - p))
            owner.append(np.full(k + 1, len(starts)))
            starts.append(p)
            ends.append(q)
    if not pts:
        raise ValueError("polyline_distances: no polyline with two points or more")
    a, b = np.array(starts), np.array(ends)
    owner = np.concatenate(owner)  # type: ignore[assignment]
    xy = np.asarray(xy, dtype=float)
    k = min(6, len(owner))
    _, idx = cKDTree(np.concatenate(pts)).query(xy, k=k)
    seg = owner[idx.reshape(len(xy), k)]                     # (n, k) candidate segments
    e = b[seg] - a[seg]
    w = xy[:, None, :] - a[seg]
    u = np.clip(np.sum(w * e, -1) / np.maximum(np.sum(e * e, -1), 1e-12), 0.0, 1.0)
    return np.sqrt(np.sum((w - u[..., None] * e) ** 2, -1)).min(axis=1)
