"""``pirl_sim/Roundabout-v0``: drive through highway-env's roundabout among PIRL drivers of known weights.

The agent drives an ego vehicle along one route (default: south entry to north exit, as in highway-env's
roundabout) of highway-env's ``roundabout-generic-v0`` road (one ring lane, radius 20 m by default),
populated by :class:`~pirl_sim.scenarios.highway.traffic.RoundaboutTraffic`: PIRL drivers whose weights
and styles are drawn from the ``population`` (a :class:`~pirl_sim.scenarios.population_config.PopulationConfig`,
the same as the SUMO and highway-env scenarios'), each re-planning with its MPC every 0.1 s, plus
highway-env IDM background traffic; vehicles yield at entries, leave at exits, and crashed ones are
removed after ``rules.crash_removal_delay``. ``initial_vehicles`` of the plan are on the road at reset, the
others arrive at the entries at their planned departure times (counted from the reset). Every reset starts
the highway-env scenario's simulation (:meth:`~pirl_sim.scenarios.highway.scenario.HighwayAdapter.start`, the
ego added as an :class:`~pirl_sim.scenarios.contract.EgoSpec`), and every frame is one of its steps.

This is the default backend (``backend = "highway"``); ``config={"backend": "sumo"}`` makes the same task
on a SUMO roundabout (:mod:`pirl_sim.envs.sumo_roundabout`), with the same action, reward and info
(:mod:`pirl_sim.envs.common`).

Spaces
------
- **Action**: ``Box(-1, 1, (1,), float32)``, the ego's longitudinal acceleration, mapped linearly to
  ``[0, a_max]`` for positive and ``[a_min, 0]`` for negative values (``action.acceleration_range``,
  default ``[-4, 3]`` m/s^2, the driver model's bounds: 0 is 0 m/s^2). Steering is highway-env's lane
  following along the ego's route; the ego never reverses.
- **Observation**: any highway-env observation (``observation`` config, keys checked against the type's
  parameters); ``Kinematics`` is highway-env's computed without pandas (the same values,
  :class:`~pirl_sim.envs.observation.RoundaboutKinematics`). Default: ``Kinematics`` of the ego and its 7
  nearest vehicles (behind too), rows
  ``[presence, x, y, vx, vy, cos_h, sin_h]``; the ego's row absolute, the others relative to it; x, y
  scaled from [-100, 100] m and vx, vy from [-15, 15] m/s to [-1, 1] and clipped; empty rows are zero.
  Shape (8, 7), float32, in ``[-1, 1]`` (the space says so when every feature is bounded).
- **Style columns** (``style_observation``, :mod:`pirl_sim.envs.styles`): ``"none"`` (default) as above;
  ``"truth"`` or ``"inferred"`` append three columns to every ``Kinematics`` row, ``[style_known,
  speed_dev, acc_sq]``: the neighbour's normalised weights as ``clip(ln(theta) / 3, -1, 1)``, its ground
  truth (PIRL drivers only) or inferred online by the fitted learner ``style_learner`` from the vehicle's
  history as the ego observed it (last ``window`` frames of the learner, or ``style_history``); zeros and
  ``style_known = 0`` where unknown (the ego's row, empty rows, too short histories). Shape (8, 10).

Rewards (``reward``)
--------------------
Every step (``simulation_frequency / policy_frequency`` frames of 0.1 s; default 2 frames, 0.2 s):

- ``"exit"`` (reach the exit soon, safely, comfortably; every term in seconds, weights ``exit_reward``,
  defaults :data:`~pirl_sim.envs.common.EXIT_REWARD_DEFAULTS`)::

      r = progress * ds / v_max  -  time * T  -  comfort * T * mean_k[(a_k/3)^2 + (j_k/8)^2 + (v_k^2 kappa_k/3)^2]
          - near_miss * T_near  -  collision * crashed  +  arrival * arrived

  ``ds`` [m] the ego's progress along its route's reference path, ``v_max`` [m/s] the drivers' speed cap
  (13.9), ``T`` [s] the step, ``a_k`` [m/s^2], ``j_k`` [m/s^3] and ``v_k^2 kappa_k`` [m/s^2] (lateral) its
  acceleration, jerk and lateral acceleration in each frame, ``T_near`` [s] the step's time with another
  vehicle nearer than ``near_miss_gap`` (2 m; centre distance minus 5 m, the vehicles' length). Defaults:
  progress 1, time 1 (so driving at v_max costs nothing and every second slower costs up to 1), comfort
  0.5, near_miss 2, collision 50 s (more than the 40 s episode a crash could cut short), arrival 10 s.
  The return is about ``(route left)/v_max - (time to exit) - costs + 10`` for an arriving episode, and a
  crash is always worse than waiting until the time limit.

- ``"task"``: ``progress_reward * ds / (v_max T) + comfort_reward * mean_k((a_k/3)^2 + (j_k/8)^2)
  + collision_reward * crashed + arrival_reward * arrived`` with ``ds`` [m] the ego's progress along its
  route, ``T`` [s] the step, ``a_k`` [m/s^2] and ``j_k`` [m/s^3] its acceleration and jerk in each frame.
- ``"theta"``: ``-(theta . f) T + collision_reward * crashed + arrival_reward * arrived``, with ``f`` the
  driver model's features (speed_dev, acc_sq, jerk_sq) of the ego's frames in the step (means, as the
  paper's) along its route's reference path and ``theta`` the normalised weights ``reward_theta``
  (``{"speed_dev": ..., "acc_sq": ...}``, ``jerk_sq`` = 1): the return is minus the cost that a PIRL
  driver of that style minimises, so an agent can be trained to drive in a given style. A crash also
  costs what the stopped vehicle would have cost until the time limit, ``theta_speed_dev v_des^2
  (duration - t)`` (``crash_cost_to_go``): otherwise ending the episode by a crash would save the agent
  the rest of its cost, and a cost-only reward would teach it to crash.

``info["rewards"]`` holds every term of all three, and the ``"exit"`` reward's comfort term split into its parts
(``comfort_acc_time``, ``comfort_jerk_time``, ``comfort_lateral_time`` [s]: the step's mean of each squared ratio
times ``T``; they sum to ``comfort_time``). The episode terminates when the ego crashes or reaches the
end of its route, and is truncated after ``duration`` [s].

Info
----
``speed`` [m/s], ``crashed``, ``arrived``, ``progress`` [m] (route coordinate), ``features`` (3,) of the
step, ``rewards``, ``n_vehicles`` on the road, and, aligned with the observation's rows 1..V-1 (the
neighbours, in the order the ``Kinematics`` observation lists them, also with ``order = "shuffled"``):
``neighbour_ids`` (vehicle ids, ``""`` for empty rows), ``neighbour_is_pirl`` (bool), ``neighbour_styles``
(style index, -1 for background traffic, -2 for empty rows), ``neighbour_theta`` (V-1, 3) normalised
weights (0 where not a PIRL driver: background drivers' weights are unknown); ``style_names`` and
``feature_names`` name the indices.

Configuration
-------------
``gymnasium.make("pirl_sim/Roundabout-v0", config={...})`` or ``env.reset(options={"config": {...}})``.
Unknown keys raise ``ValueError`` listing the valid ones (:meth:`PirlRoundaboutEnv.default_config`), as do
bad values; highway-env itself ignores unknown keys silently. ``simulation_frequency`` is fixed at 10 Hz
(the driver model's and the recordings' step). Seeded resets are deterministic: ``reset(seed=s)`` draws the
population plan, placement and noise from ``s``.
"""

