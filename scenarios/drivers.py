"""PIRL drivers in any simulator: the roundabout driver model on many routes at once, and the controller that
drives them (used by the SUMO and the highway-env scenarios).

:class:`RouteSet` lays the routes' reference paths end to end on one global arc-length axis (route ``r`` at
``[r * spacing, r * spacing + length_r]``, s [m]), so that every PIRL vehicle of a step, whatever its route, is
planned in one batched MPC call; :func:`route_set_model` is the matching :class:`pirl_sim.model.DriverModel`
for the learners, and :meth:`RouteSet.project` projects positions onto the routes. :class:`PirlDrivers` is the
batch controller (:class:`~.contract.BatchController`): every step, each PIRL vehicle's warm-started MPC
(horizon 30 steps of 0.1 s by default, ``n_iter`` / ``n_qp_iter`` per re-plan) plans under its own weights and
the command is the planned speed [m/s] one step ahead; with numba the work runs in
:mod:`pirl_sim.scenarios.driver_kernel` (``kernel="numpy"``: the reference path).

The design is explained in the documentation's "Simulators and data" page (PIRL drivers).
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from pirl_sim.driving import DEFAULT_BOUNDS, roundabout_features
from pirl_sim.dynamics import following, longitudinal
from pirl_sim.model import DriverModel
from pirl_sim.mpc import Bounds, SequentialMPC
from pirl_sim.paths import DEFAULT_A_LAT, DEFAULT_V_MAX

from .leaders import obstacle
from .yielding import ConflictTable, yield_gaps
from .route_set import ROUTE_SPACING, RouteSet, RouteSetProfile

__all__ = [
    "ROUTE_SPACING",
    "RouteSet",
    "RouteSetProfile",
    "RouteSetDriverModel",
    "route_set_model",
    "PirlDrivers",
]

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
        return self.routes.position(np.asarray(states)[..., 0], offset)  # type: ignore[union-attr]


def route_set_model(routes: RouteSet, *, dt: float = 0.1, a_lat: float = DEFAULT_A_LAT,
                    v_max: float = DEFAULT_V_MAX, bounds: Bounds | None = DEFAULT_BOUNDS, n_iter: int = 10,
                    n_qp_iter: int = 4, interacting: bool = False) -> RouteSetDriverModel:
    """The paper's roundabout model (:func:`pirl_sim.driving.roundabout_model`) on every route of ``routes``.

    With ``interacting`` the drivers also weigh ``headway`` to the vehicle ahead and ``yielding`` to the obstacle
    before a conflict point: features ``"interacting"`` of `pirl_sim.driving.roundabout_features` on the states of
    `pirl_sim.dynamics.following` with two obstacles (s, v, a, g, v_L, g_y, v_y).

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
    if not isinstance(interacting, bool):
        raise TypeError(f"interacting must be a bool, got {interacting!r}")
    dynamics, kind = (following(dt, obstacles=2), "interacting") if interacting else (longitudinal(dt), "paper")
    return RouteSetDriverModel(dynamics, roundabout_features(profile, kind), bounds,  # type: ignore[arg-type]
                               routes=routes,
                               n_iter=n_iter, n_qp_iter=n_qp_iter)


# ----------------------------------------------------------------------------------------------
# the controller
# ----------------------------------------------------------------------------------------------

