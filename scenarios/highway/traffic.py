"""Traffic on highway-env's roundabout: PIRL drivers, background IDM drivers, entries, exits and crashes.

:class:`RoundaboutTraffic` is a highway-env :class:`~highway_env.road.road.Road` (highway-env's environments,
observations and rendering work with it unchanged) that also runs the traffic: every ``act()`` it decides every
vehicle's longitudinal command [m/s^2], every ``step(dt)`` (dt = 0.1 s) it moves the vehicles, removes those
that arrived or crashed ``crash_removal_delay`` seconds ago, inserts departures where there is room and records
one frame. PIRL drivers (:class:`~.vehicles.PirlVehicle`) re-plan in one batched MPC call
(:class:`pirl_sim.scenarios.drivers.PirlDrivers`), their command capped by the IDM interaction limit towards
their leader (a cut larger than ``override_tol / dt`` is an override); background drivers
(:class:`~.vehicles.BackgroundVehicle`) are highway-env's IDM; the ego (env only) takes the agent's
acceleration. Leaders are found across lane segments along the route, and entering vehicles yield to the ring by
gap acceptance (``yield_*`` parameters).

The rules are explained in the documentation's "highway-env roundabouts" page.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import pandas as pd
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle

from pirl_sim.validation import number

from ..contract import STEP, EgoObservation, EgoView, Frame, ground_truth_table
from ..planning import theta_columns
from ..population_config import FEATURE_NAMES
from ..recording import (
    DRIVER_STEP_COLUMNS,
    BACKGROUND_STYLE,
    BACKGROUND_STYLE_NAME,
    TRACK_COLUMNS,
    ScenarioRecording,
)
from ..scenario_config import MpcDriverConfig
from ..drivers import PirlDrivers, RouteSet, RouteSetProfile, route_set_model
from .crossings import lane_conflicts, route_conflicts
from .network import RouteLanes, ring_lanes
from .vehicles import (
    BACKGROUND,
    EGO,
    PIRL,
    STYLE_COLORS,
    BackgroundVehicle,
    EgoVehicle,
    PirlVehicle,
    RouteFollowing,
    place_on_route,
)

__all__ = ["STEP_LENGTH", "DriverConfig", "TrafficRules", "RoundaboutTraffic", "idm_acceleration"]

STEP_LENGTH = STEP  #: [s] simulation step = driver-model step = INTERACTION frame (the contract's)
_EPS = 1e-9
_STANDSTILL = 0.1  # [m/s] slower counts as stopped at the line
_IN_THE_WAY = 1.0  # [m/s] a vehicle this slow whose rear is still over a node is in the way of the node's other lanes


@dataclass(frozen=True)
class DriverConfig(MpcDriverConfig):
    """The PIRL drivers' model and MPC (`~pirl_sim.scenarios.scenario_config.MpcDriverConfig`, whose other attributes
    it has, as the SUMO scenario's, without SUMO's vehicle type; validated on construction).

    Attributes
    ----------
    speed_smoothing : float            default 8 m (`~pirl_sim.scenarios.highway.network` says why)
    depart_speed : float               speed [m/s] at insertion (capped by the desired speed there)
    stop_speed, resume_speed : float   [m/s] standstill hand-back: IDM drives a PIRL vehicle slower than
                                       ``stop_speed`` until it is faster than ``resume_speed``
    override_tol : float               [m/s] a command is overridden when the speed after the step misses it by more
    """

    speed_smoothing: float = 8.0
    override_tol: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "override_tol", number("drivers.override_tol", self.override_tol, low=0.0,
                                                        allow_equal=False))


@dataclass(frozen=True)
class TrafficRules:
    """How vehicles share the roundabout (see the module docstring; validated on construction).

    Attributes
    ----------
    lookahead : float                  [m] how far ahead on its route a vehicle looks for a leader, > 0
    yield_distance : float             [m] an entering vehicle decides whether to yield within this of the ring, > 0
    yield_lookback : float             [m] ring vehicles up to this far before the merge node count, > 0
    yield_headway : float              [s] a ring vehicle's time away from the node after the entering one cleared it
    yield_min_distance : float         [m] a ring vehicle closer than this to the node always conflicts, >= 0
    entry_acceleration, max_deceleration : float   [m/s^2] assumed to clear the node; more needed to stop: go, > 0
    stop_clearance, stop_margin : float   [m] waiting vehicles' clearance from the ring lane; gap to the stop line, >= 0
    crash_removal_delay : float or None   [s] crashed vehicles are removed this long after the crash; None: never
    initial_spacing : float            [m] least distance between vehicles placed at a reset, > 0
    background_speed_factor_std : float   std of background drivers' speed factors (mean 1, in [0.7, 1.3]), >= 0
    safety_time_gap, safety_jam_gap : float   [s], [m] the reaction time and jam gap of the safety layer of drivers
                                       who interact (`safe_acceleration`; their own cost keeps their distance), >= 0
    safety_yield_headway : float       [s] ``yield_headway`` in that safety layer, >= 0
    """

    lookahead: float = 80.0
    yield_distance: float = 40.0
    yield_lookback: float = 60.0
    yield_headway: float = 1.5
    yield_min_distance: float = 10.0
    entry_acceleration: float = 1.5
    max_deceleration: float = 5.0
    stop_clearance: float = 0.75
    stop_margin: float = 0.5
    crash_removal_delay: float | None = 2.0
    initial_spacing: float = 15.0
    background_speed_factor_std: float = 0.1
    safety_time_gap: float = 0.5
    safety_jam_gap: float = 1.0
    safety_yield_headway: float = 1.0

    def __post_init__(self) -> None:
        for name in ("lookahead", "yield_distance", "yield_lookback", "entry_acceleration", "max_deceleration",
                     "initial_spacing"):
            object.__setattr__(self, name, number(f"rules.{name}", getattr(self, name), low=0.0, allow_equal=False))
        for name in ("yield_headway", "yield_min_distance", "stop_clearance", "stop_margin",
                     "background_speed_factor_std", "safety_time_gap", "safety_jam_gap", "safety_yield_headway"):
            object.__setattr__(self, name, number(f"rules.{name}", getattr(self, name), low=0.0))
        if self.crash_removal_delay is not None:
            object.__setattr__(self, "crash_removal_delay",
                               number("rules.crash_removal_delay", self.crash_removal_delay, low=0.0))


# ----------------------------------------------------------------------------------------------
# IDM (highway-env's parameters)
# ----------------------------------------------------------------------------------------------

#: highway-env's IDM parameters (``IDMVehicle`` class constants)
IDM_A_MAX = IDMVehicle.COMFORT_ACC_MAX  # [m/s^2]
IDM_B = -IDMVehicle.COMFORT_ACC_MIN  # [m/s^2]
IDM_T = IDMVehicle.TIME_WANTED  # [s]
IDM_S0 = IDMVehicle.DISTANCE_WANTED - IDMVehicle.LENGTH  # [m] jam gap, bumper to bumper
IDM_ACC_LIMIT = IDMVehicle.ACC_MAX  # [m/s^2] |acceleration| cap of highway-env's IDM


def idm_acceleration(v: float, v0: float, gap: float | None = None, v_lead: float = 0.0, *,
                     delta: float = IDMVehicle.DELTA, s0: float = IDM_S0, free: bool = True) -> float:
    """The IDM's acceleration [m/s^2] with highway-env's parameters.

    ``a_max (1 - (v/v0)^delta) - a_max (s*/gap)^2`` with ``s* = s0 + max(0, v T + v (v - v_lead) / (2 sqrt(a_max b)))``.

    Parameters
    ----------
    v, v0 : float          speed and desired speed [m/s]
    gap : float or None    bumper-to-bumper gap [m] to the leader (None: no leader)
    v_lead : float         leader speed [m/s]
    delta : float          exponent of the free-road term
    s0 : float             jam gap [m]
    free : bool            False: ``a_max`` instead of the free-road term (the limit an obstacle imposes)
    """
    v = max(v, 0.0)
    a = IDM_A_MAX * (1.0 - (v / max(v0, _EPS)) ** delta) if free else IDM_A_MAX
    if gap is not None:
        s_star = s0 + max(0.0, v * IDM_T + v * (v - v_lead) / (2.0 * math.sqrt(IDM_A_MAX * IDM_B)))
        a -= IDM_A_MAX * (s_star / max(gap, 0.01)) ** 2
    return a


def safe_acceleration(v: float, gap: float, v_lead: float, *, tau: float, b: float, dt: float) -> float:
    """The acceleration [m/s^2] that reaches Krauss's safe speed in one step of dt [s]:
    ``v_safe = v_L + (gap - v_L tau) / ((v + v_L) / (2 b) + tau)``, the fastest speed from which the car can still
    stop behind a leader that brakes at b [m/s^2] after a reaction time tau [s] (Krauss 1998; SUMO's default
    car-following model). gap [m] bumper to bumper, less the jam gap; v, v_L [m/s]."""
    v, v_lead = max(v, 0.0), max(v_lead, 0.0)
    v_safe = v_lead + (gap - v_lead * tau) / ((v + v_lead) / (2.0 * b) + tau)
    return (max(v_safe, 0.0) - v) / dt


def _time_to_cover(d: float, v: float, a: float) -> float:
    """Time [s] to travel d [m] from speed v [m/s] at constant acceleration a > 0 [m/s^2]."""
    if d <= 0:
        return 0.0
    return (-v + math.sqrt(v * v + 2.0 * a * d)) / a


# ----------------------------------------------------------------------------------------------
# the traffic
# ----------------------------------------------------------------------------------------------

class _Occupancy(NamedTuple):
    """Vehicles by lane (``(from, to)`` -> [(lane coordinate [m], vehicle)] sorted by the coordinate) and the
    committed entering vehicles (leaders at their merge nodes) of one step."""

    on_lane: dict
    merging: list


@dataclass
class _Track:
    """Bookkeeping of one vehicle, from insertion on."""

    track_id: int
    vehicle_id: str
    route_id: str
    kind: str
    style: int
    style_name: str
    theta: np.ndarray
    n_frames: int = 0
    n_commands: int = 0
    n_overridden: int = 0
    handed_back: bool = False
    collided: bool = False
    crash_time: float | None = None
    status: str = "running"
    removed_early: bool = False


@dataclass(frozen=True)
class _Departure:
    vehicle_id: str
    depart: float
    route_id: str
    is_pirl: bool
    style: int
    style_name: str
    theta: np.ndarray


class RoundaboutTraffic(Road):
    """highway-env ``Road`` whose ``act``/``step`` run the roundabout's traffic ("highway-env roundabouts": Traffic).

    Parameters
    ----------
    network, routes, route_set : RoadNetwork, mapping, RouteSet   the road, its routes' lanes, their reference paths
    plan : pandas.DataFrame               vehicles to insert (`~pirl_sim.scenarios.planning.plan_population`)
    drivers, rules, control_noise : DriverConfig, TrafficRules, float   [m/s^3] std of noise on PIRL drivers' jerk
    noise_rng, behaviour_rng, np_random, record, record_history : Generators and bools, see the page.

    Attributes
    ----------
    time : float                 [s] since the start
    controller : PirlDrivers     the PIRL drivers' batched MPC controller
    act_time_s : float           wall time [s] spent deciding commands (controller included)
    """

    def __init__(self, network, routes: Mapping[str, RouteLanes], route_set: RouteSet, plan: pd.DataFrame, *,
                 drivers: DriverConfig, rules: TrafficRules, control_noise: float = 0.0,
                 noise_rng: np.random.Generator | None = None, behaviour_rng: np.random.Generator | None = None,
                 np_random=None, record: bool = True, record_history: bool = False) -> None:
        super().__init__(network=network, vehicles=[], np_random=np_random, record_history=record_history)
        if not isinstance(drivers, DriverConfig) or not isinstance(rules, TrafficRules):
            raise TypeError("drivers must be a DriverConfig and rules a TrafficRules")
        self.routes = dict(routes)
        self.route_set = route_set
        self.ring = ring_lanes(network)  # lanes (from, to) on the roundabout's ring
        unknown = sorted(set(plan["route_id"]) - set(self.routes))
        if unknown:
            raise ValueError(f"planned routes {unknown} are not in the catalogue {sorted(self.routes)}")
        missing = [r for r in self.routes if r not in route_set.route_ids]
        if missing:
            raise ValueError(f"routes {missing} have no reference path in the route set")
        self.drivers = drivers
        self.rules = rules
        self.record = record
        self.behaviour_rng = behaviour_rng if behaviour_rng is not None else np.random.default_rng(0)
        theta_cols = theta_columns(plan)
        self.model = route_set_model(route_set, dt=STEP_LENGTH, a_lat=drivers.a_lat, v_max=drivers.v_max,
                                     n_iter=drivers.n_iter, n_qp_iter=drivers.n_qp_iter,
                                     interacting=len(theta_cols) > len(FEATURE_NAMES))
        self.profile = RouteSetProfile(route_set, drivers.a_lat, drivers.v_max)
        self._pending: list[_Departure] = [
            _Departure(r.vehicle_id, float(r.depart), r.route_id, bool(r.is_pirl), int(r.style), r.style_name,
                       np.array([getattr(r, c) for c in theta_cols], dtype=float))
            for r in plan.sort_values("depart", kind="stable").itertuples(index=False)]
        self.controller = PirlDrivers(
            self.model, {d.vehicle_id: (d.route_id, d.theta) for d in self._pending if d.is_pirl},
            horizon=drivers.horizon, control_noise=control_noise, rng=noise_rng,
            override_tol=drivers.override_tol, stop_speed=drivers.stop_speed, resume_speed=drivers.resume_speed)
        self.time = 0.0
        self.frame = 0
        self.act_time_s = 0.0
        self.tracks: dict[str, _Track] = {}
        self._rows: list[tuple] = []
        self._pirl_frames: list[tuple] = []  # (track id, frame, crashed) of every recorded PIRL frame
        # (track id, frame) -> (overridden, speed error [m/s] of the applied command)
        self._pirl_commands: dict[tuple[int, int], tuple[bool, float]] = {}
        self._commands: dict[str, float] = {}  # PIRL vehicle id -> commanded acceleration this step
        self._upstream = self._upstream_ring_lanes()
        self._stop_offset = self._stop_offsets()
        self._ring_after = self._ring_lanes_after()
        self._leaving: dict[str, list[tuple[str, str]]] = {}  # node -> the lanes (from, to) that leave it
        for a_, tos in self.network.graph.items():
            self._leaving[a_] = sorted((a_, b_) for b_ in tos)
        #: crossings and merges away from the ring's merges (`~.crossings.lane_conflicts`; none on highway-env's own)
        self.conflicts = lane_conflicts(network, self.routes, self.ring)
        self._conflicts_ahead = route_conflicts(self.routes, self.conflicts)
        self._conflict_at = {rid: {c: (s, side, rank) for s, c, side, rank in rows}
                             for rid, rows in self._conflicts_ahead.items()}
        self._accepted: set[tuple[str, int]] = set()  # (vehicle id, conflict) of gaps taken against a higher rank
        self._vdes_cache: dict[tuple[str, float], float] = {}
        #: called as ``callback(traffic)`` at the end of every :meth:`step` (after removal, recording, insertion)
        self.step_callbacks: list = []

    # -- set-up -------------------------------------------------------------------------------------

    def _upstream_ring_lanes(self) -> dict[str, dict[tuple[str, str], float]]:
        """merge node -> {ring lane (from, to): distance [m] from the lane's start to the node}, walking
        back round the ring up to ``yield_lookback`` (plus one lane)."""
        pred: dict[str, str] = {}
        for a, b in sorted(self.ring):
            pred[b] = a
        out: dict[str, dict[tuple[str, str], float]] = {}
        for route in self.routes.values():
            node = route.merge_node
            if node in out:
                continue
            lanes: dict[tuple[str, str], float] = {}
            dist, b = 0.0, node
            while dist < self.rules.yield_lookback and b in pred and len(lanes) < len(pred):
                a = pred[b]
                dist += self.network.get_lane((a, b, 0)).length
                lanes[(a, b)] = dist
                b = a
            out[node] = lanes
        return out

    def _ring_lanes_after(self) -> dict[str, tuple[str, str]]:
        """ring node -> the ring lane (from, to) that leaves it (where a diverging vehicle's body still sweeps)."""
        return {a: (a, b) for a, b in sorted(self.ring)}

    def _stop_offsets(self) -> dict[tuple[str, str], float]:
        """entry lane (from, to) -> distance [m] before its merge node where a waiting vehicle's front bumper stops.

        Entries meet the ring at an angle (66 degrees here), so a vehicle whose front is at the node blocks
        the ring. The stop position is the nearest one (0.25 m steps back along the route, across lanes where an
        entry lane is short) at which every corner of a vehicle box on the lane centre is at least
        ``WIDTH / 2 + stop_clearance`` from the ring lanes next to the node (their centre lines, not continued past
        their ends: highway-env's ``AbstractLane.distance``).
        """
        out: dict[tuple[str, str], float] = {}
        length, width = IDMVehicle.LENGTH, IDMVehicle.WIDTH
        need = 0.5 * width + self.rules.stop_clearance
        for route in self.routes.values():
            key = route.lanes[route.entry_lane][:2]
            if key in out:
                continue
            node = route.merge_node
            ring = [self.network.get_lane((a, b, 0)) for a, b in sorted(self.ring) if node in (a, b)]
            x = 0.0
            while ring and x < route.merge_s - length:
                u = route.merge_s - x - 0.5 * length
                k = int(np.searchsorted(route.offsets, u, side="right") - 1)
                lane = self.network.get_lane(route.lanes[k])
                c, h = lane.position(u - route.offsets[k], 0.0), lane.heading_at(u - route.offsets[k])
                d = np.array([math.cos(h), math.sin(h)])
                n = np.array([-d[1], d[0]])
                corners = [c + a * 0.5 * length * d + b * 0.5 * width * n for a in (-1, 1) for b in (-1, 1)]
                if min(r.distance(p) for r in ring for p in corners) >= need:
                    break
                x += 0.25
            out[key] = x
        return out

    def _stop_offset_of(self, route: RouteLanes) -> float:
        """[m] `_stop_offsets` of the route's entry lane."""
        return self._stop_offset[route.lanes[route.entry_lane][:2]]

    def v_des(self, vehicle: RouteFollowing) -> float:
        """The desired speed [m/s] of the vehicle's route at its route coordinate."""
        return float(self.v_des_many([vehicle])[0])

    def v_des_many(self, vehicles: list) -> np.ndarray:
        """:meth:`v_des` of several vehicles in one evaluation, shape (len(vehicles),)."""
        if not vehicles:
            return np.zeros(0)
        rs = self.route_set
        s = np.array([rs.offsets[rs.index(v.route_lanes.route_id)] + v.route_s for v in vehicles])
        return self.profile(s)[0]

    def add_vehicle(self, kind: str, vehicle_id: str, route_id: str, s: float, speed: float, *,
                    style: int = BACKGROUND_STYLE, style_name: str = BACKGROUND_STYLE_NAME,
                    theta: np.ndarray | None = None):
        """Put a vehicle on the road at route coordinate ``s`` [m] with ``speed`` [m/s] and start its track.

        ``kind`` is ``"pirl"`` (then ``vehicle_id`` must be a planned PIRL vehicle), ``"background"`` or
        ``"ego"``. Returns the vehicle.
        """
        if vehicle_id in self.tracks:
            raise ValueError(f"vehicle {vehicle_id!r} is already on the road (or was)")
        route = self.routes[route_id]
        cls = {PIRL: PirlVehicle, BACKGROUND: BackgroundVehicle, EGO: EgoVehicle}[kind]
        v = place_on_route(cls, self, route, s, speed, vehicle_id)
        if kind == PIRL:
            v.theta = np.asarray(theta, dtype=float)
            v.style, v.style_name = int(style), style_name
            v.color = STYLE_COLORS[int(style) % len(STYLE_COLORS)]
        elif kind == BACKGROUND:
            rng = self.behaviour_rng
            v.speed_factor = float(np.clip(1.0 + self.rules.background_speed_factor_std * rng.standard_normal(),
                                           0.7, 1.3))
            v.DELTA = float(rng.uniform(*IDMVehicle.DELTA_RANGE))  # highway-env's randomize_behavior, our rng
        self.vehicles.append(v)
        self.tracks[vehicle_id] = _Track(
            len(self.tracks) + 1, vehicle_id, route_id, kind, int(style) if kind == PIRL else BACKGROUND_STYLE,
            style_name if kind == PIRL else (BACKGROUND_STYLE_NAME if kind == BACKGROUND else "ego"),
            np.asarray(theta, dtype=float) if kind == PIRL else np.full(self.model.features.n_features, np.nan))
        return v

    def _depart_speed(self, route_id: str, s: float, kind: str, factor: float = 1.0) -> float:
        key = (route_id, s)
        if key not in self._vdes_cache:
            r = self.route_set.index(route_id)
            self._vdes_cache[key] = float(self.profile(self.route_set.offsets[r] + np.array([s]))[0][0])
        return min(self.drivers.depart_speed, factor * self._vdes_cache[key])

    def place_initial(self, n: int, *, avoid: tuple = ()) -> int:
        """Take the first ``n`` pending departures and put them on their routes at once (an env's reset).

        Route coordinates are drawn uniformly (behaviour stream) up to 10 m before the route's end, at
        least ``initial_spacing`` from every vehicle on the road, not within 15 m before a merge node;
        speed: the desired speed there (capped by ``depart_speed``). A vehicle without a free place after
        20 draws departs normally at time 0 instead. Returns the number placed.
        """
        rng = self.behaviour_rng
        placed = 0
        chosen, rest = self._pending[:n], self._pending[n:]
        later = []
        for d in chosen:
            route = self.routes[d.route_id]
            for _ in range(20):
                s = float(rng.uniform(0.0, route.length - 10.0))
                if route.merge_s - 15.0 < s < route.merge_s:
                    continue
                k = int(np.clip(np.searchsorted(route.offsets, s, side="right") - 1, 0, len(route.lanes) - 1))
                xy = self.network.get_lane(route.lanes[k]).position(s - route.offsets[k], 0.0)
                if all(np.hypot(*(xy - v.position)) >= self.rules.initial_spacing for v in self.vehicles):
                    break
            else:
                later.append(_Departure(d.vehicle_id, 0.0, d.route_id, d.is_pirl, d.style, d.style_name, d.theta))
                continue
            kind = PIRL if d.is_pirl else BACKGROUND
            v = self.add_vehicle(kind, d.vehicle_id, d.route_id, s, 0.0, style=d.style, style_name=d.style_name,
                                 theta=d.theta)
            v.speed = self._depart_speed(d.route_id, s, kind, getattr(v, "speed_factor", 1.0))
            placed += 1
        self._pending = later + rest
        return placed

    def shift_departures(self, dt: float) -> None:
        """Move every pending departure ``dt`` [s] earlier (not before 0)."""
        self._pending = [_Departure(d.vehicle_id, max(0.0, d.depart - dt), d.route_id, d.is_pirl, d.style,
                                    d.style_name, d.theta) for d in self._pending]

    @property
    def n_pending(self) -> int:
        """Planned vehicles not yet on the road."""
        return len(self._pending)

    def insert_due(self) -> int:
        """Insert pending vehicles whose departure time has come, where their route has room (no vehicle within the
        IDM's safe distance from its start, on its first lane or, where that is short, the next ones; a blocked
        vehicle also holds back the later ones of its route's entry). Returns the number inserted."""
        inserted = 0
        blocked: set[str] = set()
        keep = []
        for i, d in enumerate(self._pending):
            if d.depart > self.time + 1e-9:  # departures are in time order: none of the rest is due
                keep += self._pending[i:]
                break
            route = self.routes[d.route_id]
            first = route.lanes[0][:2]
            if first in blocked:
                keep.append(d)
                continue
            speed = self._depart_speed(d.route_id, 0.0, PIRL if d.is_pirl else BACKGROUND)
            need = IDM_S0 + speed * IDM_T + IDMVehicle.LENGTH
            free = all(not (isinstance(v, RouteFollowing) and v.lane_index[:2] in route.position_of
                            and route.offsets[route.position_of[v.lane_index[:2]]] + v.lane_s < need)
                       for v in self.vehicles)
            if not free:
                blocked.add(first)  # type: ignore[arg-type]
                keep.append(d)
                continue
            kind = PIRL if d.is_pirl else BACKGROUND
            v = self.add_vehicle(kind, d.vehicle_id, d.route_id, 0.0, speed, style=d.style,
                                 style_name=d.style_name, theta=d.theta)
            v.speed = self._depart_speed(d.route_id, 0.0, kind, getattr(v, "speed_factor", 1.0))
            inserted += 1
        self._pending = keep
        return inserted

    # -- one step -----------------------------------------------------------------------------------

    @staticmethod
    def _occupancy(others: list) -> _Occupancy:
        """Where every vehicle is, for the leader searches of one step (see :class:`_Occupancy`)."""
        on_lane: dict[tuple[str, str], list] = {}
        for o in others:
            s_lane = o.lane_s if isinstance(o, RouteFollowing) else o.lane.local_coordinates(o.position)[0]
            on_lane.setdefault(o.lane_index[:2], []).append((s_lane, o))
        for rows in on_lane.values():
            rows.sort(key=lambda row: row[0])
        merging = [o for o in others if isinstance(o, RouteFollowing) and o.committed and o.entering]
        return _Occupancy(on_lane, merging)

    def _leader(self, v: RouteFollowing, others: list, occupancy: _Occupancy | None = None
                ) -> tuple[float | None, float]:
        """(bumper gap [m], speed [m/s]) of the nearest vehicle ahead on ``v``'s route, None if none within
        ``lookahead``; committed entering vehicles count at their distance to their merge node, ring vehicles just
        past the node where ``v`` leaves the ring, and vehicles slower than 1 m/s on another lane leaving a node
        ahead whose rear is still over the node.

        ``occupancy`` (:meth:`_occupancy` of ``others``) saves building it again for every vehicle."""
        on_lane, merging = occupancy if occupancy is not None else self._occupancy(others)
        route = v.route_lanes
        k, s = v.route_pos, v.route_s
        best_d, best = self.rules.lookahead, None
        for m in range(k, len(route.lanes)):  # lanes of the route from v's own on, vehicles by lane coordinate
            base = route.offsets[m] - s
            for s_lane, o in on_lane.get(route.lanes[m][:2], ()):
                d = base + s_lane
                if o is not v and 0.0 < d:
                    if d < best_d:
                        best_d, best = d, o
                    break  # the nearest one ahead on this lane
        for m in range(k, len(route.lanes) - 1):  # a diverge ahead: ring vehicles just past its node are in the way
            a, b = route.lanes[m][:2]
            after = self._ring_after.get(b)
            if (a, b) not in self.ring or after is None or after == route.lanes[m + 1][:2]:
                continue
            for s_lane, o in on_lane.get(after, ()):
                if o is v or s_lane - 0.5 * o.LENGTH > v.LENGTH:  # type: ignore[attr-defined]
                    continue  # clear of the exit's first length
                d = route.offsets[m + 1] - s + s_lane
                if 0.0 < d < best_d:
                    best_d, best = d, o
            break
        for m in range(k, len(route.lanes) - 1):  # a node ahead: a vehicle standing on another lane leaving it,
            b, nxt = route.lanes[m][1], route.lanes[m + 1][:2]  # its rear still over the node, is in the way
            for after in self._leaving.get(b, ()):
                if after == nxt:
                    continue
                for s_lane, o in on_lane.get(after, ()):
                    if o is v or o.speed >= _IN_THE_WAY or s_lane - 0.5 * o.LENGTH > 0.5 * v.WIDTH:  # type: ignore[attr-defined]
                        continue
                    d = route.offsets[m + 1] - s + s_lane
                    if 0.0 < d < best_d:
                        best_d, best = d, o
        for o in merging:
            if o is v:
                continue
            m = route.start_pos.get(o.route_lanes.merge_node)  # type: ignore[assignment]
            if m is not None and m > k:  # the node is ahead of v on its route
                d = route.offsets[m] - o.merge_distance - s
                if 0.0 < d < best_d:
                    best_d, best = d, o
        if best is None:
            return None, 0.0
        return best_d - 0.5 * (v.LENGTH + best.LENGTH), best.speed  # type: ignore[attr-defined]

    def _must_yield(self, v: RouteFollowing, others: list, headway: float) -> bool:
        """Gap acceptance at ``v``'s merge node with ``headway`` [s] (see the module docstring); updates
        ``v.committed``."""
        rules = self.rules
        d = v.merge_distance
        if v.committed or not v.entering or d > rules.yield_distance:
            return False
        node = v.route_lanes.merge_node
        upstream = self._upstream[node]
        t_clear = _time_to_cover(d + v.LENGTH, v.speed, rules.entry_acceleration)  # type: ignore[attr-defined]
        conflict = False
        for o in others:
            if o is v or o.crashed:
                continue
            key = o.lane_index[:2]
            if key not in upstream:
                continue
            if isinstance(o, RouteFollowing):
                p = o.route_lanes.start_pos.get(node)
                if p is None or p <= o.route_pos:
                    continue  # it leaves the ring before the node
                s_lane = o.lane_s
            else:
                s_lane = o.lane.local_coordinates(o.position)[0]
            d_o = upstream[key] - s_lane
            if d_o > rules.yield_lookback:
                continue
            if d_o < rules.yield_min_distance or d_o / max(o.speed, 0.1) < t_clear + headway:
                conflict = True
                break
        if not conflict:  # no room on the ring: a vehicle standing just past the node
            after = v.route_lanes.lanes[v.route_lanes.entry_lane + 1][:2]
            conflict = any(o is not v and o.lane_index[:2] == after and o.speed < _IN_THE_WAY
                           and o.lane.local_coordinates(o.position)[0] - 0.5 * o.LENGTH < v.LENGTH + rules.stop_margin  # type: ignore[attr-defined]
                           for o in others)
        stop_gap = d - 0.5 * v.LENGTH - self._stop_offset_of(v.route_lanes) - rules.stop_margin  # type: ignore[attr-defined]
        to_line = stop_gap + rules.stop_margin  # [m] front bumper to the stop line
        if stop_gap > 0.0:
            can_stop = v.speed ** 2 / (2.0 * stop_gap) <= rules.max_deceleration
        elif to_line > 0.0:  # creeping up to the line: it can still stop there
            can_stop = v.speed ** 2 / (2.0 * to_line) <= rules.max_deceleration
        else:
            can_stop = v.speed < _STANDSTILL  # waiting at the line
        if not can_stop:
            v.committed = True  # cannot stop before the node any more: go
            return False
        return conflict

    def _conflict_gap(self, v: RouteFollowing, others: list, headway: float,
                      leader: tuple[float | None, float] = (None, 0.0)) -> float | None:
        """[m] from ``v``'s front bumper to where it stops for a vehicle that goes first at a crossing or merge
        ahead (`~.crossings`), None when it need not stop.

        A vehicle on the other lane goes first when it is in the conflict zone (within half its length and the
        clearance of the point, or past it and not yet clear; when both are, the one nearer the point); otherwise,
        unless ``v`` is in the zone, when it is moving and its front cannot stop before the point any more, or when
        it has the right of way: at equal rank the
        one that arrives first (then the smaller vehicle id); against a lower rank the higher one (traffic
        leaving the ring), unless the lower-ranked vehicle accepted the gap: it arrives later than it clears the
        point plus ``headway`` [s], which it decides once and keeps until it stands before the point. ``v`` goes on when it is past the point or its
        front cannot stop before it. It also stops before a zone it could not leave: when its ``leader`` ((bumper gap
        [m], speed [m/s]) as `_leader` gives it) stands (slower than 1 m/s) less than a vehicle length beyond it.
        """
        rows = self._conflicts_ahead.get(v.route_lanes.route_id)
        if not rows:
            return None
        rules = self.rules
        best = None
        for s_c, c, side, rank in rows:
            d = s_c - v.route_s
            if d > rules.yield_distance:
                break  # rows are in route order: the rest are farther
            clear = self._clearance(c)
            if d < 0.0 or not self._can_stop(v.speed, d - 0.5 * v.LENGTH):  # type: ignore[attr-defined]
                continue  # it goes on
            t_v, zone_v = d / max(v.speed, 0.1), 0.5 * v.LENGTH + clear  # type: ignore[attr-defined]
            gap = d - 0.5 * v.LENGTH - clear  # type: ignore[attr-defined]
            if v.speed < _STANDSTILL:
                self._accepted.discard((v.vehicle_id, c))  # a gap taken is given up by stopping before the point
            if d >= zone_v and leader[0] is not None and leader[1] < 1.0 \
                    and leader[0] < 2.0 * clear + 1.5 * v.LENGTH + gap:  # type: ignore[attr-defined]
                best = gap if best is None else min(best, gap)  # keep the zone clear: no room beyond it
                continue
            t_clear = _time_to_cover(d + 0.5 * v.LENGTH + clear, v.speed, rules.entry_acceleration)  # type: ignore[attr-defined]
            for o in others:
                if o is v or not isinstance(o, RouteFollowing):
                    continue
                at = self._conflict_at[o.route_lanes.route_id].get(c)
                if at is None or at[1] == side:
                    continue
                d_o, rank_o = at[0] - o.route_s, at[2]
                zone_o = 0.5 * o.LENGTH + clear  # type: ignore[attr-defined]
                if d_o < -zone_o or d_o > rules.yield_lookback:
                    continue  # clear of the point, or far off
                t_o = d_o / max(o.speed, 0.1)
                if d_o < zone_o:  # in the zone: in the way, unless v is nearer the point in the zone too
                    first = d >= zone_v or (d_o, o.vehicle_id) < (d, v.vehicle_id)
                elif d < zone_v:  # v is in the zone and o is not: v goes on
                    first = False
                elif not self._can_stop(o.speed, d_o - 0.5 * o.LENGTH):  # type: ignore[attr-defined]
                    first = True
                elif rank_o == rank:
                    first = (o.vehicle_id, c) in self._accepted or (t_o, o.vehicle_id) < (t_v, v.vehicle_id)
                elif rank_o > rank:
                    first = (v.vehicle_id, c) not in self._accepted and t_o < t_clear + headway
                    if not first:
                        self._accepted.add((v.vehicle_id, c))  # the gap is taken: the other vehicle lets it go
                else:
                    first = (o.vehicle_id, c) in self._accepted
                if first:
                    best = gap if best is None else min(best, gap)
                    break
        return best

    def _can_stop(self, speed: float, gap: float) -> bool:
        """Whether a vehicle at ``speed`` [m/s] can stop within ``gap`` [m] braking at most ``max_deceleration``
        (a standing vehicle always can)."""
        if speed < _STANDSTILL:
            return True
        return gap > 0.0 and speed * speed / (2.0 * gap) <= self.rules.max_deceleration

    def _clearance(self, c: int) -> float:
        """[m] how far before conflict ``c``'s point a vehicle's front stops: a vehicle width and the stop clearance
        between the two lanes' centre lines at the conflict's angle, at most two vehicle lengths."""
        angle = math.radians(max(self.conflicts[c].angle, 1.0))
        need = IDMVehicle.WIDTH + self.rules.stop_clearance
        return min(need / math.sin(min(angle, 0.5 * math.pi)), 2.0 * IDMVehicle.LENGTH)

    def _limit(self, v: RouteFollowing, others: list, occupancy: _Occupancy, *, free_v0: float | None,
               delta: float, safety: bool = False) -> float:
        """IDM acceleration of ``v`` with its leader and, when yielding, the stop line; ``free_v0`` None:
        without the free-road term (the limit others impose on a PIRL driver); ``safety``: the safety layer of
        drivers who interact instead (`safe_acceleration` towards the leader and the stop line, reaction time
        ``safety_time_gap``, jam gap ``safety_jam_gap``, braking ``max_deceleration``)."""
        rules = self.rules
        gap, v_lead = self._leader(v, others, occupancy)
        v.yielding = self._must_yield(v, others, rules.safety_yield_headway if safety else rules.yield_headway)
        if v.committed and v.entering and v not in occupancy.merging:  # committed just now
            occupancy.merging.append(v)
        stop_gap = (v.merge_distance - 0.5 * v.LENGTH  # type: ignore[attr-defined]
                    - self._stop_offset_of(v.route_lanes)) if v.yielding else None
        crossing = self._conflict_gap(v, others, rules.safety_yield_headway if safety else rules.yield_headway,
                                      (gap, v_lead))
        if crossing is not None:
            stop_gap = crossing if stop_gap is None else min(stop_gap, crossing)
        if safety:
            a = math.inf
            T = rules.safety_time_gap
            if gap is not None:
                a = safe_acceleration(v.speed, gap - rules.safety_jam_gap, v_lead, tau=T, b=rules.max_deceleration,
                                      dt=STEP_LENGTH)
            if stop_gap is not None:
                a = min(a, safe_acceleration(v.speed, stop_gap - rules.stop_margin, 0.0, tau=T,
                                             b=rules.max_deceleration, dt=STEP_LENGTH))
            return a
        free = free_v0 is not None
        v0 = free_v0 if free else 1.0
        a = (idm_acceleration(v.speed, v0, gap, v_lead, delta=delta,  # type: ignore[arg-type]
                              free=free) if gap is not None
             else (idm_acceleration(v.speed, v0, delta=delta) if free else math.inf))  # type: ignore[arg-type]
        if stop_gap is not None:
            a = min(a, idm_acceleration(v.speed, v0, stop_gap, 0.0, delta=delta,  # type: ignore[arg-type]
                                        s0=self.rules.stop_margin,
                                        free=free))
        return a

    @staticmethod
    def _frame(vehicles) -> Frame:
        """Every vehicle on the road now (centres, headings, speeds, lengths), for drivers who interact."""
        n = len(vehicles)
        return Frame(tuple(str(getattr(v, "vehicle_id", f"_unnamed{k}")) for k, v in enumerate(vehicles)),
                     np.array([v.position for v in vehicles], dtype=float).reshape(n, 2),
                     np.array([v.heading for v in vehicles], dtype=float),
                     np.array([v.speed for v in vehicles], dtype=float),
                     np.array([v.LENGTH for v in vehicles], dtype=float),
                     tuple(v.route_lanes.route_id if isinstance(v, RouteFollowing) else "" for v in vehicles))

    def act(self) -> None:
        """Decide every vehicle's command, then let each act (steering, and the command)."""
        t0 = _time.perf_counter()
        others = self.vehicles
        pirl = [v for v in others if getattr(v, "kind", None) == PIRL and not v.crashed]
        frame = {"frame": self._frame(others)} if pirl and self.controller.needs_frame else {}
        commands = self.controller.commands(self.time, {
            v.vehicle_id: EgoObservation(EgoView(float(v.position[0]), float(v.position[1]), float(v.speed),
                                                 float(v.applied_acceleration))) for v in pirl}, **frame) if pirl else {}
        self._commands = {}
        tol = self.drivers.override_tol / STEP_LENGTH
        safety = self.controller.needs_frame  # drivers who interact: highway-env's rules only as a safety layer
        idm = [v for v in others if isinstance(v, RouteFollowing) and not v.crashed
               and (v.kind == BACKGROUND or (v.kind == PIRL and commands.get(v.vehicle_id) is None))]
        v_des = dict(zip(map(id, idm), self.v_des_many(idm)))  # one profile evaluation for all IDM drivers
        occupancy = self._occupancy(others)
        for v in others:
            if v.crashed or not isinstance(v, RouteFollowing) or v.kind == EGO:
                continue
            track = self.tracks[v.vehicle_id]
            if v.kind == BACKGROUND:
                a = self._limit(v, others, occupancy,
                                free_v0=v.speed_factor * v_des[id(v)], delta=v.DELTA)  # type: ignore[attr-defined]
            else:
                cmd = commands.get(v.vehicle_id)
                if cmd is None:  # handed back at a standstill: highway-env's IDM towards the desired speed
                    track.handed_back = True
                    a = self._limit(v, others, occupancy, free_v0=v_des[id(v)],
                                    delta=v.DELTA)  # type: ignore[attr-defined]
                else:
                    a_cmd = (cmd - v.speed) / STEP_LENGTH
                    a = min(a_cmd, self._limit(v, others, occupancy, free_v0=None, safety=safety,
                                               delta=v.DELTA))  # type: ignore[attr-defined]
                    self._commands[v.vehicle_id] = a_cmd
                    track.n_commands += 1
                    if a < a_cmd - tol:
                        track.n_overridden += 1
            v.command_acceleration = float(min(max(a, -IDM_ACC_LIMIT), IDM_ACC_LIMIT))
            if v.kind != BACKGROUND and cmd is not None and self.record:
                # (overridden, speed error [m/s] of the applied acceleration one frame on)
                self._pirl_commands[(track.track_id, self.frame)] = (
                    bool(a < a_cmd - tol), abs(a_cmd - v.command_acceleration) * STEP_LENGTH)
        for v in others:
            v.act()
        self.act_time_s += _time.perf_counter() - t0

    def _move_and_collide(self, dt: float) -> None:
        """highway-env's ``Road.step``: every vehicle steps, then every pair checks for a collision — here
        only the pairs that pass highway-env's own first test (``RoadObject._is_colliding``: centres closer
        than half the sum of the diagonals plus the first one's speed times ``dt``), found for all pairs at
        once with numpy; the other pairs' checks return without effect in highway-env, so the outcome is
        the same."""
        vehicles = self.vehicles
        for v in vehicles:
            v.step(dt)
        n = len(vehicles)
        if n > 1:
            pos = np.array([v.position for v in vehicles])
            reach = np.array([0.5 * v.diagonal for v in vehicles])
            speed = np.array([v.speed for v in vehicles])
            dist = np.sqrt(((pos[:, None, :] - pos[None, :, :]) ** 2).sum(axis=-1))
            near = dist <= reach[:, None] + reach[None, :] + speed[:, None] * dt
            for i, j in zip(*np.nonzero(np.triu(near, k=1))):
                vehicles[i].handle_collisions(vehicles[j], dt)
        for i, v in enumerate(vehicles):
            for other in self.objects:
                v.handle_collisions(other, dt)

    def step(self, dt: float) -> None:
        """Move every vehicle (highway-env), then remove, insert and record (see the module docstring)."""
        if abs(dt - STEP_LENGTH) > 1e-9:
            raise ValueError(f"the roundabout traffic steps by {STEP_LENGTH} s (the driver model's step), got {dt}")
        self._move_and_collide(dt)
        self.frame += 1
        self.time = round(self.frame * STEP_LENGTH, 9)
        delay = self.rules.crash_removal_delay
        keep = []
        for v in self.vehicles:  # type: ignore[has-type]
            track = self.tracks.get(getattr(v, "vehicle_id", None))  # type: ignore[arg-type]
            if track is None:
                keep.append(v)
                continue
            if v.crashed and not track.collided:
                track.collided, track.crash_time = True, self.time
            if v.kind != EGO and v.remaining <= 0.0:
                track.status = "arrived"
            elif (v.kind != EGO and track.collided and delay is not None
                  and self.time - track.crash_time >= delay - 1e-9):  # type: ignore[operator]
                track.status, track.removed_early = "vanished", True
            else:
                keep.append(v)
        self.vehicles = keep
        if self.record:
            for v in keep:
                track = self.tracks.get(getattr(v, "vehicle_id", None))  # type: ignore[arg-type]
                if track is None:
                    continue
                track.n_frames += 1
                c, s = math.cos(v.heading), math.sin(v.heading)
                self._rows.append((track.track_id, self.time, float(v.position[0]), float(v.position[1]),
                                   v.speed * c, v.speed * s, float(v.heading), v.LENGTH, v.WIDTH))
                if track.kind == PIRL:
                    self._pirl_frames.append((track.track_id, self.frame, bool(v.crashed)))
        self.insert_due()
        for callback in self.step_callbacks:
            callback(self)

    # -- results ------------------------------------------------------------------------------------

    @property
    def n_finished(self) -> int:
        """Vehicles that arrived or were removed."""
        return sum(t.status != "running" for t in self.tracks.values())

    def summary(self) -> pd.DataFrame:
        """One row per vehicle that was on the road: ids, kind, style, flags, status, frames."""
        return pd.DataFrame([{
            "track_id": t.track_id, "vehicle_id": t.vehicle_id, "route_id": t.route_id, "kind": t.kind,
            "style": t.style, "style_name": t.style_name, "n_frames": t.n_frames, "n_commands": t.n_commands,
            "n_overridden": t.n_overridden, "handed_back": t.handed_back, "collided": t.collided,
            "removed_early": t.removed_early, "status": t.status} for t in self.tracks.values()])

    def recording(self, info: Mapping[str, Any], lanes, successors) -> ScenarioRecording:
        """The run so far as a :class:`~pirl_sim.scenarios.recording.ScenarioRecording` (needs ``record``).

        Track ids in insertion order (1, 2, ...); vehicles never recorded (inserted in the last step) are
        left out. ``interacted`` (PIRL tracks): a command was overridden, the vehicle was handed back at a
        standstill, or it collided; the ego is a non-PIRL track with style name ``"ego"``. ``driver_steps``
        (PIRL tracks, every recorded frame): ``commanded`` where the driver's MPC gave the command at that
        frame (not when handed back at a standstill or crashed, nor at a track's last frame), ``overridden``
        where the traffic cut that command (the rule of ``interacted``), ``collided`` where the vehicle had
        crashed.
        """
        if not self.record:
            raise ValueError("this traffic was created with record=False")
        tracks = pd.DataFrame(self._rows, columns=["track_id", "time_s", "x", "y", "vx", "vy", "psi_rad",
                                                   "length", "width"])
        tracks.insert(2, "agent_type", "car")
        tracks = tracks[list(TRACK_COLUMNS)]
        recorded = [t for t in sorted(self.tracks.values(), key=lambda t: t.track_id) if t.n_frames > 0]
        renumber = {t.track_id: k + 1 for k, t in enumerate(recorded)}
        tracks["track_id"] = tracks["track_id"].map(renumber).astype(np.int64)
        pirl = np.array([t.kind == PIRL for t in recorded], dtype=bool)
        gt = ground_truth_table(
            agent_id=[t.vehicle_id for t in recorded], route_id=[t.route_id for t in recorded], is_pirl=pirl,
            style=[t.style for t in recorded], style_name=[t.style_name for t in recorded],
            theta=np.array([t.theta for t in recorded]),
            interacted=[t.n_overridden > 0 or t.handed_back or t.collided for t in recorded],
            collided=[t.collided for t in recorded], removed_early=[t.removed_early for t in recorded],
            overridden_fraction=[t.n_overridden / t.n_commands if t.n_commands else 0.0 for t in recorded],
            status=[t.status for t in recorded], n_frames=[t.n_frames for t in recorded])
        frames = pd.DataFrame(self._pirl_frames, columns=["track_id", "frame_id", "collided"])
        keys = list(zip(frames["track_id"], frames["frame_id"]))
        checked = [self._pirl_commands.get(k) for k in keys]
        steps = pd.DataFrame({
            "track_id": frames["track_id"].map(renumber).to_numpy(dtype=np.int64),
            "frame_id": frames["frame_id"].to_numpy(dtype=np.int64),
            "commanded": np.array([c is not None for c in checked], dtype=bool),
            "overridden": np.array([c is not None and c[0] for c in checked], dtype=bool),
            "collided": frames["collided"].to_numpy(dtype=bool),
            "command_error": np.array([np.nan if c is None else c[1] for c in checked], dtype=float),
        }, columns=list(DRIVER_STEP_COLUMNS))
        return ScenarioRecording(tracks, gt, lanes, successors, info, steps)