from __future__ import annotations

import copy
import functools
import inspect
from collections.abc import Mapping
from contextlib import ExitStack

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.action import ActionType
from highway_env.envs.common import observation as _obs

from pirl_sim.envs.common import (
    EGO_ID,
    REWARDS,
    EgoReward,
    StepGuard,
    acceleration,
    check_action,
    clearance,
    check_common,
    check_kinematics,
    common_defaults,
    neighbour_info,
    reward_weights,
)
from pirl_sim.envs.observation import RoundaboutKinematics, StyleKinematics
from pirl_sim.envs.styles import StyleObserver, check_style_config
from pirl_sim.scenarios.contract import EgoSpec
from pirl_sim.scenarios.highway.network import RoundaboutGeometry, build_network, route_catalogue
from pirl_sim.scenarios.highway.scenario import (
    EGO_END_MARGIN,
    ROUTE_IDS,
    HighwayAdapter,
    HighwayScenarioConfig,
    build_routes,
    drivers_from_dict,
    rules_from_dict,
)
from pirl_sim.scenarios.highway.traffic import STEP_LENGTH, DriverConfig, RoundaboutTraffic, TrafficRules
from pirl_sim.scenarios.highway.vehicles import EgoVehicle
from pirl_sim.scenarios.population_config import FEATURE_NAMES
from pirl_sim.validation import check_keys, number

