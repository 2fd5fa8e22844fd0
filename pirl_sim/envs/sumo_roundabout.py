"""``pirl_sim/Roundabout-v0`` with ``backend="sumo"``: the same task on a SUMO roundabout (libsumo).

:class:`PirlRoundaboutSumoEnv`: the ego drives its route of the SUMO scenario's roundabout among the SUMO
scenario's traffic (the population plan of :func:`~pirl_sim.scenarios.planning.plan_population`, PIRL drivers
re-planning every 0.1 s, SUMO's Krauss drivers as background), the scenario's own simulation stepped by the env.
It shares with the highway-env backend the action, the reward (:class:`~pirl_sim.envs.common.EgoReward`), the
info (:func:`~pirl_sim.envs.common.neighbour_info`) and the ``Kinematics`` rows
(:func:`~pirl_sim.envs.observation.kinematics_rows`). libsumo holds one simulation per process: a second env of
this backend in one process needs ``sumo_binding = "traci"``.

What differs from the highway-env backend (start, ego, observation, recording) is in the documentation's
"The gymnasium environment" page.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from contextlib import ExitStack
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from pirl_sim.scenarios.contract import STEP as CONTRACT_STEP, EgoSpec
from pirl_sim.scenarios.drivers import PirlDrivers, RouteSetProfile
from pirl_sim.scenarios.population_config import FEATURE_NAMES
from pirl_sim.scenarios.sumo.network import RoundaboutSpec, routes
from pirl_sim.scenarios.sumo.runner import BACKENDS
from pirl_sim.scenarios.sumo.scenario import (
    DEFAULT_NETWORK,
    DriverConfig,
    SumoAdapter,
    SumoScenarioConfig,
    scenario_from_dict,
)
from pirl_sim.validation import check_keys, number

from .common import (
    EGO_ID,
    EgoReward,
    StepGuard,
    acceleration,
    check_common,
    clearance,
    check_kinematics,
    common_defaults,
    neighbour_info,
)
from .observation import DIRECT_FEATURES, kinematics_rows, shuffle_rows, style_space, with_style_columns
from .styles import StyleObserver, check_style_config

__all__ = ["PirlRoundaboutSumoEnv"]

STEP = CONTRACT_STEP  # [s] SUMO step = driver-model step (the simulator contract's)
PERCEPTION_DISTANCE = 200.0  # [m] highway-env's AbstractEnv.PERCEPTION_DISTANCE (5 x Vehicle.MAX_SPEED)
_MAX_WAIT = 60.0  # [s] longest wait for the ego's insertion after the warm-up
_KINEMATICS_KEYS = ("type", "features", "vehicles_count", "features_range", "absolute", "normalize", "clip",
                    "see_behind", "order")
_BOUNDED = {"presence", "cos_h", "sin_h"}
_EGO_COLOR = (0.85, 0.1, 0.1)  # RGB of the ego in a rendered frame
_BACKGROUND_COLOR = (0.6, 0.6, 0.6)  # RGB of background (non-PIRL) traffic


def _has_display() -> bool:
    import os
    import sys

    return sys.platform in ("win32", "darwin") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@dataclass(frozen=True)
class _Neighbour:  # what neighbour_info reads of a vehicle
    vehicle_id: str
    kind: str
    style: int
    theta: np.ndarray


class _Controller:
    """The run's batch controller: PIRL drivers' MPC, and the agent's acceleration for the ego."""

    def __init__(self, drivers: PirlDrivers) -> None:
        self.drivers = drivers
        self.acceleration = 0.0  # [m/s^2] the agent's current command
        self.ego = None  # the ego's last Observation (None before insertion and after it left)

    def __call__(self, time, vehicle_id, observation):  # the runner's single-vehicle form (unused)
        return self.commands(time, {vehicle_id: observation}).get(vehicle_id)

    def commands(self, time, observations):
        ego = observations.get(EGO_ID)
        self.ego = ego
        pirl = {k: o for k, o in observations.items() if k != EGO_ID}
        out = dict(self.drivers.commands(time, pirl)) if pirl else {}
        if ego is not None:
            out[EGO_ID] = max(ego.ego.speed + self.acceleration * STEP, 0.0)
        return out


