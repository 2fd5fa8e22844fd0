"""PIRL drivers in any simulator: the roundabout driver model on many routes at once, and the controller that
drives them (used by the SUMO and the highway-env scenarios).

One arc-length axis for all routes. Every PIRL vehicle follows the paper's longitudinal model
(:mod:`pirl_sim.driving`: state s [m], v [m/s], a [m/s^2], control jerk [m/s^3], features speed_dev,
acc_sq, jerk_sq) along the reference path of its route. The desired speed, and so the ``speed_dev``
feature, depends on the route. So that all vehicles of a step are planned in **one** batched MPC call
whatever their routes, a :class:`RouteSet` lays the routes' reference paths end to end on one global
arc-length axis: route ``r`` occupies ``[r * spacing, r * spacing + length_r]`` (``spacing`` = 10 km by
default, far more than a route plus an MPC horizon), and the curvature along the global axis is one
piecewise cubic (:meth:`RouteSet.curvature`) that equals, piece for piece, the cubic spline
:class:`pirl_sim.driving.SpeedProfile` fits to each path's curvature (held constant beyond a path's ends,
as there; the curvature may first be smoothed further, ``RouteSet.speed_smoothing``).
The dynamics are invariant to shifts in s, so a vehicle at ``s`` on route ``r`` is planned exactly as on
its own path, and trajectories of different routes are comparable by one model — also for learning:
:func:`route_set_model` is a :class:`pirl_sim.model.DriverModel` the learners take as is.

Projection. A driver's position on its path comes from :meth:`RouteSet.project`: Newton on the
foot-point condition of the path's own interpolated frame (the same equation as
:meth:`pirl_sim.paths.ReferencePath.to_frenet`, to 1e-7 m), vectorised over the vehicles of all routes and
started from where the vehicle's previous plan put it; a vehicle's first position uses ``to_frenet``.

Controller. :class:`PirlDrivers` is a batch controller (:class:`~.contract.BatchController` of the simulator
contract, for :class:`~.sumo.runner.SumoRun` and :class:`~.highway.traffic.RoundaboutTraffic`; it reads only
each observation's ``ego``, a :class:`~.contract.VehicleView`): every step, for every PIRL vehicle on the road, the start
state is (s of the vehicle's centre, the simulator's speed, the acceleration the driver's own previous plan
reached if the simulator carried that command out, else the simulator's measured acceleration), its MPC (:class:`pirl_sim.mpc.SequentialMPC`, horizon 30 steps of 0.1 s by
default, warm-started with its previous plan shifted by a step) plans under the driver's weights, and the
commanded speed is the planned speed one step ahead. ``n_iter`` / ``n_qp_iter`` bound the Newton steps and
bounded QPs per re-plan. With warm starts one of each (a real-time iteration, the scenarios' default) costs
about half of three of each; in closed loop over every route of the default scenario (three styles, from
13.9 m/s) its speeds stay within 0.07 m/s of a converged MPC's (three of each: 0.04 m/s; measured in
``tests/test_sumo_drivers.py``). The drivers are near-optimal receding-horizon drivers of their cost.

Speed. Where numba is installed (the ``sumo`` extra), the projection and the MPC run as compiled loops, one
driver at a time (:mod:`pirl_sim.scenarios.driver_kernel`: the same plans as the numpy path to rounding, tested
on random problems and in closed loop); the numpy path stays the reference (``PirlDrivers(kernel="numpy")``).
Every driver's state lives in one row of arrays, gathered and scattered once per step. A re-plan costs
~12 us of MPC (one Newton step by a Riccati recursion, its line search, the bounded QPs of the few drivers
that need them) against ~60 us on the numpy path (``benchmarks/bench_sumo.py``).
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.interpolate import CubicSpline, make_smoothing_spline

from pirl_sim.driving import DEFAULT_BOUNDS, desired_speed_along, roundabout_features
from pirl_sim.dynamics import longitudinal
from pirl_sim.model import DriverModel
from pirl_sim.mpc import Bounds, SequentialMPC
from pirl_sim.paths import DEFAULT_A_LAT, DEFAULT_V_MAX, ReferencePath

__all__ = [
    "ROUTE_SPACING",
    "RouteSet",
    "RouteSetProfile",
    "RouteSetDriverModel",
    "route_set_model",
    "PirlDrivers",
]

ROUTE_SPACING = 10_000.0  #: [m] distance between the starts of consecutive routes on the global axis
_NEWTON_MAX_ITER = 50
_MIN_SLOPE = -0.05  # as ReferencePath.to_frenet: floor on the Newton slope (far from centres of curvature)


@dataclass(frozen=True, eq=False)
class RouteSet:
    """Reference paths of several routes on one global arc-length axis (see the module docstring).

    Parameters
    ----------
    route_ids : tuple of str
        Unique route ids; route ``r`` starts at ``r * spacing`` on the global axis.
    paths : tuple of ReferencePath
        One open path per route, each shorter than ``spacing / 4``.
    spacing : float
        [m], > 0.
    speed_smoothing : float
        Smoothing length [m], >= 0, applied to each path's curvature table before it sets the desired speed
        (the smoothing spline of :meth:`pirl_sim.paths.ReferencePath.from_polyline`, applied to kappa(s),
        ends held constant). 0: each path's own curvature, and :class:`RouteSetProfile` equals
        :class:`pirl_sim.driving.SpeedProfile` of each path exactly. It separates the two jobs of a
        reference path: the geometry (the Frenet projection of recorded positions) wants a path close to
        the lane, the desired speed a curvature seen at the scale a driver looks ahead; smoothing the
        geometry itself by 8 m cuts the corners of the entries' S-bends by up to 1.5 m, which distorts
        projected speeds by up to 1 m/s there (2 m: within 0.2 m of the lanes, 0.1 m/s).

    Raises
    ------
    ValueError
        Repeated ids, a count mismatch, a closed path, a path too long for ``spacing``, or a negative
        ``speed_smoothing``.
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
        route_index : array_like of int, shape (M,)
        xy : array_like, shape (M, 2)
            Points [m].
        s_guess : array_like, shape (M,), optional
            Starting arc lengths [m] along each route, within a few metres of the answer (e.g. where the
            vehicle's plan put it); NaN or None: :meth:`pirl_sim.paths.ReferencePath.to_frenet` finds it.
        tol : float
            [m] Newton stops when no point moves more.

        Returns
        -------
        numpy.ndarray, shape (M,)
            Local arc length [m] along each route (beyond ``[0, length]`` on the straight extensions).

        Raises
        ------
        ValueError
            If the Newton iteration does not converge (a point beyond the local centre of curvature).
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
        for _ in range(_NEWTON_MAX_ITER):
            x, y, dx, dy, h, dh = self._frame(r, s)
            c, sn = np.cos(h), np.sin(h)
            rx, ry = q[:, 0] - x, q[:, 1] - y
            f = rx * c + ry * sn
            fprime = -(dx * c + dy * sn) + dh * (-rx * sn + ry * c)
            step = np.clip(-f / np.minimum(fprime, _MIN_SLOPE), -step_cap, step_cap)
            s = s + step
            if np.max(np.abs(step), initial=0.0) <= tol:
                break
        else:
            k = int(np.argmax(np.abs(step)))
            raise ValueError(f"point {q[k].tolist()} on route {self.route_ids[r[k]]!r}: no foot point after "
                             f"{_NEWTON_MAX_ITER} Newton steps (last step {step[k]:.3g} m)")
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


@dataclass(frozen=True)
class RouteSetDriverModel(DriverModel):
    """The roundabout driver model on a :class:`RouteSet` (states carry global arc lengths).

    Predictions by :class:`pirl_sim.mpc.SequentialMPC` with ``n_iter`` Newton iterations and ``n_qp_iter``
    bounded QPs per call; positions in Cartesian metres through the route set.
    """

    routes: RouteSet | None = None
    n_iter: int = 10
    n_qp_iter: int = 4

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.routes, RouteSet):
            raise TypeError(f"routes must be a RouteSet, got {type(self.routes).__name__}")

    def predictor(self) -> SequentialMPC:
        if "seq" not in self._predictors:
            self._predictors["seq"] = SequentialMPC(self.dynamics, self.features, self.bounds,
                                                    n_iter=self.n_iter, n_qp_iter=self.n_qp_iter)
        return self._predictors["seq"]

    def predict_states(self, x0: np.ndarray, theta: np.ndarray, horizon: int) -> np.ndarray:
        """As :meth:`pirl_sim.driving.PathDriverModel.predict_states` (stopped starts made physical)."""
        x0 = np.array(np.atleast_2d(x0), dtype=float)
        stopped = x0[:, 1] <= 0.0
        x0[stopped, 1] = 0.0
        x0[stopped, 2] = np.maximum(x0[stopped, 2], 0.0)
        return super().predict_states(x0, theta, horizon)

    def positions(self, states: np.ndarray, offset=0.0) -> np.ndarray:
        """Cartesian positions (..., 2) [m] of states (..., n_x) at lateral offset [m] from their paths."""
        return self.routes.position(np.asarray(states)[..., 0], offset)