__all__ = ["PirlRoundaboutEnv", "LongitudinalAction", "REWARDS", "EGO_ID"]

_EGO_COLOR = (50, 200, 0)

#: highway-env's observation types by config name (``observation_factory``'s list)
_OBSERVATIONS = {
    "TimeToCollision": _obs.TimeToCollisionObservation,
    "Kinematics": _obs.KinematicObservation,
    "OccupancyGrid": _obs.OccupancyGridObservation,
    "KinematicsGoal": _obs.KinematicsGoalObservation,
    "GrayscaleObservation": _obs.GrayscaleObservation,
    "AttributesObservation": _obs.AttributesObservation,
    "TupleObservation": _obs.TupleObservation,
    "LidarObservation": _obs.LidarObservation,
    "ExitObservation": _obs.ExitObservation,
}
#: Kinematics features highway-env computes (``Vehicle.to_dict``)
_KINEMATICS_FEATURES = ("presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h", "cos_d", "sin_d", "long_off",
                        "lat_off", "ang_off")
#: Kinematics features that stay in [-1, 1] after normalisation and clipping
_BOUNDED_FEATURES = {"presence", "cos_h", "sin_h", "cos_d", "sin_d"}


@functools.lru_cache(maxsize=32)
def _route_length(radius: float, route_id: str) -> float:
    """Length [m] of route ``route_id`` of the roundabout of ring radius ``radius`` [m]."""
    return route_catalogue(build_network(RoundaboutGeometry(radius)))[route_id].length


def _routes_for(radius: float, smoothing: float, speed_smoothing: float):
    """(network, route catalogue, RouteSet) the env's simulations run on for a ring radius [m] and path
    smoothing [m] (the highway-env adapter's per-process cache)."""
    drivers = DriverConfig(smoothing=smoothing, speed_smoothing=speed_smoothing)
    return build_routes(HighwayScenarioConfig(RoundaboutGeometry(radius), drivers=drivers), cache=True)


class LongitudinalAction(ActionType):
    """A continuous longitudinal action: ``Box(-1, 1, (1,))`` -> acceleration [m/s^2] of the ego.

    Positive values scale ``a_max``, negative ones ``-a_min`` (so 0 means no acceleration); the ego's
    steering is lane following along its route (:class:`~pirl_sim.scenarios.highway.vehicles.EgoVehicle`).
    """

    TYPE = "LongitudinalAcceleration"

    def __init__(self, env, acceleration_range=(-4.0, 3.0), **kwargs) -> None:
        super().__init__(env)
        lo, hi = (float(a) for a in acceleration_range)
        self.acceleration_range = (lo, hi)
        self.last_action = np.zeros(1, dtype=np.float32)

    def space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

    @property
    def vehicle_class(self):
        return EgoVehicle

    def acceleration(self, action) -> float:
        """The acceleration [m/s^2] of an action (checked and clipped to [-1, 1] by
        :func:`~pirl_sim.envs.common.check_action` first)."""
        return acceleration(action, self.acceleration_range)

    def act(self, action) -> None:
        self.controlled_vehicle.command_acceleration = self.acceleration(action)
        self.last_action = np.array([check_action(action)], dtype=np.float32)


