"""Many routes on one arc-length axis: `RouteSet` lays reference paths end to end so one batched MPC plans
vehicles of every route, and `RouteSetProfile` is the desired-speed profile along that axis."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.interpolate import CubicSpline, make_smoothing_spline

from pirl_sim.driving import desired_speed_along
from pirl_sim.paths import DEFAULT_A_LAT, DEFAULT_V_MAX, ReferencePath

__all__ = ["ROUTE_SPACING", "RouteSet", "RouteSetProfile", "NEWTON_MAX_ITER", "MIN_SLOPE"]

ROUTE_SPACING = 10_000.0  #: [m] distance between the starts of consecutive routes on the global axis
NEWTON_MAX_ITER = 50
MIN_SLOPE = -0.05  # as ReferencePath.to_frenet: floor on the Newton slope (far from centres of curvature)


@dataclass(frozen=True, eq=False)
class RouteSet:
    """Reference paths of several routes on one global arc-length axis (module doc; ValueError when invalid).

    Parameters
    ----------
    route_ids : tuple of str          unique route ids; route ``r`` starts at ``r * spacing`` on the global axis
    paths : tuple of ReferencePath    one open path per route, each shorter than ``spacing / 4``
    spacing : float                   [m], > 0
    speed_smoothing : float           smoothing length [m], >= 0, of each path's curvature for the desired speed;
                                      0: `RouteSetProfile` equals each path's `pirl_sim.driving.SpeedProfile`
    """

    route_ids: tuple[str, ...]
    paths: tuple[ReferencePath, ...]
    spacing: float = ROUTE_SPACING
    speed_smoothing: float = 0.0

    def __post_init__(self) -> None:
        ids, paths = tuple(self.route_ids), tuple(self.paths)
        if not ids:
            raise ValueError("a RouteSet needs at least one route")
        if len(ids) != len(paths):
            raise ValueError(f"got {len(ids)} route ids for {len(paths)} paths")
        repeated = sorted({r for r in ids if ids.count(r) > 1})
        if repeated:
            raise ValueError(f"route ids must be unique, repeated: {repeated}")
        if not (isinstance(self.spacing, (int, float)) and math.isfinite(self.spacing) and self.spacing > 0):
            raise ValueError(f"spacing must be a positive number of metres, got {self.spacing!r}")
        for rid, p in zip(ids, paths):
            if not isinstance(p, ReferencePath):
                raise ValueError(f"route {rid!r}: expected a ReferencePath, got {type(p).__name__}")
            if p.closed:
                raise ValueError(f"route {rid!r}: routes are open paths, got a closed one")
            if p.length >= 0.25 * self.spacing:
                raise ValueError(f"route {rid!r} is {p.length:.0f} m long; spacing = {self.spacing} m must "
                                 "exceed four times the longest route")
        ell = self.speed_smoothing
        if isinstance(ell, bool) or not isinstance(ell, (int, float)) or not math.isfinite(ell) or ell < 0:
            raise ValueError(f"speed_smoothing must be a length >= 0 m, got {ell!r}")
        object.__setattr__(self, "route_ids", ids)
        object.__setattr__(self, "paths", paths)
        object.__setattr__(self, "spacing", float(self.spacing))
        object.__setattr__(self, "speed_smoothing", float(ell))

    # -- indexing -----------------------------------------------------------------------------------

    @property
    def n_routes(self) -> int:
        return len(self.route_ids)

    @cached_property
    def offsets(self) -> np.ndarray:
        """Global arc length [m] of each route's start, shape (R,)."""
        out = self.spacing * np.arange(self.n_routes, dtype=float)
        out.setflags(write=False)
        return out

    @cached_property
    def lengths(self) -> np.ndarray:
        """Length [m] of each route's path, shape (R,)."""
        out = np.array([p.length for p in self.paths])
        out.setflags(write=False)
        return out

    def index(self, route_id: str) -> int:
        """Position of ``route_id`` in :attr:`route_ids`.

        Raises
        ------
        ValueError
            For an unknown route id (the message lists the known ones).
        """
        try:
            return self.route_ids.index(route_id)
        except ValueError:
            raise ValueError(f"unknown route {route_id!r}; routes: {', '.join(self.route_ids)}") from None

    def path(self, route_id: str) -> ReferencePath:
        """The reference path of ``route_id``."""
        return self.paths[self.index(route_id)]

    def route_of(self, s_global) -> np.ndarray:
        """Route index (int array shaped like ``s_global``) owning each global arc length [m]."""
        r = np.floor(np.asarray(s_global, dtype=float) / self.spacing + 0.5).astype(np.int64)
        return np.clip(r, 0, self.n_routes - 1)

    def to_local(self, s_global) -> tuple[np.ndarray, np.ndarray]:
        """(route index, arc length [m] along that route's path) of global arc lengths."""
        r = self.route_of(s_global)
        return r, np.asarray(s_global, dtype=float) - self.offsets[r]

    def to_global(self, route_index, s_local) -> np.ndarray:
        """Global arc length [m] of arc length ``s_local`` [m] on route(s) ``route_index``."""
        return self.offsets[np.asarray(route_index, dtype=np.int64)] + np.asarray(s_local, dtype=float)

    # -- geometry (vectorised over routes) ----------------------------------------------------------

    @cached_property
    def _tables(self) -> dict[str, np.ndarray]:
        n = np.array([len(p.s) for p in self.paths], dtype=np.int64)
        base = np.concatenate(([0], np.cumsum(n)[:-1])).astype(np.int64)
        rows = np.concatenate([np.column_stack([p.s, p.x, p.y, p.heading]) for p in self.paths])
        return {
            "base": base,
            "n": n,
            "inv_step": np.array([1.0 / (p.s[1] - p.s[0]) for p in self.paths]),
            "step": np.array([p.s[1] - p.s[0] for p in self.paths]),
            "length": np.array([p.length for p in self.paths]),
            "rows": rows,  # (sum n, 4): s, x, y, heading of every table row, route after route
            "first": rows[base],
            "last": rows[base + n - 1],
        }

    def _frame(self, r: np.ndarray, s: np.ndarray):
        """Position, its s-derivative, heading and its s-derivative at local arc lengths ``s`` on routes ``r``
        (linear interpolation of each path's table, straight extensions beyond the ends, as
        ``ReferencePath._frame`` with ``extrapolate=True``)."""
        T = self._tables
        n = T["n"][r]
        j = np.clip((s * T["inv_step"][r]).astype(np.int64), 0, n - 2)  # s < 0 truncates to 0: clipped anyway
        g = T["base"][r] + j
        v0, v1 = T["rows"][g], T["rows"][g + 1]  # (M, 4)
        dv = v1 - v0
        u = np.clip((s - v0[:, 0]) / dv[:, 0], 0.0, 1.0)  # the table is uniform up to round-off
        val = v0[:, 1:] + u[:, None] * dv[:, 1:]
        der = dv[:, 1:] / dv[:, :1]
        x, y, h = val[:, 0], val[:, 1], val[:, 2]
        dx, dy, dh = der[:, 0], der[:, 1], der[:, 2]
        before, after = s < 0.0, s > T["length"][r]
        outside = before | after
        if outside.any():
            end = np.where(before[:, None], T["first"][r], T["last"][r])  # (M, 4)
            h_end = end[:, 3]
            c, sn = np.cos(h_end), np.sin(h_end)
            over = np.where(before, s, s - T["length"][r])
            x = np.where(outside, end[:, 1] + over * c, x)
            y = np.where(outside, end[:, 2] + over * sn, y)
            dx, dy = np.where(outside, c, dx), np.where(outside, sn, dy)
            h, dh = np.where(outside, h_end, h), np.where(outside, 0.0, dh)
        return x, y, dx, dy, h, dh

    def position(self, s_global, offset=0.0) -> np.ndarray:
        """Cartesian point [m], shape s.shape + (2,), at global arc length(s) and lateral offset(s) [m]."""
        s_global = np.asarray(s_global, dtype=float)
        r, s = self.to_local(s_global)
        d = np.broadcast_to(np.asarray(offset, dtype=float), s.shape)
        x, y, _, _, h, _ = self._frame(r.ravel(), s.ravel())
        d = d.ravel()
        pts = np.column_stack([x - d * np.sin(h), y + d * np.cos(h)])
        return pts.reshape(s.shape + (2,))

    def project(self, route_index, xy, s_guess=None, *, tol: float = 1e-7) -> np.ndarray:
        """Arc length [m] of the foot points of ``xy`` on the paths of their routes.

        Parameters
        ----------
        route_index : array_like of int (M,)
        xy : array_like (M, 2)             points [m]
        s_guess : array_like (M,), optional   start arc lengths [m] within a few metres; NaN or None: from
                               `~pirl_sim.paths.ReferencePath.to_frenet`
        tol : float                        [m] Newton stops when no point moves more

        Returns
        -------
        s : numpy.ndarray (M,)             local arc length [m] along each route (beyond ``[0, length]`` on the
                                           straight extensions); ValueError when Newton does not converge
        """
        r = np.asarray(route_index, dtype=np.int64).reshape(-1)
        q = np.asarray(xy, dtype=float).reshape(-1, 2)
        if len(r) != len(q):
            raise ValueError(f"got {len(r)} route indices for {len(q)} points")
        s = np.full(len(q), np.nan) if s_guess is None else np.array(s_guess, dtype=float).reshape(-1)
        cold = np.flatnonzero(~np.isfinite(s))
        for k in cold:
            s[k] = float(self.paths[r[k]].to_frenet(q[k], extrapolate=True)[0])
        step_cap = self._tables["step"][r]
        for _ in range(NEWTON_MAX_ITER):
            x, y, dx, dy, h, dh = self._frame(r, s)
            c, sn = np.cos(h), np.sin(h)
            rx, ry = q[:, 0] - x, q[:, 1] - y
            f = rx * c + ry * sn
            fprime = -(dx * c + dy * sn) + dh * (-rx * sn + ry * c)
            step = np.clip(-f / np.minimum(fprime, MIN_SLOPE), -step_cap, step_cap)
            s = s + step
            if np.max(np.abs(step), initial=0.0) <= tol:
                break
        else:
            k = int(np.argmax(np.abs(step)))  # type: ignore[assignment]
            raise ValueError(f"point {q[k].tolist()} on route {self.route_ids[r[k]]!r}: no foot point after "
                             f"{NEWTON_MAX_ITER} Newton steps (last step {step[k]:.3g} m)")
        return s

    # -- curvature on the global axis ---------------------------------------------------------------

    @cached_property
    def _kappa(self) -> tuple[np.ndarray, np.ndarray]:
        """Breakpoints (P + 1,) and cubic coefficients (4, P) of the curvature on the global axis."""
        half = 0.5 * self.spacing
        breaks: list[np.ndarray] = []
        coefs: list[np.ndarray] = []
        const = lambda v: np.array([[0.0], [0.0], [0.0], [float(v)]])  # noqa: E731
        for o, p in zip(self.offsets, self.paths):
            kappa = _smoothed(p.s, p.kappa, self.speed_smoothing)
            spline = CubicSpline(p.s, kappa, bc_type="not-a-knot")  # as SpeedProfile on an open path
            start, end = float(spline(0.0)), float(spline(p.length))
            breaks += [np.array([o - half]), o + spline.x[:-1], np.array([o + p.length])]
            coefs += [const(start), spline.c, const(end)]
        breaks.append(np.array([self.offsets[-1] + half]))
        x, c = np.concatenate(breaks), np.ascontiguousarray(np.concatenate(coefs, axis=1))
        x.setflags(write=False)
        c.setflags(write=False)
        return x, c

    def curvature(self, s_global) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """kappa [1/m], dkappa/ds [1/m^2], d2kappa/ds2 [1/m^3] at global arc lengths (held constant beyond
        each path's ends), as :meth:`pirl_sim.driving.SpeedProfile.curvature` on each route's path.

        One piecewise cubic (a :class:`scipy.interpolate.PPoly` made of each route's
        :class:`~scipy.interpolate.CubicSpline` and constant pieces between routes), evaluated with its two
        derivatives from one interval search.
        """
        s = np.asarray(s_global, dtype=float)
        x, c = self._kappa
        i = np.clip(np.searchsorted(x, s, side="right") - 1, 0, c.shape[1] - 1)
        t = s - x[i]
        c0, c1, c2, c3 = c[0, i], c[1, i], c[2, i], c[3, i]
        k = ((c0 * t + c1) * t + c2) * t + c3
        dk = (3.0 * c0 * t + 2.0 * c1) * t + c2
        d2k = 6.0 * c0 * t + 2.0 * c1
        return k, dk, d2k


