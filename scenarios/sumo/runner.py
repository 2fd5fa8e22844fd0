"""Run SUMO on a network through libsumo (or TraCI), record every vehicle every step, let a controller drive some.

One :class:`SumoRun` is one simulation::

    with SumoRun(files.net, routes(spec), vehicles, pirl_ids={"v0"}, controller=ctrl, seed=0) as run:
        rec = run.run(60.0)                      # SumoRecording: rec.frame, rec.summary

or in one call, :func:`simulate`. libsumo holds **one simulation per process** (a second concurrent run is
refused; :func:`run_in_subprocess` runs a function in a fresh spawned process); ``backend="traci"`` runs SUMO as a
separate process over a socket. Vehicles in ``pirl_ids`` are driven by ``controller`` (a commanded speed [m/s]
per step, or a :class:`~pirl_sim.scenarios.contract.BatchController`), under ``speed_mode`` (default
:data:`SPEED_MODE_ALL_CHECKS` = 31; :func:`speed_mode` builds others); a command SUMO does not carry out within
``override_tol`` is flagged ``overridden``. Records are SI (``x``, ``y`` [m]: the centre of the box); recording
conventions, controllers, collisions and speed modes are explained in the documentation's "SUMO roundabouts" page.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import time as _time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
import pandas as pd

from ..contract import STEP, BatchController, Frame  # noqa: F401  (BatchController: the contract's, re-exported)
from .network import NetworkFiles, load_net, validate_route
from .imports import sumo_module

__all__ = [
    "BACKENDS",
    "SPEED_MODE_ALL_CHECKS",
    "RECORD_COLUMNS",
    "SUMMARY_COLUMNS",
    "VehicleSpec",
    "VehicleState",
    "Observation",
    "Controller",
    "BatchController",
    "COLLISION_ACTIONS",
    "ConstantSpeed",
    "SumoRecording",
    "SumoRun",
    "speed_mode",
    "sumo_command",
    "sumo_angle_to_psi",
    "simulate",
    "run_in_subprocess",
]

BACKENDS = ("libsumo", "traci")
SPEED_MODE_ALL_CHECKS = 31  #: safe speed, max accel, max decel, right of way, red lights (SUMO's default)
DEFAULT_STEP_LENGTH = STEP  # [s] (the simulator contract's step)
DEFAULT_OVERRIDE_TOL = 0.01  # [m/s]
DEFAULT_LEADER_LOOKAHEAD = 100.0  # [m]
COLLISION_ACTIONS = ("warn", "remove", "teleport", "none")  #: SUMO's --collision.action values

#: columns of :attr:`SumoRecording.frame`, in order
RECORD_COLUMNS: tuple[str, ...] = (
    "step", "time", "vehicle_id", "route_id", "pirl",
    "x", "y", "x_front", "y_front", "psi_rad", "speed", "vx", "vy", "accel",
    "length", "width", "edge_id", "lane_id", "lane_pos",
    "commanded_speed", "overridden", "collided", "arrived", "vanished",
)
_LATER_COLUMNS = ("commanded_speed", "overridden", "collided", "arrived", "vanished")  # set after their row
_FIXED_COLUMNS = tuple(c for c in RECORD_COLUMNS if c not in _LATER_COLUMNS)
#: columns of :attr:`SumoRecording.summary`, in order
SUMMARY_COLUMNS: tuple[str, ...] = (
    "vehicle_id", "route_id", "pirl", "depart", "first_time", "last_time", "n_steps", "status",
    "collided", "removed_early", "n_commanded", "overridden_fraction",
)

_libsumo_owner: SumoRun | None = None  # the run holding this process's libsumo simulation, if any


def _import_libsumo():
    """``import libsumo`` without its pyarrow version print.

    libsumo 1.28 prints "Warning! pyarrow is installed with version ... which might be incompatible" to stdout
    on import when the installed pyarrow is not the Arrow version it was built against (23.0). It carries its
    own renamed copy of libarrow and pirl_sim passes no Arrow data to it, so the warning does not apply here.
    ``LIBSUMO_AS_TRACI=quiet`` (read by libsumo's ``__init__``) skips the print; it is set only around the
    import, after ``traci`` is imported, because with it set ``import traci`` would silently become libsumo.
    """
    sumo_module("traci")  # first: traci stays the socket client

    old = os.environ.get("LIBSUMO_AS_TRACI")
    os.environ["LIBSUMO_AS_TRACI"] = "quiet"
    try:
        libsumo = sumo_module("libsumo")
    finally:
        if old is None:
            del os.environ["LIBSUMO_AS_TRACI"]
        else:
            os.environ["LIBSUMO_AS_TRACI"] = old
    return libsumo


def speed_mode(*, safe_speed: bool = True, max_accel: bool = True, max_decel: bool = True,
               right_of_way: bool = True, red_light: bool = True,
               ignore_junction_foes: bool = False) -> int:
    """SUMO speed-mode bitset from named checks (TraCI ``setSpeedMode``).

    Parameters
    ----------
    safe_speed : bool              bit 0: never faster than the car-following model's safe speed
    max_accel, max_decel : bool    bits 1, 2: the vehicle type's maximum acceleration / deceleration
    right_of_way : bool            bit 3: right of way towards foes approaching the junction
    red_light : bool               bit 4: brake hard to avoid passing a red light
    ignore_junction_foes : bool    bit 5 (inverted): disregard right of way towards foes already in the junction

    Returns
    -------
    mode : int                     e.g. 31 with all defaults, 25 without the acceleration bounds
    """
    bits = (safe_speed, max_accel, max_decel, right_of_way, red_light, ignore_junction_foes)
    return sum(int(bool(b)) << i for i, b in enumerate(bits))


def sumo_angle_to_psi(angle_deg):
    """Convert SUMO's vehicle angle to a mathematical heading.

    Parameters
    ----------
    angle_deg : float or array_like
        SUMO's ``vehicle.getAngle``: degrees clockwise from north (+y), navigational.

    Returns
    -------
    float or numpy.ndarray
        Heading [rad] counter-clockwise from +x, in (-pi, pi]: 0 deg -> pi/2, 90 deg -> 0, 270 deg -> pi.
    """
    if isinstance(angle_deg, float):  # the runner's per-vehicle call: the same operations in scalar floats
        return _angle_to_psi(angle_deg)
    psi = np.pi / 2 - np.radians(angle_deg)
    return np.pi - np.mod(np.pi - psi, 2 * np.pi)


def _angle_to_psi(angle_deg: float) -> float:
    """`sumo_angle_to_psi` of one float (bit-for-bit numpy's result: radians, then the floored modulo)."""
    psi = math.pi / 2 - math.radians(angle_deg)
    return math.pi - ((math.pi - psi) % (2 * math.pi))


def sumo_command(net_path, *, seed: int = 0, step_length: float = DEFAULT_STEP_LENGTH,
                 extra_args: Sequence[str] = (), collision_action: str = "warn") -> list[str]:
    """The SUMO command line both backends start.

    Parameters
    ----------
    net_path : str or os.PathLike
    seed : int                        SUMO's random seed (``--seed``): same seed, same simulation
    step_length : float               [s]
    extra_args : sequence of str      appended (e.g. ``["--additional-files", "types.add.xml"]``)
    collision_action : {"warn", "remove", "teleport", "none"}   SUMO's ``--collision.action``

    Returns
    -------
    cmd : list of str                 ``[sumo, -n, net, --step-length, ...]``: the flags of the SUMO page (Running
                                      SUMO), then ``extra_args``
    """
    sumolib = sumo_module("sumolib")

    return [
        sumolib.checkBinary("sumo"), "-n", str(net_path),
        "--step-length", repr(float(step_length)),
        "--no-step-log", "--no-warnings",
        "--seed", str(int(seed)),
        "--collision.action", str(collision_action),
        "--time-to-teleport", "-1",
        "--begin", "0",
        "--collision.check-junctions", "true",
        *map(str, extra_args),
    ]


@dataclass(frozen=True)
class VehicleSpec:
    """A vehicle to insert.

    Attributes
    ----------
    vehicle_id : str
    route_id : str              one of the run's routes
    depart : float              scheduled insertion time [s], >= 0 (SUMO delays it while the route's start is occupied)
    depart_speed : str or float   SUMO ``departSpeed``: a speed [m/s] or "max", "desired", "speedLimit", "random",
                                "avg", "last"
    type_id : str               vehicle type; ``"DEFAULT_VEHTYPE"`` (passenger car, Krauss, 5 m x 1.8 m) unless more
                                types are loaded with ``extra_args``
    """

    vehicle_id: str
    route_id: str
    depart: float
    depart_speed: str | float = "max"
    type_id: str = "DEFAULT_VEHTYPE"

    def __post_init__(self) -> None:
        if not isinstance(self.vehicle_id, str) or not self.vehicle_id:
            raise ValueError(f"vehicle_id must be a non-empty string, got {self.vehicle_id!r}")
        if not isinstance(self.route_id, str) or not self.route_id:
            raise ValueError(f"vehicle {self.vehicle_id!r}: route_id must be a non-empty string, "
                             f"got {self.route_id!r}")
        d = self.depart
        if isinstance(d, bool) or not isinstance(d, (int, float, np.integer, np.floating)) \
                or not math.isfinite(d) or d < 0:
            raise ValueError(f"vehicle {self.vehicle_id!r}: depart must be a finite time >= 0 s, got {d!r}")
        s = self.depart_speed
        if isinstance(s, str):
            if s not in ("max", "desired", "speedLimit", "random", "avg", "last") and not _is_number(s):
                raise ValueError(f"vehicle {self.vehicle_id!r}: unknown depart_speed {s!r}")
        elif isinstance(s, bool) or not isinstance(s, (int, float, np.integer, np.floating)) \
                or not math.isfinite(s) or s < 0:
            raise ValueError(f"vehicle {self.vehicle_id!r}: depart_speed must be >= 0 m/s or a SUMO "
                             f"keyword, got {s!r}")


def _is_number(s: str) -> bool:
    try:
        return math.isfinite(float(s)) and float(s) >= 0
    except ValueError:
        return False


@dataclass(frozen=True)
class VehicleState:
    """One vehicle at one time, as the controller sees it (SI units; conventions in the module docstring)."""

    x: float
    y: float
    x_front: float
    y_front: float
    psi_rad: float
    speed: float
    accel: float
    length: float
    width: float
    edge_id: str
    lane_id: str
    lane_pos: float


class Observation:
    """What a controller is told about one controlled vehicle at one step.

    Attributes
    ----------
    time : float                        [s]
    vehicle_id : str
    ego : VehicleState
    others : Mapping[str, VehicleState]   every other vehicle in the network now (a read-only view of one table)
    leader : (str, float) or None       SUMO's leader on the route within the lookahead and the gap [m] (bumper
                                        to bumper minus ego's minGap); vehicles merging from an entry are not
                                        leaders. Read it during the controller call (later: RuntimeError).
    route_edges : tuple of str          the ego's route
    """

    __slots__ = ("time", "vehicle_id", "ego", "_others", "_states", "route_edges", "_leader", "_leader_fn", "_run")

    def __init__(self, time: float, vehicle_id: str, ego: VehicleState, others: Mapping[str, VehicleState],
                 leader: tuple[str, float] | None = None, route_edges: tuple[str, ...] = (), *,
                 leader_fn: Callable[[], tuple[str, float] | None] | None = None):
        self.time, self.vehicle_id, self.ego, self._others = time, vehicle_id, ego, others
        self.route_edges = route_edges
        self._leader, self._leader_fn = leader, leader_fn
        self._states = self._run = None

    @classmethod
    def _of_run(cls, run: SumoRun, time: float, vehicle_id: str, states: Mapping[str, VehicleState],
                route_edges: tuple[str, ...]) -> Observation:
        """The runner's observation (built for every controlled vehicle and step, so without a call to
        ``__init__``): ``others`` is a view of ``states`` made on first access, the leader asked from ``run``
        on first access."""
        obs = object.__new__(cls)
        obs.time, obs.vehicle_id, obs.ego, obs._others, obs._states = (
            time, vehicle_id, states[vehicle_id], None, states)  # type: ignore[assignment]
        obs.route_edges, obs._leader, obs._leader_fn, obs._run = (route_edges, None, _leader_from_run,
                                                                  run)  # type: ignore[assignment]
        return obs

    @property
    def others(self) -> Mapping[str, VehicleState]:
        if self._others is None:
            self._others = _OthersView(self._states, self.vehicle_id)
        return self._others

    @property
    def leader(self) -> tuple[str, float] | None:
        fn = self._leader_fn
        if fn is not None:
            self._leader = (self._run._leader(self.vehicle_id)  # type: ignore[attr-defined]
                            if fn is _leader_from_run else fn())
            self._leader_fn = None
        return self._leader

    def _expire(self) -> None:
        """The step is over: a leader not read so far can no longer be asked for."""
        if self._leader_fn is not None:
            self._leader_fn = _expired_leader

    def __repr__(self) -> str:
        return (f"Observation(time={self.time!r}, vehicle_id={self.vehicle_id!r}, ego={self.ego!r}, "
                f"others=<{len(self.others)} vehicles>, route_edges={self.route_edges!r})")


def _frame(ids: list[str], states: Mapping[str, VehicleState], routes: list[str]) -> Frame:
    """Every vehicle of the step (`~pirl_sim.scenarios.contract.Frame`), in the order of ``ids``."""
    st = [states[v] for v in ids]
    n = len(st)
    return Frame(tuple(ids), np.fromiter((c for x in st for c in (x.x, x.y)), dtype=float, count=2 * n).reshape(n, 2),
                 np.fromiter((x.psi_rad for x in st), dtype=float, count=n),
                 np.fromiter((x.speed for x in st), dtype=float, count=n),
                 np.fromiter((x.length for x in st), dtype=float, count=n), tuple(routes))


def _leader_from_run():  # marker: Observation.leader asks its run
    raise AssertionError("not called")


def _expired_leader():
    raise RuntimeError("Observation.leader is read from SUMO during the step only; read it in the controller call")


class _OthersView(Mapping):
    """Read-only view of the step's vehicle states without one vehicle (Observation.others), O(1) to build."""

    __slots__ = ("_states", "_ego")

    def __init__(self, states: Mapping[str, VehicleState], ego: str):
        self._states, self._ego = states, ego

    def __getitem__(self, key: str) -> VehicleState:
        if key == self._ego:
            raise KeyError(key)
        return self._states[key]

    def __iter__(self):
        return (k for k in self._states if k != self._ego)

    def __len__(self) -> int:
        return len(self._states) - (self._ego in self._states)

    def __contains__(self, key) -> bool:
        return key != self._ego and key in self._states


#: ``controller(time [s], vehicle_id, observation) -> commanded speed [m/s] or None``
Controller = Callable[[float, str, Observation], "float | None"]


@dataclass(frozen=True)
class ConstantSpeed:
    """A picklable controller commanding the same speed to every controlled vehicle (tests, benchmarks).

    Attributes
    ----------
    speed : float
        [m/s], >= 0.
    """

    speed: float

    def __post_init__(self) -> None:
        if isinstance(self.speed, bool) or not isinstance(self.speed, (int, float, np.integer, np.floating)) \
                or not math.isfinite(self.speed) or self.speed < 0:
            raise ValueError(f"speed must be a finite speed >= 0 m/s, got {self.speed!r}")

    def __call__(self, time: float, vehicle_id: str, observation: Observation) -> float:
        return float(self.speed)


@dataclass(frozen=True)
class SumoRecording:
    """Result of a run (columns: "SUMO roundabouts" page, Running SUMO).

    Attributes
    ----------
    frame : pandas.DataFrame       one row per vehicle per step (`RECORD_COLUMNS`), by step, then vehicle order;
                                   ``commanded_speed`` NaN and ``overridden`` NA where not commanded or checked
    summary : pandas.DataFrame     one row per vehicle (`SUMMARY_COLUMNS`): ``status`` ("arrived", "vanished",
                                   "running", "not_departed"), ``removed_early``, ``overridden_fraction``
    wall_time_s : float            wall-clock time of the stepping [s] (SUMO start and insertion excluded)
    sim_time_s : float             simulated time [s]
    backend : str
    seed : int
    """

    frame: pd.DataFrame
    summary: pd.DataFrame
    wall_time_s: float
    sim_time_s: float
    backend: str
    seed: int


# ----------------------------------------------------------------------------------------------
# the run
# ----------------------------------------------------------------------------------------------

@dataclass
class _VehicleRecord:
    spec: VehicleSpec
    pirl: bool
    length: float = float("nan")
    width: float = float("nan")
    last_row: int = -1
    first_time: float = float("nan")
    last_time: float = float("nan")
    last_edge: str = ""
    status: str = "not_departed"
    commanded: bool = False  # a command is active (so None must hand control back)


class SumoRun:
    """One SUMO simulation of given routes and vehicles, a context manager ("SUMO roundabouts": "In detail: SumoRun").

    Parameters
    ----------
    net, routes, vehicles : str, os.PathLike or NetworkFiles; routes; VehicleSpecs   e.g. ``network.routes(spec)``
    pirl_ids, controller : iterable of str, Controller or None   vehicles driven by ``controller`` (then required)
    seed, step_length, backend : int, float, {"libsumo", "traci"}   SUMO's ``--seed``; [s]; how SUMO is run
    speed_mode, speed_modes : int, mapping vehicle id -> int or None   TraCI speed mode (`speed_mode`), per vehicle
    override_tol, leader_lookahead : float   [m/s] a command missed by more is overridden; [m] ``Observation.leader``
    extra_args, collision_action : sequence of str, str   appended to SUMO's command line; its ``--collision.action``

    Attributes
    ----------
    colliding : frozenset of str          vehicles SUMO reported in a collision in the last step
    """

    def __init__(self, net, routes, vehicles: Iterable[VehicleSpec], *, pirl_ids: Iterable[str] = (),
                 controller: Controller | None = None, seed: int = 0,
                 step_length: float = DEFAULT_STEP_LENGTH, backend: str = "libsumo",
                 speed_mode: int = SPEED_MODE_ALL_CHECKS, override_tol: float = DEFAULT_OVERRIDE_TOL,
                 leader_lookahead: float = DEFAULT_LEADER_LOOKAHEAD, extra_args: Sequence[str] = (),
                 collision_action: str = "warn", speed_modes: Mapping[str, int] | None = None):
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if collision_action not in COLLISION_ACTIONS:
            raise ValueError(f"collision_action must be one of {COLLISION_ACTIONS}, got {collision_action!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an integer, got {seed!r}")
        for name, v in (("step_length", step_length), ("override_tol", override_tol),
                        ("leader_lookahead", leader_lookahead)):
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        speed_modes = dict(speed_modes or {})
        for label, mode in (("speed_mode", speed_mode), *((f"speed_modes[{k!r}]", m) for k, m in speed_modes.items())):
            if isinstance(mode, bool) or not isinstance(mode, (int, np.integer)) or not 0 <= mode < 128:
                raise ValueError(f"{label} must be an integer bitset in [0, 127], got {mode!r}")
        if isinstance(extra_args, str):
            raise ValueError(f"extra_args must be a sequence of arguments, got the string {extra_args!r}")
        if isinstance(net, NetworkFiles):
            net = net.net
        self.net_path = os.fspath(net)
        sumo_net = load_net(self.net_path)

        items = list(routes.items()) if isinstance(routes, Mapping) else list(routes)
        self.routes: dict[str, tuple[str, ...]] = {}
        for item in items:
            if not (isinstance(item, (tuple, list)) and len(item) == 2 and isinstance(item[0], str)):
                raise ValueError(f"routes must be (route_id, edges) pairs, got {item!r}")
            rid, edges = item
            if rid in self.routes:
                raise ValueError(f"route {rid!r} is given twice")
            self.routes[rid] = tuple(validate_route(sumo_net, edges, route_id=rid))

        self.vehicles: list[VehicleSpec] = list(vehicles)
        seen: set[str] = set()
        for v in self.vehicles:  # type: ignore[assignment]
            if not isinstance(v, VehicleSpec):
                raise ValueError(f"vehicles must be VehicleSpec instances, got {v!r}")
            if v.vehicle_id in seen:
                raise ValueError(f"vehicle id {v.vehicle_id!r} is given twice")
            seen.add(v.vehicle_id)
            if v.route_id not in self.routes:
                raise ValueError(f"vehicle {v.vehicle_id!r}: unknown route {v.route_id!r} "
                                 f"(routes: {', '.join(self.routes) or 'none'})")
        if isinstance(pirl_ids, str):
            raise ValueError(f"pirl_ids must be a collection of vehicle ids, got the string {pirl_ids!r}")
        self.pirl_ids = frozenset(pirl_ids)
        unknown = sorted(self.pirl_ids - seen)
        if unknown:
            raise ValueError(f"pirl_ids name vehicles that are not in the run: {unknown}")
        stray = sorted(set(speed_modes) - self.pirl_ids)
        if stray:
            raise ValueError(f"speed_modes name vehicles that are not controlled (pirl_ids): {stray}")
        if self.pirl_ids and controller is None:
            raise ValueError("pirl_ids are given but no controller drives them")
        if controller is not None and not callable(controller):
            raise ValueError(f"controller must be callable, got {controller!r}")

        self.controller = controller
        self._batch = controller is not None and callable(getattr(controller, "commands", None))
        self.seed = int(seed)
        self.step_length = float(step_length)
        self.backend = backend
        self.speed_mode = int(speed_mode)
        self.speed_modes = {k: int(m) for k, m in speed_modes.items()}
        self.colliding: frozenset[str] = frozenset()
        self.override_tol = float(override_tol)
        self.leader_lookahead = float(leader_lookahead)
        self.collision_action = collision_action
        self.command = sumo_command(self.net_path, seed=self.seed, step_length=self.step_length,
                                    extra_args=extra_args, collision_action=collision_action)

        self._api: Any = None  # libsumo module or traci connection while running
        self._closed = False
        self._order = {v.vehicle_id: k for k, v in enumerate(self.vehicles)}
        self._veh = {v.vehicle_id: _VehicleRecord(v, v.vehicle_id in self.pirl_ids) for v in self.vehicles}
        self._rows: list[tuple] = []  # the `_FIXED_COLUMNS` of every row
        self._n_rows = 0
        self._cols: dict[str, list] = {c: [] for c in _LATER_COLUMNS}
        self._pending: dict[str, tuple[int, float]] = {}  # vehicle -> (row, commanded speed)
        self._present: set[str] = set()  # vehicles recorded in the last step
        self._n_controlled = 0  # controlled vehicles among them
        self._step = 0
        self._wall = 0.0
        self._vars: tuple[int, ...] = ()

    # -- lifecycle --------------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """Whether SUMO is started and not yet closed."""
        return self._api is not None

    def start(self) -> SumoRun:
        """Start SUMO and schedule the routes and vehicles; returns ``self``.

        Raises
        ------
        RuntimeError
            If this run was started before, or (libsumo) another libsumo run of this process is open.
        """
        global _libsumo_owner
        if self._api is not None or self._closed:
            raise RuntimeError("a SumoRun starts once; build a new one for another simulation")
        if self.backend == "libsumo":
            if _libsumo_owner is not None:
                raise RuntimeError(
                    "libsumo runs one simulation per process and another SumoRun holds it; close that "
                    "run first, use run_in_subprocess(...), or backend='traci'")
            libsumo = _import_libsumo()

            libsumo.start(self.command)
            _libsumo_owner = self
            api = libsumo
        else:
            traci = sumo_module("traci")

            label = f"pirl_sim-{os.getpid()}-{id(self)}"
            traci.start(self.command, label=label)
            api = traci.getConnection(label)
        self._api = api
        try:
            from traci import constants as tc  # pure-Python constants, identical in libsumo

            self._vars = (tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_ACCELERATION,
                          tc.VAR_ROAD_ID, tc.VAR_LANE_ID, tc.VAR_LANEPOSITION)
            for rid, edges in self.routes.items():
                api.route.add(rid, list(edges))
            for v in self.vehicles:
                api.vehicle.add(v.vehicle_id, v.route_id, typeID=v.type_id, depart=repr(float(v.depart)),
                                departLane="best", departPos="base", departSpeed=str(v.depart_speed))
        except BaseException:
            self.close(quiet=True)
            raise
        return self

    def close(self, *, quiet: bool = False) -> None:
        """Close SUMO (idempotent; also called by ``__exit__``). ``quiet``: an error of the closing itself is
        dropped, for when another exception is on its way (an interrupted run whose SUMO already ended: TraCI's
        close then fails on the broken connection, and that must not replace the interruption)."""
        global _libsumo_owner
        api, self._api = self._api, None
        self._closed = True
        if api is None:
            return
        try:
            api.close()
        except Exception:
            if not quiet:
                raise
        finally:
            if _libsumo_owner is self:
                _libsumo_owner = None

    def __enter__(self) -> SumoRun:
        return self.start()

    def __exit__(self, exc_type, *exc) -> None:
        self.close(quiet=exc_type is not None)

    def __del__(self):  # last resort: never leave libsumo's one simulation open
        try:
            self.close()
        except Exception:
            pass

    # -- stepping ---------------------------------------------------------------------------------

    @property
    def time(self) -> float:
        """Current simulation time [s]."""
        self._require_running()
        return float(self._api.simulation.getTime())

    def expected(self) -> int:
        """Vehicles in the network or still waiting to be inserted (0: the run has nothing left to do)."""
        self._require_running()
        return int(self._api.simulation.getMinExpectedNumber())

    @property
    def n_present(self) -> int:
        """Vehicles in the network after the last step."""
        return len(self._present)

    @property
    def n_present_controlled(self) -> int:
        """Controlled vehicles (``pirl_ids``) in the network after the last step."""
        return self._n_controlled

    @property
    def n_finished(self) -> int:
        """Vehicles that have left the network (arrived or vanished) so far."""
        return sum(rec.status in ("arrived", "vanished") for rec in self._veh.values())

    def _require_running(self) -> None:
        if self._api is None:
            raise RuntimeError("the run is not started (use `with SumoRun(...) as run:` or run.start())")

    def step(self) -> None:
        """Advance one step: SUMO moves, then the new state is recorded and the controller is asked."""
        self._require_running()
        api = self._api
        t0 = _time.perf_counter()
        api.simulationStep()
        self._step += 1
        t = float(api.simulation.getTime())

        for vid in api.simulation.getDepartedIDList():
            rec = self._veh[vid]
            api.vehicle.subscribe(vid, self._vars)
            rec.length = float(api.vehicle.getLength(vid))
            rec.width = float(api.vehicle.getWidth(vid))
            rec.first_time = t
            if rec.pirl:
                api.vehicle.setSpeedMode(vid, self.speed_modes.get(vid, self.speed_mode))
        cols = self._cols
        colliding = set(api.simulation.getCollidingVehiclesIDList())
        self.colliding = frozenset(colliding)
        results = api.vehicle.getAllSubscriptionResults()
        ids = sorted(results, key=self._order.__getitem__)
        # vehicles gone since the last step: arrived when SUMO says so at the end of their route, else
        # vanished (removed through the API, teleported away, ... - these are not all in the arrived list)
        arrived = set(api.simulation.getArrivedIDList())
        for vid in [v for v in self._present if v not in results]:
            rec = self._veh[vid]
            done = vid in arrived and rec.last_edge == self.routes[rec.spec.route_id][-1]
            rec.status = "arrived" if done else "vanished"
            cols["arrived" if done else "vanished"][rec.last_row] = True
            if vid in colliding:  # taken out by collision.action=remove in this step
                cols["collided"][rec.last_row] = True
            self._pending.pop(vid, None)
        self._present = set(results)
        self._n_controlled = sum(1 for vid in ids if self._veh[vid].pirl)
        for vid in ids:
            self._veh[vid].status = "running"  # also back from a teleport
        states = {vid: self._state(vid, results[vid]) for vid in ids}
        # commands of the previous step: did SUMO drive them?
        for vid, (row, cmd) in self._pending.items():
            st = states.get(vid)
            if st is not None:
                cols["overridden"][row] = abs(st.speed - cmd) > self.override_tol
        self._pending.clear()

        # one row per vehicle: the columns fixed now in one tuple (`_FIXED_COLUMNS`), the ones later steps may
        # change (`_LATER_COLUMNS`) in lists of their own (this runs for every vehicle and step)
        row = self._n_rows
        self._n_rows += len(ids)
        step_no, cos, sin = self._step, math.cos, math.sin
        add = self._rows.append
        for vid in ids:
            rec = self._veh[vid]
            st = states[vid]
            rec.last_row, rec.last_time, rec.last_edge = row, t, st.edge_id
            row += 1
            speed, psi = st.speed, st.psi_rad
            add((step_no, t, vid, rec.spec.route_id, rec.pirl, st.x, st.y, st.x_front, st.y_front, psi, speed,
                 speed * cos(psi), speed * sin(psi), st.accel, st.length, st.width, st.edge_id, st.lane_id,
                 st.lane_pos))
        n = len(ids)
        cols["commanded_speed"].extend([math.nan] * n)
        cols["overridden"].extend([None] * n)
        cols["collided"].extend([vid in colliding for vid in ids] if colliding else [False] * n)
        cols["arrived"].extend([False] * n)
        cols["vanished"].extend([False] * n)

        if self.pirl_ids:
            frozen_states = MappingProxyType(states)
            observations = {}
            of_run = Observation._of_run
            for vid in ids:
                rec = self._veh[vid]
                if not rec.pirl:
                    continue
                observations[vid] = of_run(self, t, vid, frozen_states, self.routes[rec.spec.route_id])
            batch = None
            if observations and self._batch:
                extra = ({"frame": _frame(ids, states, [self._veh[v].spec.route_id for v in ids])}
                         if getattr(self.controller, "needs_frame", False) else {})
                batch = self.controller.commands(t, MappingProxyType(observations), **extra)  # type: ignore[union-attr]
                if not isinstance(batch, Mapping):
                    raise ValueError(f"controller.commands returned {type(batch).__name__} at t = {t} s; "
                                     "expected a mapping vehicle id -> speed or None")
                stray = sorted(set(batch) - set(observations))
                if stray:
                    raise ValueError(f"controller.commands returned commands for vehicles it was not asked "
                                     f"about at t = {t} s: {stray}")
            for vid, obs in observations.items():
                rec = self._veh[vid]
                cmd = (batch.get(vid) if batch is not None  # type: ignore[assignment]
                       else self.controller(t, vid, obs))  # type: ignore[misc]
                if cmd is None:
                    if rec.commanded:
                        api.vehicle.setSpeed(vid, -1.0)
                        rec.commanded = False
                    continue
                if isinstance(cmd, bool) or not isinstance(cmd, (int, float, np.integer, np.floating)) \
                        or not math.isfinite(cmd) or cmd < 0:
                    raise ValueError(f"controller returned {cmd!r} for vehicle {vid!r} at t = {t} s; "
                                     "expected a speed >= 0 m/s or None")
                cmd = float(cmd)
                api.vehicle.setSpeed(vid, cmd)
                rec.commanded = True
                cols["commanded_speed"][rec.last_row] = cmd
                self._pending[vid] = (rec.last_row, cmd)
            for obs in observations.values():
                obs._expire()
        self._wall += _time.perf_counter() - t0

    def set_command(self, vehicle_id: str, speed: float) -> None:
        """Replace the commanded speed [m/s] of a controlled vehicle in the network for the next step (what
        the controller returned for it at the end of the last step)."""
        self._require_running()
        rec = self._veh.get(vehicle_id)
        if rec is None or not rec.pirl or vehicle_id not in self._present:
            raise ValueError(f"{vehicle_id!r} is not a controlled vehicle in the network")
        if isinstance(speed, bool) or not isinstance(speed, (int, float, np.integer, np.floating)) \
                or not math.isfinite(speed) or speed < 0:
            raise ValueError(f"speed must be a finite speed >= 0 m/s, got {speed!r}")
        self._api.vehicle.setSpeed(vehicle_id, float(speed))
        rec.commanded = True
        self._cols["commanded_speed"][rec.last_row] = float(speed)
        self._pending[vehicle_id] = (rec.last_row, float(speed))

    def _state(self, vid: str, r: Mapping[int, Any]) -> VehicleState:
        rec = self._veh[vid]
        var = self._vars
        xf, yf = r[var[0]]
        psi = _angle_to_psi(float(r[var[1]]))
        half = 0.5 * rec.length
        # the frozen dataclass's fields set directly (its __init__ costs ~6x more; this runs for every vehicle
        # and step): the same object, equal to VehicleState(x=..., ...)
        st = object.__new__(VehicleState)
        st.__dict__.update(
            x=xf - half * math.cos(psi), y=yf - half * math.sin(psi), x_front=float(xf), y_front=float(yf),
            psi_rad=psi, speed=float(r[var[2]]), accel=float(r[var[3]]),
            length=rec.length, width=rec.width, edge_id=r[var[4]], lane_id=r[var[5]],
            lane_pos=float(r[var[6]]),
        )
        return st

    def _leader(self, vid: str) -> tuple[str, float] | None:
        lead = self._api.vehicle.getLeader(vid, self.leader_lookahead)
        if not lead or not lead[0]:
            return None
        return str(lead[0]), float(lead[1])

    def run(self, duration: float, *, until_empty: bool = True) -> SumoRecording:
        """Step for ``duration`` [s] of simulated time (fewer if ``until_empty`` and every vehicle is done).

        Parameters
        ----------
        duration : float
            [s], > 0; rounded to whole steps.
        until_empty : bool
            Stop early once no vehicle is in the network or waiting to be inserted.

        Returns
        -------
        SumoRecording
            Everything recorded since the start (a run may be continued by calling ``run`` again).
        """
        if isinstance(duration, bool) or not isinstance(duration, (int, float, np.integer, np.floating)) \
                or not math.isfinite(duration) or duration <= 0:
            raise ValueError(f"duration must be a finite time > 0 s, got {duration!r}")
        self._require_running()
        n_steps = max(1, round(duration / self.step_length))
        for _ in range(n_steps):
            self.step()
            if until_empty and self.expected() == 0:
                break
        return self.recording()

    # -- results ----------------------------------------------------------------------------------

    def recording(self) -> SumoRecording:
        """The recording so far as tidy DataFrames."""
        cols = dict(zip(_FIXED_COLUMNS,
                        zip(*self._rows))) if self._rows else {c: [] for c in _FIXED_COLUMNS}  # type: ignore[misc]
        cols.update(self._cols)  # type: ignore[arg-type]
        frame = pd.DataFrame({c: cols[c] for c in RECORD_COLUMNS})
        frame = frame.astype({
            "step": "int64", "time": "float64", "vehicle_id": "object", "route_id": "object", "pirl": "bool",
            "x": "float64", "y": "float64", "x_front": "float64", "y_front": "float64",
            "psi_rad": "float64", "speed": "float64", "vx": "float64", "vy": "float64", "accel": "float64",
            "length": "float64", "width": "float64", "edge_id": "object", "lane_id": "object",
            "lane_pos": "float64", "commanded_speed": "float64", "overridden": "boolean",
            "collided": "bool", "arrived": "bool", "vanished": "bool",
        })
        groups = {vid: g for vid, g in frame.groupby("vehicle_id", sort=False)}
        rows = []
        for v in self.vehicles:
            rec = self._veh[v.vehicle_id]
            mine = groups.get(v.vehicle_id, frame.iloc[:0])
            checked = mine["overridden"].dropna()
            rows.append({
                "vehicle_id": v.vehicle_id, "route_id": v.route_id, "pirl": rec.pirl,
                "depart": float(v.depart), "first_time": rec.first_time, "last_time": rec.last_time,
                "n_steps": len(mine), "status": rec.status, "collided": bool(mine["collided"].any()),
                "removed_early": rec.status == "vanished",
                "n_commanded": int(mine["commanded_speed"].notna().sum()),
                "overridden_fraction": float(checked.astype(bool).mean()) if len(checked) else math.nan,
            })
        summary = pd.DataFrame(rows, columns=list(SUMMARY_COLUMNS)).astype({
            "pirl": "bool", "depart": "float64", "first_time": "float64", "last_time": "float64",
            "n_steps": "int64", "collided": "bool", "removed_early": "bool", "n_commanded": "int64",
            "overridden_fraction": "float64",
        })
        return SumoRecording(frame=frame, summary=summary, wall_time_s=self._wall,
                             sim_time_s=self._step * self.step_length, backend=self.backend, seed=self.seed)


# ----------------------------------------------------------------------------------------------
# one-call helpers
# ----------------------------------------------------------------------------------------------

def simulate(net, routes, vehicles: Iterable[VehicleSpec], duration: float, *,
             until_empty: bool = True, **kwargs) -> SumoRecording:
    """Build a `SumoRun`, run it for ``duration`` [s] and close it (also on errors).

    Parameters
    ----------
    net, routes, vehicles : see `SumoRun`.
    duration : float          [s]
    until_empty : bool        see `SumoRun.run`
    **kwargs : passed to `SumoRun` (``pirl_ids``, ``controller``, ``seed``, ``backend``, ...).

    Returns
    -------
    recording : SumoRecording
    """
    with SumoRun(net, routes, vehicles, **kwargs) as run:
        return run.run(duration, until_empty=until_empty)


def run_in_subprocess(fn: Callable[..., Any], *args, **kwargs) -> Any:
    """Call ``fn(*args, **kwargs)`` in a fresh spawned worker process and return its result (or re-raise).

    libsumo holds one simulation per process, and a forked child would inherit its state. ``fn``, the arguments
    and the result must be picklable; a calling script needs the ``if __name__ == "__main__":`` guard (SUMO page).

    Parameters
    ----------
    fn : callable
    *args, **kwargs
        Passed to ``fn``.
    """
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(fn, *args, **kwargs).result()