class PirlRoundaboutEnv(AbstractEnv):
    """highway-env roundabout populated by PIRL drivers of known, diverse weights (see the module docstring).

    Parameters
    ----------
    config : dict, optional
        Overrides of :meth:`default_config` (unknown keys raise ``ValueError``).
    render_mode : {"human", "rgb_array"}, optional
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(self, config: dict | None = None, render_mode: str | None = None) -> None:
        self._stack = ExitStack()  # holds the running simulation (the highway-env adapter's)
        self._sim = None
        super().__init__(config=config, render_mode=render_mode)

    @classmethod
    def default_config(cls) -> dict:
        """Every configuration key with its default (the valid keys)."""
        config = super().default_config()
        del config["other_vehicles_type"]  # the traffic's vehicle classes are fixed
        config.update({
            "backend": "highway",  # "sumo": the same task on SUMO (pirl_sim.envs.sumo_roundabout)
            **common_defaults(),
            "simulation_frequency": 10,  # [Hz] fixed: the driver model's step
            "roundabout_radius": 20.0,  # [m]
            "initial_vehicles": 8,
            "drivers": DriverConfig(),
            "rules": TrafficRules(),
            "ego_start": 40.0,  # [m] route coordinate at reset
            "screen_width": 600,  # [px]
            "screen_height": 600,  # [px]
            "centering_position": [0.5, 0.6],
        })
        return config

    # -- configuration ------------------------------------------------------------------------------

    def configure(self, config: dict | None) -> None:
        """Check ``config`` (keys and values) and merge it into the current configuration."""
        if config:
            if not isinstance(config, Mapping):
                raise ValueError(f"config must be a mapping, got {type(config).__name__}")
            valid = tuple(self.default_config())
            check_keys("config", config, valid)
            merged = dict(self.config)  # type: ignore[has-type]
            merged.update(copy.deepcopy(dict(config)))
            self._validate(merged)
            self.config = merged
        super().configure(None)

    @staticmethod
    def _validate(c: dict) -> None:
        """Normalise and check a full configuration in place (raises ValueError)."""
        if c["backend"] != "highway":
            raise ValueError(f"backend must be 'highway' for this env, got {c['backend']!r} (make the env with "
                             "config={'backend': 'sumo'} for SUMO)")
        if c["simulation_frequency"] != 10:
            raise ValueError(f"simulation_frequency must be 10 Hz (the driver model's step of {STEP_LENGTH} s), "
                             f"got {c['simulation_frequency']!r}")
        check_common(c)
        obs = c["observation"]
        if not isinstance(obs, Mapping) or obs.get("type") not in _OBSERVATIONS:
            raise ValueError(f"observation must be a mapping with a type in {sorted(_OBSERVATIONS)}, got {obs!r}")
        params = [p for p in inspect.signature(_OBSERVATIONS[obs["type"]].__init__).parameters
                  if p not in ("self", "env", "kwargs")]
        check_keys(f"observation ({obs['type']})", obs, ("type", *params))
        if obs["type"] == "Kinematics":
            check_kinematics(obs, _KINEMATICS_FEATURES, "observation (Kinematics)")
        check_style_config(c, ROUTE_IDS)
        if c["style_observation"] != "none" and obs["type"] != "Kinematics":
            raise ValueError(f"style_observation {c['style_observation']!r} adds columns to the 'Kinematics' "
                             f"observation; got observation type {obs['type']!r}")
        c["roundabout_radius"] = RoundaboutGeometry(c["roundabout_radius"]).radius
        if isinstance(c["drivers"], Mapping):
            c["drivers"] = drivers_from_dict(c["drivers"], source="config drivers")
        elif not isinstance(c["drivers"], DriverConfig):
            raise ValueError(f"drivers must be a DriverConfig or a mapping, got {type(c['drivers']).__name__}")
        if isinstance(c["rules"], Mapping):
            c["rules"] = rules_from_dict(c["rules"], source="config rules")
        elif not isinstance(c["rules"], TrafficRules):
            raise ValueError(f"rules must be a TrafficRules or a mapping, got {type(c['rules']).__name__}")
        n0 = c["initial_vehicles"]
        if isinstance(n0, bool) or not isinstance(n0, (int, np.integer)) or n0 < 0:
            raise ValueError(f"initial_vehicles must be an integer >= 0, got {n0!r}")
        if n0 > c["population"].n_vehicles:
            raise ValueError(f"initial_vehicles = {n0} exceeds the population's n_vehicles = "
                             f"{c['population'].n_vehicles}")
        if c["ego_route"] not in ROUTE_IDS:
            raise ValueError(f"ego_route must be one of {', '.join(ROUTE_IDS)}, got {c['ego_route']!r}")
        number("ego_start", c["ego_start"], low=0.0)
        length = _route_length(c["roundabout_radius"], c["ego_route"])
        if c["ego_start"] > length - EGO_END_MARGIN:
            raise ValueError(f"ego_start must be in [0, {length - EGO_END_MARGIN:.1f}] m on route {c['ego_route']!r} "
                             f"(its length {length:.1f} m less {EGO_END_MARGIN:g} m), got {c['ego_start']!r}")

    @property
    def reward_weights(self) -> np.ndarray:
        """Normalised weights (3,) of the ``"theta"`` reward over :data:`FEATURE_NAMES`."""
        return reward_weights(self.config["reward_theta"])

    def define_spaces(self) -> None:
        obs = dict(self.config["observation"])
        c = self.config
        if (getattr(self, "_style", None) is None
                or self._style.mode != c["style_observation"]):  # type: ignore[has-type]
            self._style = StyleObserver(c["style_observation"], c["style_learner"], c["style_history"])
        self._style_width = self._style.width
        if obs["type"] == "Kinematics":  # highway-env's, pandas-free, remembering its rows (for info)
            cls = StyleKinematics if self._style_width else RoundaboutKinematics
            self.observation_type = cls(self, **{k: v for k, v in obs.items() if k != "type"})
        else:
            self.observation_type = _obs.observation_factory(self, obs)
        self.action_type = LongitudinalAction(self, **{k: v for k, v in self.config["action"].items()
                                                       if k != "type"})
        self.observation_space = self.observation_type.space()
        self.action_space = self.action_type.space()
        if isinstance(self.observation_type, _obs.KinematicObservation) and self.observation_type.normalize \
                and self.observation_type.clip:
            ranged = set(self.observation_type.features_range or {})
            if all(f in _BOUNDED_FEATURES or f in ranged for f in self.observation_type.features):
                self.observation_space = spaces.Box(-1.0, 1.0, shape=self.observation_space.shape,
                                                    dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Reset (see :class:`gymnasium.Env`); ``options`` may hold ``"config"`` (checked as at construction)."""
        if options is not None:
            if not isinstance(options, Mapping):
                raise ValueError(f"options must be a mapping, got {type(options).__name__}")
            check_keys("options", options, ("config",))
        self._guard = StepGuard()
        return super().reset(seed=seed, options=options)

    def step(self, action):
        """One agent step (see :class:`gymnasium.Env`). The action is checked first
        (:func:`~pirl_sim.envs.common.check_action`: ``None``, NaN or a wrong shape raise before anything moves);
        stepping on after the episode ended warns as gymnasium's envs do."""
        check_action(action)
        guard = getattr(self, "_guard", None) or StepGuard()
        self._guard = guard
        guard.before_step()
        obs, reward, terminated, truncated, info = super().step(action)
        guard.after_step(terminated, truncated)
        return obs, reward, terminated, truncated, info

    # -- scene ----------------------------------------------------------------------------------------

    def _reset(self) -> None:
        c = self.config
        scenario = HighwayScenarioConfig(RoundaboutGeometry(c["roundabout_radius"]), population=c["population"],
                                         drivers=c["drivers"], rules=c["rules"])
        adapter = HighwayAdapter()
        seed = int(self.np_random.integers(2**31))
        plan = adapter.plan(scenario, seed)
        ego = EgoSpec(c["ego_route"], float(c["ego_speed"]), route_s=float(c["ego_start"]), vehicle_id=EGO_ID)
        self._stack.close()
        self._sim = sim = self._stack.enter_context(adapter.start(  # type: ignore[assignment]
            scenario, seed, plan, ego=ego, cache_network=True, initial_vehicles=int(c["initial_vehicles"]),
            np_random=self.np_random, record=c["record_tracks"], record_history=c["show_trajectories"]))
        traffic = self.road = sim.traffic
        self.vehicle = sim.ego_vehicle
        self.vehicle.color = _EGO_COLOR  # type: ignore[attr-defined]
        self._ego_cost = EgoReward(c, sim.routes, traffic.profile, c["ego_route"],
                                   self.vehicle.position)  # type: ignore[attr-defined]
        traffic.step_callbacks.append(self._log_ego)
        self._style = StyleObserver(c["style_observation"], c["style_learner"], c["style_history"])
        if self._style.mode == "inferred":
            traffic.step_callbacks.append(self._log_others)

    def _log_others(self, traffic: RoundaboutTraffic) -> None:
        """Every other route-following vehicle's frame, for the online inference of its weights."""
        self._style.record([(v.vehicle_id, v.route_lanes.route_id, float(v.position[0]), float(v.position[1]),
                             float(v.speed)) for v in traffic.vehicles
                            if v is not self.vehicle and getattr(v, "route_lanes", None) is not None])

    def _log_ego(self, traffic: RoundaboutTraffic) -> None:
        ego = self.vehicle
        others = [v.position for v in traffic.vehicles if v is not ego]
        self._ego_cost.log_frame(ego.position, ego.speed, ego.applied_acceleration,  # type: ignore[attr-defined]
                                 clearance(ego.position, others))  # type: ignore[attr-defined]

    # -- stepping -------------------------------------------------------------------------------------

    def _simulate(self, action=None) -> None:
        """highway-env's frame loop (the action, then one frame, rendering in between), each frame one step of
        the simulation."""
        start = self.vehicle.route_s  # type: ignore[attr-defined]
        self._ego_cost.begin_step()
        frames = int(self.config["simulation_frequency"] // self.config["policy_frequency"])
        for frame in range(frames):
            if action is not None and not self.config["manual_control"] and self.steps % frames == 0:
                self.action_type.act(action)
            self._sim.step()  # type: ignore[attr-defined]
            self.steps += 1
            if frame < frames - 1:  # the last frame renders through render() as usual
                self._automatic_rendering()
        self.enable_auto_render = False
        self._ego_cost.step_terms(progress=self.vehicle.route_s - start,  # type: ignore[attr-defined]
                                  crashed=self.vehicle.crashed,  # type: ignore[attr-defined]
                                arrived=self._arrived, time=self.time)

    @property
    def _arrived(self) -> bool:
        return self.vehicle is not None and self.vehicle.remaining <= 0.0

    def _rewards(self, action) -> dict[str, float]:
        return dict(self._ego_cost.terms)

    def _reward(self, action) -> float:
        return self._ego_cost.reward()

    def _is_terminated(self) -> bool:
        return bool(self.vehicle.crashed or self._arrived)  # type: ignore[attr-defined]

    def _is_truncated(self) -> bool:
        return bool(self.time >= self.config["duration"] - 1e-9)

    def _neighbours(self) -> list:
        """The vehicles of the observation's rows 1..V-1 (highway-env's Kinematics order)."""
        o = self.observation_type
        if isinstance(o, RoundaboutKinematics):
            return list(o.rows)
        if isinstance(o, _obs.KinematicObservation):
            count, see_behind, sort, only = o.vehicles_count, o.see_behind, o.order == "sorted", \
                not o.include_obstacles
        else:
            count, see_behind, sort, only = 8, True, True, True
        close = self.road.close_objects_to(self.vehicle, self.PERCEPTION_DISTANCE, count=count - 1,
                                           see_behind=see_behind, sort=sort, vehicles_only=only)
        rows = close[-count + 1:] if count > 1 else []
        return list(rows) + [None] * (count - 1 - len(rows))

    def _info(self, obs, action=None) -> dict:
        return {
            "speed": float(self.vehicle.speed),  # type: ignore[attr-defined]
            "time": float(self.time),
            "crashed": bool(self.vehicle.crashed),  # type: ignore[attr-defined]
            "arrived": bool(self._arrived),
            "progress": float(self.vehicle.route_s),  # type: ignore[attr-defined]
            "features": self._ego_cost.features.copy(),
            "rewards": self._rewards(action),
            "n_vehicles": len(self.road.vehicles),
            **neighbour_info(self._neighbours()),
            "style_names": self.config["population"].style_names,
            "feature_names": FEATURE_NAMES,
        }

    # -- recording ------------------------------------------------------------------------------------

    def recording(self):
        """The episode so far as a :class:`~pirl_sim.scenarios.recording.ScenarioRecording` (needs
        ``record_tracks=True``; the ego is a track with ``agent_id`` "ego" and style name "ego")."""
        info = {"simulator": "highway-env (pirl_sim/Roundabout-v0)", "ego_route": self.config["ego_route"],
                "step_length_s": STEP_LENGTH}
        return self._sim.recording(info)

    def close(self) -> None:
        """Close the viewer and leave the simulation."""
        self._stack.close()
        super().close()