def route_set_model(routes: RouteSet, *, dt: float = 0.1, a_lat: float = DEFAULT_A_LAT,
                    v_max: float = DEFAULT_V_MAX, bounds: Bounds | None = DEFAULT_BOUNDS, n_iter: int = 10,
                    n_qp_iter: int = 4) -> RouteSetDriverModel:
    """The paper's roundabout model (:func:`pirl_sim.driving.roundabout_model`) on every route of ``routes``.

    Parameters
    ----------
    routes : RouteSet
    dt : float
        Model step [s].
    a_lat, v_max : float
        Desired-speed parameters [m/s^2, m/s].
    bounds : Bounds or None
        Box bounds of the MPC (default: :data:`pirl_sim.driving.DEFAULT_BOUNDS`).
    n_iter, n_qp_iter : int
        Newton iterations and bounded QPs per MPC call.
    """
    profile = RouteSetProfile(routes, a_lat, v_max)
    return RouteSetDriverModel(longitudinal(dt), roundabout_features(profile), bounds, routes=routes,
                               n_iter=n_iter, n_qp_iter=n_qp_iter)


# ----------------------------------------------------------------------------------------------
# the controller
# ----------------------------------------------------------------------------------------------

@dataclass
class PirlDrivers:
    """Batch controller of a simulator's PIRL vehicles: every one re-plans with its MPC every step.

    Parameters
    ----------
    model : RouteSetDriverModel
        Its dynamics' ``dt`` must be the simulation's step length.
    drivers : mapping vehicle id -> (route id, theta)
        Each PIRL vehicle's route (in ``model.routes``) and normalised weights (K,) in feature order.
    horizon : int
        MPC horizon [steps], >= 1.
    control_noise : float
        Standard deviation [m/s^3] of Gaussian noise added to each applied jerk.
    rng : numpy.random.Generator, optional
        Required when ``control_noise > 0``.
    override_tol : float
        [m/s] The simulator carried a command out when its speed is within this of the command; then the
        driver's own planned acceleration is its next start acceleration, otherwise the measured one.
    stop_speed, resume_speed : float
        [m/s] Standstill hand-back: a vehicle slower than ``stop_speed`` (the simulator stopped it, e.g. to
        yield at an entry) is handed back to the simulator's car-following model (command None) until it drives faster than
        ``resume_speed``, then its MPC re-plans from a cold start. Why: the driver model has no reason to
        start from a standstill where the desired speed rises ahead. Its cost, mean (v - v_des(s))^2 plus
        acceleration and jerk terms, is lowest at low speed where v_des is low, so from v = 0 every plan
        defers the start and the receding horizon never starts (measured: at several points of every
        route for the "minimises acceleration" and "no preference" styles, longer horizons worse).
    kernel : {"auto", "numba", "numpy"}
        How the drivers re-plan and are projected onto their routes: ``"numba"``, compiled loops
        (:class:`~pirl_sim.scenarios.driver_kernel.CompiledDriverMPC`: the same plans as the numpy MPC to
        rounding, several times faster at a simulator step's batch sizes); ``"numpy"``, the batched
        :class:`pirl_sim.mpc.SequentialMPC` and :meth:`RouteSet.project` (the reference); ``"auto"``
        (default), numba where it is installed (the ``sumo`` extra) and the model is the paper's roundabout
        model, numpy otherwise.

    Attributes
    ----------
    n_calls : int
        Batched MPC calls so far (one per step with PIRL vehicles).
    n_plans : int
        Vehicle re-plans so far.
    plan_time_s : float
        Wall time [s] spent in the MPC.
    control_time_s : float
        Wall time [s] spent in :meth:`commands` (projection, MPC, bookkeeping).
    handbacks : dict
        vehicle id -> how often it was handed back to the simulator at a standstill (vehicles handed back at least
        once).
    """

    model: RouteSetDriverModel
    drivers: Mapping[str, tuple[str, np.ndarray]]
    horizon: int = 30
    control_noise: float = 0.0
    rng: np.random.Generator | None = None
    override_tol: float = 0.01
    stop_speed: float = 0.5
    resume_speed: float = 3.0
    kernel: str = "auto"
    n_calls: int = field(default=0, init=False)
    n_plans: int = field(default=0, init=False)
    plan_time_s: float = field(default=0.0, init=False)
    control_time_s: float = field(default=0.0, init=False)

    def __post_init__(self) -> None:
        if not isinstance(self.model, RouteSetDriverModel):
            raise TypeError(f"model must be a RouteSetDriverModel, got {type(self.model).__name__}")
        h = self.horizon
        if isinstance(h, bool) or not isinstance(h, (int, np.integer)) or h < 1:
            raise ValueError(f"horizon must be a positive number of steps, got {h!r}")
        if not math.isfinite(self.control_noise) or self.control_noise < 0:
            raise ValueError(f"control_noise must be >= 0 m/s^3, got {self.control_noise!r}")
        if self.control_noise > 0 and not isinstance(self.rng, np.random.Generator):
            raise TypeError("control_noise > 0 needs rng, a numpy.random.Generator")
        if not (0 <= self.stop_speed <= self.resume_speed and math.isfinite(self.resume_speed)):
            raise ValueError(f"need 0 <= stop_speed <= resume_speed [m/s], got {self.stop_speed!r} and "
                             f"{self.resume_speed!r}")
        self.handbacks: dict[str, int] = {}
        feats = self.model.features
        dyn = self.model.dynamics
        # every driver's state in one row of arrays (gathered and scattered once per step, not per driver)
        self._slot: dict[str, int] = {}  # vehicle id -> row
        routes_, thetas = [], []
        for vid, (rid, theta) in self.drivers.items():
            w = feats.weights(theta)
            if w.shape != (feats.n_features,) or np.any(w <= 0):
                raise ValueError(f"driver {vid!r}: theta must be {feats.n_features} positive weights "
                                 f"{feats.names}, got {theta!r}")
            self._slot[vid] = len(routes_)
            routes_.append(self.model.routes.index(rid))
            thetas.append(w)
        n = len(routes_)
        self._route = np.array(routes_, dtype=np.int64)
        self._theta = np.array(thetas, dtype=float).reshape(n, feats.n_features)
        self._handed_back = np.zeros(n, dtype=bool)  # the simulator drives it until it is faster than resume_speed
        self._s_next = np.full(n, math.nan)  # [m] local arc length the last plan reaches one step on
        self._a_next = np.zeros(n)  # [m/s^2] acceleration the last plan reaches one step on
        self._command = np.full(n, math.nan)  # [m/s] last commanded speed
        self._plans = np.zeros((n, int(self.horizon), dyn.n_u))  # last plans (zeros: none yet)
        self._live: set[str] = set()  # vehicles planned or handed back so far, still in the network
        self._gone: set[str] = set()  # vehicles that left the network
        self._lo, self._hi, _, _ = (self.model.bounds.resolve(dyn) if self.model.bounds is not None
                                    else (np.full(dyn.n_x, -np.inf), np.full(dyn.n_x, np.inf), None, None))
        self._mpc = self.model.predictor()
        if self.kernel not in ("auto", "numba", "numpy"):
            raise ValueError(f"kernel must be 'auto', 'numba' or 'numpy', got {self.kernel!r}")
        self._compiled = None
        if self.kernel != "numpy":
            from .driver_kernel import CompiledDriverMPC, KernelUnsupported, numba_available

            if self.kernel == "numba" or numba_available():
                try:
                    self._compiled = CompiledDriverMPC(self.model, self._mpc)
                except (KernelUnsupported, ImportError):  # another model, or a numba that does not import
                    if self.kernel == "numba":
                        raise

    def __call__(self, time: float, vehicle_id: str, observation) -> float:
        """Single-vehicle :data:`~.sumo.runner.Controller` form (plans only this vehicle)."""
        return self._plan(time, {vehicle_id: observation}, prune=False)[vehicle_id]

    def commands(self, time: float, observations: Mapping) -> dict[str, float | None]:
        """Commanded speeds [m/s] for every observed PIRL vehicle, planned in one batched MPC call.

        Parameters
        ----------
        time : float
            [s]
        observations : mapping vehicle id -> Observation

        Returns
        -------
        dict
            vehicle id -> speed [m/s] one step ahead in the vehicle's plan (>= 0), or None for a vehicle
            handed back to the simulator at a standstill.
        """
        return self._plan(time, observations, prune=True)

    def _plan(self, time: float, observations: Mapping, *, prune: bool) -> dict[str, float | None]:
        t0 = _time.perf_counter()
        if prune:  # vehicles not observed any more have left the network
            gone = [v for v in self._live if v not in observations]
            self._live.difference_update(gone)
            self._gone.update(gone)
        slot, gone = self._slot, self._gone
        unknown = [v for v in observations if v not in slot or v in gone]
        if unknown:
            raise ValueError(f"no PIRL driver for vehicle(s) {unknown}")
        vids = list(observations)
        egos = [observations[v].ego for v in vids]
        rows = np.fromiter((slot[v] for v in vids), dtype=np.int64, count=len(vids))
        speed = np.fromiter((e.speed for e in egos), dtype=float, count=len(vids))
        # standstill hand-back (see the class docstring)
        was_back = self._handed_back[rows]
        resumed = was_back & (speed > self.resume_speed)
        stopped = ~was_back & (speed < self.stop_speed)
        if resumed.any():
            r_rows = rows[resumed]
            self._handed_back[r_rows] = False
            self._plans[r_rows] = 0.0
            self._command[r_rows] = math.nan
            self._s_next[r_rows] = math.nan
        if stopped.any():
            self._handed_back[rows[stopped]] = True
            for k in np.flatnonzero(stopped):
                self.handbacks[vids[k]] = self.handbacks.get(vids[k], 0) + 1
        back = self._handed_back[rows]
        out: dict[str, float | None] = {vids[k]: None for k in np.flatnonzero(back)}
        self._live.update(vids)
        if back.all():
            self.control_time_s += _time.perf_counter() - t0
            return out
        keep = np.flatnonzero(~back)
        rows, speed = rows[keep], speed[keep]
        vids = [vids[k] for k in keep]
        egos = [egos[k] for k in keep]
        M = len(rows)
        r = self._route[rows]
        xy = np.fromiter((c for e in egos for c in (e.x, e.y)), dtype=float, count=2 * M).reshape(M, 2)
        accel = np.fromiter((e.accel for e in egos), dtype=float, count=M)
        project = self.model.routes.project if self._compiled is None else self._compiled.project
        s_local = project(r, xy, self._s_next[rows])
        command = self._command[rows]
        with np.errstate(invalid="ignore"):
            followed = np.isfinite(command) & (np.abs(speed - command) <= self.override_tol)
        a = np.where(followed, self._a_next[rows], accel)
        x0 = np.column_stack([self.model.routes.to_global(r, s_local), speed, a])
        x0 = np.clip(x0, self._lo, self._hi)  # the MPC plans from the start moved into its bounds
        at_rest = x0[:, 1] <= 0.0  # a stopped car does not decelerate further
        x0[at_rest, 2] = np.maximum(x0[at_rest, 2], 0.0)
        theta = self._theta[rows]
        prev = self._plans[rows]
        init = np.concatenate([prev[:, 1:], prev[:, -1:]], axis=1)  # the last plans shifted by a step
        t1 = _time.perf_counter()
        plan = (self._mpc if self._compiled is None else self._compiled).controls(x0, theta, self.horizon, init=init)
        self.plan_time_s += _time.perf_counter() - t1
        u = plan[:, 0]
        if self.control_noise > 0:
            u = u + self.control_noise * self.rng.standard_normal(u.shape)
        dyn = self.model.dynamics
        x1 = x0 @ dyn.A.T + u @ dyn.B.T
        self._s_next[rows] = x1[:, 0] - self.model.routes.offsets[r]
        self._a_next[rows] = x1[:, 2]
        cmd = np.maximum(x1[:, 1], 0.0)
        self._command[rows] = cmd
        self._plans[rows] = plan
        out.update(zip(vids, cmd.tolist()))
        self.n_calls += 1
        self.n_plans += M
        self.control_time_s += _time.perf_counter() - t0
        return out