def _smoothed(s: np.ndarray, values: np.ndarray, ell: float) -> np.ndarray:
    """Smoothing spline (gain 1 / (1 + (k ell)^4) at wavenumber k) of values on the uniform grid s, the ends
    padded with their end values over 12 ell; ell = 0 returns the values."""
    if ell == 0.0:
        return values
    h = float(s[1] - s[0])
    n_pad = int(math.ceil(12.0 * ell / h))
    t = np.concatenate([s[0] - h * np.arange(n_pad, 0, -1), s, s[-1] + h * np.arange(1, n_pad + 1)])
    v = np.concatenate([np.full(n_pad, values[0]), values, np.full(n_pad, values[-1])])
    return make_smoothing_spline(t, v, lam=ell**4 / h)(s)


@dataclass(frozen=True, eq=False)
class RouteSetProfile:
    """The desired speed v_des(s) [m/s] along the global axis of a :class:`RouteSet`, with exact first and
    second derivatives in s: :func:`pirl_sim.driving.smooth_desired_speed` of each route's curvature.

    Parameters
    ----------
    routes : RouteSet
    a_lat : float
        Comfortable lateral acceleration [m/s^2], > 0.
    v_max : float
        Speed cap [m/s], > 0.
    """

    routes: RouteSet
    a_lat: float = DEFAULT_A_LAT
    v_max: float = DEFAULT_V_MAX

    def __post_init__(self) -> None:
        if not isinstance(self.routes, RouteSet):
            raise TypeError(f"routes must be a RouteSet, got {type(self.routes).__name__}")
        for name in ("a_lat", "v_max"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be > 0, got {v!r}")

    def curvature(self, s):
        """See :meth:`RouteSet.curvature`."""
        return self.routes.curvature(s)

    def __call__(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """v_des(s) [m/s], dv_des/ds [1/s], d2v_des/ds2 [1/(m s)] at global arc lengths s [m]."""
        return desired_speed_along(*self.routes.curvature(s), self.a_lat, self.v_max)