class PirlRoundaboutSumoEnv(gym.Env):
    """``pirl_sim/Roundabout-v0`` on SUMO (see the module docstring and :mod:`pirl_sim.envs.roundabout`).

    Parameters
    ----------
    config : dict, optional
        Overrides of :meth:`default_config` (unknown keys raise ``ValueError`` listing the valid ones).
    render_mode : {"rgb_array", "human"}, optional
        ``"rgb_array"``: `render` returns the network's lanes with every vehicle as an oriented box
        (`pirl_sim.viz.LiveView`; the ego red, PIRL drivers coloured by style, background traffic grey),
        ``(screen_height, screen_width, 3)`` uint8; ``"human"``: the same frame shown in a matplotlib window
        after each reset and step (needs a display: without one, the instance's ``metadata`` lists
        ``"rgb_array"`` only).
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 10}

    def __init__(self, config: dict | None = None, render_mode: str | None = None) -> None:
        super().__init__()
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got "
                             f"{render_mode!r}")
        if not _has_display():  # this env's modes: those it can show here
            self.metadata = {**type(self).metadata, "render_modes": ["rgb_array"]}
        if render_mode == "human" and not _has_display():
            raise RuntimeError("render_mode='human' needs a display (DISPLAY or WAYLAND_DISPLAY is not set): use "
                               "render_mode='rgb_array' and save or show the frames yourself")
        self.render_mode = render_mode
        self._view = self._window = None  # the figure frames are drawn on, and the human mode's window
        self._frame = None  # the vehicles of the last observation: (ids, states)
        self.config = self.default_config()
        self.configure(config)
        self._sim = None  # the running simulation (the SUMO adapter's), None when closed
        self._last_sim = None  # kept after close() for recording()
        self._stack = ExitStack()
        self.time = 0.0
        self._define_spaces()

    @classmethod
    def default_config(cls) -> dict:
        """Every configuration key with its default (the valid keys)."""
        return {
            "backend": "sumo",
            **common_defaults(),
            "network": DEFAULT_NETWORK,
            "drivers": DriverConfig(),
            "warmup": 30.0,  # [s] of traffic before the ego enters
            "ego_speed_mode": 0,
            "sumo_binding": "libsumo",
            "screen_width": 600,  # [px] of a rendered frame (the highway-env backend's keys)
            "screen_height": 600,  # [px]
        }

    def configure(self, config: dict | None) -> None:
        """Check ``config`` (keys and values) and merge it into the current configuration."""
        if not config:
            return
        if not isinstance(config, Mapping):
            raise ValueError(f"config must be a mapping, got {type(config).__name__}")
        check_keys("config", config, tuple(self.default_config()))
        merged = dict(self.config)
        merged.update(copy.deepcopy(dict(config)))
        self._validate(merged)
        self.config = merged

    @staticmethod
    def _validate(c: dict) -> None:
        if c["backend"] != "sumo":
            raise ValueError(f"backend must be 'sumo' for this env, got {c['backend']!r}")
        check_common(c)
        obs = c["observation"]
        if not isinstance(obs, Mapping) or obs.get("type") != "Kinematics":
            raise ValueError(f"the sumo backend observes 'Kinematics' only, got {obs!r}")
        check_keys("observation (Kinematics, sumo backend)", obs, _KINEMATICS_KEYS)
        feats = obs.get("features", ())
        unknown = [f for f in feats if f not in DIRECT_FEATURES] if isinstance(feats, (list, tuple)) else []
        if unknown:
            raise ValueError(f"observation features {unknown} are not available with the sumo backend; "
                             f"valid: {', '.join(DIRECT_FEATURES)}")
        check_kinematics(obs, DIRECT_FEATURES, "observation")
        # network and drivers: objects, or tables as the SUMO scenario's config reads them
        tables = {k: c[k] for k in ("network", "drivers") if isinstance(c[k], Mapping)}
        if tables:
            c.update({k: getattr(scenario_from_dict(tables, source="config"), k) for k in tables})
        for name, cls in (("network", RoundaboutSpec), ("drivers", DriverConfig)):
            if not isinstance(c[name], cls):
                raise ValueError(f"{name} must be a {cls.__name__} or a table of its fields, got "
                                 f"{type(c[name]).__name__}")
        number("warmup", c["warmup"], low=0.0)
        catalogue = [rid for rid, _ in routes(c["network"])]
        if c["ego_route"] not in catalogue:
            raise ValueError(f"ego_route must be one of {', '.join(catalogue)}, got {c['ego_route']!r}")
        check_style_config(c, catalogue)
        m = c["ego_speed_mode"]
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 0 <= m < 128:
            raise ValueError(f"ego_speed_mode must be an integer bitset in [0, 127], got {m!r}")
        if c["sumo_binding"] not in BACKENDS:
            raise ValueError(f"sumo_binding must be one of {BACKENDS}, got {c['sumo_binding']!r}")
        for key in ("screen_width", "screen_height"):
            v = c[key]
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 16:
                raise ValueError(f"{key} must be a whole number of pixels >= 16, got {v!r}")

    # -- spaces -------------------------------------------------------------------------------------

    def _define_spaces(self) -> None:
        obs = self.config["observation"]
        self._features = list(obs.get("features", ["presence", "x", "y", "vx", "vy"]))
        self._count = int(obs.get("vehicles_count", 5))
        ranged = set(obs.get("features_range") or {})
        bounded = obs.get("normalize", True) and obs.get("clip", True) and all(
            f in _BOUNDED or f in ranged for f in self._features)
        lim = 1.0 if bounded else np.inf
        self.observation_space = spaces.Box(-lim, lim, shape=(self._count, len(self._features)), dtype=np.float32)
        c = self.config
        self._style = StyleObserver(c["style_observation"], c["style_learner"], c["style_history"])
        if self._style.width:
            self.observation_space = style_space(self.observation_space, self._style.width)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

    def _acceleration(self, action) -> float:
        return acceleration(action, self.config["action"].get("acceleration_range", (-4.0, 3.0)))

    # -- episodes -----------------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Reset (see :class:`gymnasium.Env`); ``options`` may hold ``"config"`` (checked as at construction)."""
        super().reset(seed=seed)
        if options is not None:
            if not isinstance(options, Mapping):
                raise ValueError(f"options must be a mapping, got {type(options).__name__}")
            check_keys("options", options, ("config",))
            if "config" in options:
                self.configure(options["config"])
                self._define_spaces()
        self._stop()
        c = self.config
        drv: DriverConfig = c["drivers"]
        scenario = SumoScenarioConfig(network=c["network"], population=c["population"], drivers=drv,
                                      collision_action="remove")
        adapter = SumoAdapter(c["sumo_binding"])
        plan_seed = int(self.np_random.integers(2**31))
        plan = adapter.plan(scenario, plan_seed)
        self._route_of = dict(zip(plan["vehicle_id"], plan["route_id"]))
        self._style = StyleObserver(c["style_observation"], c["style_learner"], c["style_history"])
        theta_cols = [f"theta_{f}" for f in FEATURE_NAMES]
        self._who = {r.vehicle_id: _Neighbour(r.vehicle_id, "pirl" if r.is_pirl else "background", int(r.style),
                                              np.array([getattr(r, t) for t in theta_cols]))
                     for r in plan.itertuples(index=False)}
        warmup = float(c["warmup"])
        ego = EgoSpec(c["ego_route"], float(c["ego_speed"]), depart=warmup, speed_mode=int(c["ego_speed_mode"]),
                      vehicle_id=EGO_ID)
        try:
            self._sim = self._stack.enter_context(adapter.start(  # type: ignore[assignment]
                scenario, plan_seed, plan, ego=ego,
                wrap_controller=_Controller, cache_network=True))  # type: ignore[arg-type]
        except RuntimeError as exc:
            if c["sumo_binding"] == "libsumo" and "one simulation per process" in str(exc):
                raise RuntimeError("libsumo runs one simulation per process and another SUMO run of this process "
                                   "holds it: close that env or run first, or make this env with "
                                   "sumo_binding='traci'") from exc
            raise
        self._last_sim, self._controller = self._sim, self._sim.batch_controller  # type: ignore[attr-defined]
        while self._controller.ego is None:  # the traffic's warm-up, then the ego's insertion
            self._sumo_step()
            if self._sim.run.time > warmup + _MAX_WAIT:  # type: ignore[attr-defined]
                self._stop()
                raise RuntimeError(f"the ego could not enter {c['ego_route']!r} within {_MAX_WAIT:.0f} s after the "
                                   "warm-up (its entry stayed blocked)")
        self._t0 = self._sim.run.time  # type: ignore[attr-defined]
        self.time = 0.0
        self._controller.acceleration = 0.0
        ego = self._controller.ego.ego
        paths = self._sim.routes  # type: ignore[attr-defined]
        self._ego_cost = EgoReward(c, paths, RouteSetProfile(paths, drv.a_lat, drv.v_max), c["ego_route"],
                                 (ego.x, ego.y))
        self._crashed = self._arrived = False
        self._guard = StepGuard()
        self._last_ego = ego
        obs = self._observe()
        if self.render_mode == "human":
            self.render()
        return obs, self._info()

    def step(self, action):
        if self._sim is None:
            raise RuntimeError("call reset() before step()")
        if self._crashed or self._arrived:
            raise RuntimeError("the episode has ended: call reset()")
        c = self.config
        a = self._acceleration(action)  # checked before anything moves
        self._guard.before_step()
        self._controller.acceleration = a
        ego = self._controller.ego.ego
        self._sim.run.set_command(EGO_ID, max(ego.speed + a * STEP, 0.0))  # the new action from this frame on
        s0 = self._ego_cost.s_path
        self._ego_cost.begin_step()
        for _ in range(round(10 / c["policy_frequency"])):
            self._sumo_step()
            if EGO_ID in self._sim.run.colliding:
                self._crashed = True
            now = self._controller.ego
            if now is None:  # left the network: at its route's end unless taken out by a crash
                self._arrived = not self._crashed
                break
            self._last_ego = now.ego
            if self._style.mode == "inferred":
                self._style.record([(vid, self._route_of[vid], st.x, st.y, st.speed) for vid, st in now.others.items()
                                    if vid in self._route_of])
            gap = clearance((now.ego.x, now.ego.y), [(st.x, st.y) for st in now.others.values()])
            self._ego_cost.log_frame((now.ego.x, now.ego.y), now.ego.speed, now.ego.accel, gap)
            if self._crashed:
                break
        self.time = round(self._sim.run.time - self._t0, 9)
        self._ego_cost.step_terms(progress=self._ego_cost.s_path - s0, crashed=self._crashed, arrived=self._arrived,
                                time=self.time)
        terminated = self._crashed or self._arrived
        truncated = not terminated and self.time >= c["duration"] - 1e-9
        self._guard.after_step(terminated, truncated)
        obs = self._observe()
        if self.render_mode == "human":
            self.render()
        return obs, self._ego_cost.reward(), terminated, truncated, self._info()

    def render(self):
        """The current frame (``render_mode="rgb_array"``: ``(screen_height, screen_width, 3)`` uint8; ``"human"``:
        shown in a window, None); None with a warning without a render mode.

        Raises
        ------
        RuntimeError
            Before the first `reset`.
        """
        if self.render_mode is None:
            gym.logger.warn("render() without a render mode: make the env with render_mode='rgb_array' or 'human'")
            return None
        if self._frame is None or self._last_sim is None:
            raise RuntimeError("call reset() before render()")
        from pirl_sim.viz import LiveView, distinct_colors, road_from_sumo

        net = self._last_sim.net
        if self._view is None or self._view_net is not net:
            size = (int(self.config["screen_width"]), int(self.config["screen_height"]))
            self._view, self._view_net = LiveView(road_from_sumo(net), size_px=size), net
        ids, states = self._frame
        styles = [self._who[v].style if v in self._who and self._who[v].kind == "pirl" else -1 for v in ids[1:]]
        palette = distinct_colors(max(len(self.config["population"].style_names), 1))
        colors = [_EGO_COLOR] + [palette[k % len(palette)][:3] if k >= 0 else _BACKGROUND_COLOR for k in styles]
        frame = self._view.render([st.x for st in states], [st.y for st in states], [st.psi_rad for st in states],
                                  [st.length for st in states], [st.width for st in states], colors, self.time)
        if self.render_mode == "rgb_array":
            return frame
        self._show(frame)
        return None

    def _show(self, frame: np.ndarray) -> None:
        import matplotlib.pyplot as plt

        if self._window is None or not plt.fignum_exists(self._window[0].number):
            fig, ax = plt.subplots()
            ax.set_axis_off()
            self._window = (fig, ax.imshow(frame))  # type: ignore[assignment]
        self._window[1].set_data(frame)  # type: ignore[index]
        plt.pause(1.0 / self.metadata["render_fps"])

    def _sumo_step(self) -> None:
        # the controller sees the ego only in steps it is asked (some controlled vehicle in the network)
        self._controller.ego = None
        self._sim.step()  # type: ignore[attr-defined]

    # -- observation and info -----------------------------------------------------------------------

    def _observe(self) -> np.ndarray:
        o = self.config["observation"]
        ego = self._last_ego
        now = self._controller.ego
        others = now.others if now is not None else {}
        heading = np.array([np.cos(ego.psi_rad), np.sin(ego.psi_rad)])
        near = []
        for vid, st in others.items():
            delta = np.array([st.x - ego.x, st.y - ego.y])
            dist = float(np.hypot(*delta))
            if dist < PERCEPTION_DISTANCE and (o.get("see_behind", False) or delta @ heading > -2 * ego.length):
                near.append((dist, vid, st))
        if o.get("order", "sorted") == "sorted":
            near.sort(key=lambda item: (item[0], item[1]))
        self._frame = ([EGO_ID, *others], [ego, *others.values()])  # type: ignore[assignment]
        near = near[:self._count - 1]
        states = np.array([[ego.x, ego.y, ego.speed, ego.psi_rad]] +
                          [[st.x, st.y, st.speed, st.psi_rad] for _, _, st in near], dtype=float)
        obs = kinematics_rows(states, self._features, absolute=o.get("absolute", False),
                              features_range=o.get("features_range"), normalize=o.get("normalize", True),
                              clip=o.get("clip", True), vehicles_count=self._count)
        rows = [self._who.get(vid, _Neighbour(vid, "", -1, np.zeros(len(FEATURE_NAMES)))) for _, vid, _ in near]
        rows += [None] * (self._count - 1 - len(rows))  # type: ignore[list-item]
        if o.get("order", "sorted") == "shuffled":
            rows = shuffle_rows(obs, rows, self.np_random)
        self._rows = rows
        if self._style.width:
            return with_style_columns(obs, self._style.columns(rows))
        return obs.astype(np.float32)

    def _info(self) -> dict:
        now = self._controller.ego
        return {
            "speed": float(self._last_ego.speed),
            "time": float(self.time),
            "crashed": bool(self._crashed),
            "arrived": bool(self._arrived),
            "progress": float(self._ego_cost.s_path),
            "features": self._ego_cost.features.copy(),
            "rewards": dict(self._ego_cost.terms),
            "n_vehicles": ((len(now.others) + 1) if now is not None
                           else self._sim.n_present),  # type: ignore[attr-defined]
            **neighbour_info(self._rows),
            "style_names": self.config["population"].style_names,
            "feature_names": FEATURE_NAMES,
        }

    def recording(self):
        """The episode so far (warm-up included) as a :class:`~pirl_sim.scenarios.recording.ScenarioRecording`
        (needs ``record_tracks=True``; the ego is a non-PIRL track with ``agent_id`` and style name "ego")."""
        if not self.config["record_tracks"]:
            raise ValueError("this env was made with record_tracks=False; set it to True to record")
        if self._last_sim is None:
            raise RuntimeError("nothing to record: call reset() first")
        info = {"simulator": "sumo (pirl_sim/Roundabout-v0)", "ego_route": self._last_sim.ego_spec.route_id,
                "step_length_s": STEP}
        return self._last_sim.recording(info)

    def _stop(self) -> None:
        """End the SUMO run (at every reset and close)."""
        self._stack.close()
        self._sim = None

    def close(self) -> None:
        """End the SUMO run and close the human mode's window."""
        self._stop()
        if self._window is not None:
            import matplotlib.pyplot as plt

            plt.close(self._window[0])
            self._window = None