@dataclass
class PirlDrivers:
    """Batch controller of a simulator's PIRL vehicles: each re-plans with its MPC every step ("Simulators and data").

    Parameters
    ----------
    model, horizon : RouteSetDriverModel, int   its dynamics' ``dt`` is the simulation's step; MPC horizon [steps] >= 1
    drivers : mapping vehicle id -> (route id, theta)   each PIRL vehicle's route and normalised weights (K,)
    control_noise, rng : float, Generator or None   std [m/s^3] of noise on each applied jerk; its generator (if > 0)
    override_tol, stop_speed, resume_speed : float   [m/s] a command is carried out within this; standstill hand-back
    kernel : {"auto", "numba", "numpy"}   compiled loops (`~pirl_sim.scenarios.driver_kernel.CompiledDriverMPC`), or not

    A model whose dynamics carry obstacles (`route_set_model` with ``interacting``) ``needs_frame``: its
    `commands` take the step's `~pirl_sim.scenarios.contract.Frame`, from which each driver's vehicle ahead
    (`pirl_sim.scenarios.leaders`, held at constant speed over the prediction) and the standing obstacle it yields
    to (`pirl_sim.scenarios.yielding`) start its prediction.

    Attributes
    ----------
    n_calls, n_plans : int                  batched MPC calls and vehicle re-plans so far
    plan_time_s, control_time_s, handbacks : float, float, dict   wall time [s] in the MPC, in `commands`; see the page
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
        routes_, thetas = [], []  # type: ignore[var-annotated]
        for vid, (rid, theta) in self.drivers.items():
            w = feats.weights(theta)
            if w.shape != (feats.n_features,) or np.any(w <= 0):
                raise ValueError(f"driver {vid!r}: theta must be {feats.n_features} positive weights "
                                 f"{feats.names}, got {theta!r}")
            self._slot[vid] = len(routes_)
            routes_.append(self.model.routes.index(rid))  # type: ignore[union-attr]
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
        self._lo, self._hi, _, _ = (
            self.model.bounds.resolve(dyn) if self.model.bounds is not None  # type: ignore[var-annotated]
            else (np.full(dyn.n_x, -np.inf), np.full(dyn.n_x, np.inf), None, None))
        self._mpc = self.model.predictor()
        self._table: ConflictTable | None = None  # where routes meet (drivers who yield), built when first needed
        self._route_index: dict[str, int] = {}
        self._s_seen: dict[str, float] = {}  # every vehicle's last local arc length [m] (warm starts)
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

    @property
    def needs_frame(self) -> bool:
        """Whether the drivers see other vehicles (their `commands` need ``frame``)."""
        return self.model.dynamics.n_x > 3

    def __call__(self, time: float, vehicle_id: str, observation) -> float:
        """Single-vehicle :data:`~.sumo.runner.Controller` form (plans only this vehicle)."""
        if self.needs_frame:
            raise ValueError("drivers who interact plan in one batch with the step's frame: use commands(..., frame=)")
        return self._plan(time, {vehicle_id: observation}, prune=False)[vehicle_id]  # type: ignore[return-value]

    def commands(self, time: float, observations: Mapping, frame=None) -> dict[str, float | None]:
        """Commanded speeds [m/s] for every observed PIRL vehicle, planned in one batched MPC call.

        Parameters
        ----------
        time : float
            [s]
        observations : mapping vehicle id -> Observation
        frame : Frame or None
            Every vehicle at this step; needed when `needs_frame` (each observed vehicle among its ids).

        Returns
        -------
        dict
            vehicle id -> speed [m/s] one step ahead in the vehicle's plan (>= 0), or None for a vehicle
            handed back to the simulator at a standstill.
        """
        if self.needs_frame and frame is None:
            raise ValueError("these drivers weigh headway and need the step's frame: commands(time, observations, "
                             "frame=Frame(...))")
        return self._plan(time, observations, prune=True, frame=frame)

    def _obstacles(self, frame, vids: list, speed: np.ndarray, s_local: np.ndarray) -> list[np.ndarray]:
        """Per vehicle of ``vids`` (on the local arc lengths ``s_local`` [m] of their routes): gap [m] and speed
        [m/s] of the vehicle ahead (`pirl_sim.scenarios.leaders.obstacle`), then of the obstacle it yields to
        (`pirl_sim.scenarios.yielding.yield_gaps`; standing)."""
        where = {v: i for i, v in enumerate(frame.ids)}
        missing = [v for v in vids if v not in where]
        if missing:
            raise ValueError(f"vehicle(s) {missing[:5]} are not in the step's frame")
        gap, v_lead = frame.leaders()
        rows = np.fromiter((where[v] for v in vids), dtype=np.int64, count=len(vids))
        route, s = self._frame_arc_lengths(frame, rows, s_local)
        g_y = yield_gaps(self._conflicts(), route, s, frame.speed, frame.xy, frame.psi, rows)
        return [*obstacle(gap[rows], v_lead[rows], speed), *obstacle(g_y, np.zeros(len(rows)), speed)]

    def _project(self, route: np.ndarray, xy: np.ndarray, guess: np.ndarray) -> np.ndarray:
        """`RouteSet.project` (compiled where the kernel is); from the nearest points of the paths when the warm
        starts ``guess`` do not converge (a vehicle that moved far from its last arc length)."""
        project = self._compiled.project if self._compiled is not None else self.model.routes.project  # type: ignore
        try:
            return project(route, xy, guess)
        except ValueError:
            if not np.isfinite(guess).any():
                raise
            return project(route, xy, np.full(len(guess), np.nan))

    def _conflicts(self) -> ConflictTable:
        if self._table is None:
            self._table = ConflictTable(self.model.routes)
        return self._table

    def _frame_arc_lengths(self, frame, rows: np.ndarray, s_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Route index (-1: not a route of the model) and local arc length [m] of every vehicle of ``frame``: the
        planned ones' ``s_rows`` at ``rows``, the others projected (warm-started from their last one)."""
        routes = self.model.routes
        assert routes is not None  # a RouteSetDriverModel checks its routes when built
        index = self._route_index
        for rid in frame.routes:
            if rid not in index:
                index[rid] = routes.route_ids.index(rid) if rid in routes.route_ids else -1
        route = np.fromiter((index[rid] for rid in frame.routes), dtype=np.int64, count=len(frame.ids))
        s = np.full(len(route), np.nan)
        s[rows] = s_rows
        others = np.ones(len(route), dtype=bool)
        others[rows] = False
        known = np.flatnonzero((route >= 0) & others)
        if len(known):
            guess = np.array([self._s_seen.get(frame.ids[k], np.nan) for k in known])
            s[known] = self._project(route[known], frame.xy[known], guess)
        # every vehicle's arc length, the planned ones' too: one that stops being planned warm-starts from it, not
        # from the nearest point of its path, which is ambiguous where a route crosses itself
        self._s_seen = {frame.ids[k]: float(s[k]) for k in np.flatnonzero(np.isfinite(s))}
        return route, s

    def _plan(self, time: float, observations: Mapping, *, prune: bool, frame=None) -> dict[str, float | None]:
        t0 = _time.perf_counter()
        if prune:  # vehicles not observed any more have left the network
            gone = [v for v in self._live if v not in observations]
            self._live.difference_update(gone)
            self._gone.update(gone)
        slot, gone = self._slot, self._gone  # type: ignore[assignment]
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
            # _s_next stays where the vehicle stopped: the warm start of its projection, not the nearest point of its
            # path, which is ambiguous where a route crosses itself (`_project` falls back on that)
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
        s_local = self._project(r, xy, self._s_next[rows])
        command = self._command[rows]
        with np.errstate(invalid="ignore"):
            followed = np.isfinite(command) & (np.abs(speed - command) <= self.override_tol)
        a = np.where(followed, self._a_next[rows], accel)
        x0 = np.column_stack([self.model.routes.to_global(r, s_local), speed, a])  # type: ignore[union-attr]
        if frame is not None and self.needs_frame:
            x0 = np.column_stack([x0, *self._obstacles(frame, vids, speed, s_local)])
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
            u = u + self.control_noise * self.rng.standard_normal(u.shape)  # type: ignore[union-attr]
        dyn = self.model.dynamics
        x1 = x0 @ dyn.A.T + u @ dyn.B.T
        self._s_next[rows] = x1[:, 0] - self.model.routes.offsets[r]  # type: ignore[union-attr]
        self._a_next[rows] = x1[:, 2]
        cmd = np.maximum(x1[:, 1], 0.0)
        self._command[rows] = cmd
        self._plans[rows] = plan
        out.update(zip(vids, cmd.tolist()))
        self.n_calls += 1
        self.n_plans += M
        self.control_time_s += _time.perf_counter() - t0
        return out
