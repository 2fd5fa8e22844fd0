"""Scripted egos for ``pirl_sim/Roundabout-v0``: what an agent has to beat, and action wrappers for agents.

Each baseline is a policy with ``act(env) -> action`` (the env's ``Box(-1, 1, (1,))`` action) on the unwrapped
env, deciding once per agent step, with ``reset(env)`` after every ``env.reset``: :class:`HoldSpeed` (both
backends), :class:`IdmEgo` (highway backend: the ego driven as the background traffic drives) and
:class:`MpcEgo` (highway backend: a PIRL driver of weights ``theta``). :func:`action_of` maps accelerations
[m/s^2] to actions. :class:`ResidualAction` (a correction to a baseline's action, optionally shielded by
:func:`interaction_limit`) and :class:`DesiredSpeedAction` (a factor on the IDM ego's desired speed,
:func:`idm_action`) are gymnasium wrappers for agents.

The baselines and wrappers are explained in the documentation's "The gymnasium environment" page.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from pirl_sim.scenarios.population_config import FEATURE_NAMES, FREE_FEATURES

from .common import EGO_ID, check_action, reward_weights

IDM_DELTA = 4.0  #: highway-env's IDM exponent (IDMVehicle.DELTA), also the env's background traffic's

__all__ = ["BASELINES", "EPISODE_TERMS", "DesiredSpeedAction", "HoldSpeed", "IdmEgo", "MpcEgo", "ResidualAction",
           "action_of", "drive_episode", "idm_action", "interaction_limit", "make_baseline"]

#: baseline names of :func:`make_baseline`
BASELINES = ("hold-speed", "idm", "mpc")


def action_of(a: float, acceleration_range) -> np.ndarray:
    """The action (1,) float32 in [-1, 1] that commands acceleration ``a`` [m/s^2] (clipped to the range)."""
    lo, hi = (float(x) for x in acceleration_range)
    x = a / hi if a >= 0 else -a / lo
    return np.array([min(max(x, -1.0), 1.0)], dtype=np.float32)


def _highway(env, name: str):
    from .roundabout import PirlRoundaboutEnv

    base = getattr(env, "unwrapped", env)
    if not isinstance(base, PirlRoundaboutEnv):
        raise TypeError(f"the {name} baseline drives the highway backend's ego (PirlRoundaboutEnv), got "
                        f"{type(base).__name__}")
    return base


class HoldSpeed:
    """Action 0 every step: the ego keeps its initial speed (both backends)."""

    name = "hold-speed"

    def reset(self, env) -> None:
        """Nothing to reset."""

    def act(self, env) -> np.ndarray:
        return np.zeros(1, dtype=np.float32)


class IdmEgo:
    """The ego as the env's IDM background traffic drives (highway backend; see the module docstring)."""

    name = "idm"

    def reset(self, env) -> None:
        _highway(env, self.name)

    def act(self, env) -> np.ndarray:
        return idm_action(env)


def idm_action(env, speed_factor: float = 1.0) -> np.ndarray:
    """The IDM ego's action (highway backend): highway-env's IDM towards ``speed_factor`` times the route's
    desired speed v_des(s), behind the ego's leader on its route and, when it must yield, before the entry's
    stop line (the traffic's rules, as its background vehicles of that speed factor drive)."""
    base = _highway(env, "idm")
    traffic, ego = base.road, base.vehicle
    others = traffic.vehicles
    a = traffic._limit(ego, others, traffic._occupancy(others), free_v0=speed_factor * traffic.v_des(ego),
                       delta=IDM_DELTA)
    return action_of(a, base.action_type.acceleration_range)


def interaction_limit(env) -> float:
    """The largest acceleration [m/s^2] the traffic's rules allow the ego now (highway backend): the IDM limit of
    its leader on its route and, when it must yield, of the entry's stop line, without the free-road term (+inf
    when neither applies). The cap the traffic puts on the PIRL drivers' commands and :class:`MpcEgo`'s."""
    base = _highway(env, "shield")
    traffic, ego = base.road, base.vehicle
    others = traffic.vehicles
    return float(traffic._limit(ego, others, traffic._occupancy(others), free_v0=None, delta=IDM_DELTA))


class MpcEgo:
    """The ego as a PIRL driver of weights ``theta`` drives (highway backend; see the module docstring).

    Parameters
    ----------
    theta : mapping
        Normalised weights ``{"speed_dev": ..., "acc_sq": ...}`` (``jerk_sq`` = 1), each > 0.
    """

    name = "mpc"

    def __init__(self, theta: Mapping[str, float]) -> None:
        if not isinstance(theta, Mapping):
            raise TypeError(f"theta must be a mapping feature -> weight (features {', '.join(FREE_FEATURES)}), "
                            f"got {type(theta).__name__}")
        unknown = [k for k in theta if k not in FEATURE_NAMES]
        missing = [k for k in FREE_FEATURES if k not in theta]
        if unknown or missing:
            raise ValueError(f"theta needs the weights {', '.join(FREE_FEATURES)} (optional jerk_sq = 1); got "
                             f"{dict(theta)!r}")
        w = reward_weights(theta)
        if not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise ValueError(f"theta's weights must be finite and > 0, got {dict(theta)!r}")
        self.theta = dict(theta)
        self._weights = w
        self._drivers = None

    def reset(self, env) -> None:
        from pirl_sim.scenarios.drivers import PirlDrivers

        base = _highway(env, self.name)
        traffic, drv = base.road, base.config["drivers"]
        self._drivers = PirlDrivers(traffic.model,  # type: ignore[assignment]
                                    {EGO_ID: (base.config["ego_route"], self._weights)},
                                    horizon=drv.horizon, stop_speed=drv.stop_speed, resume_speed=drv.resume_speed)

    def act(self, env) -> np.ndarray:
        from pirl_sim.scenarios.contract import EgoObservation, EgoView
        from pirl_sim.scenarios.highway.traffic import STEP_LENGTH

        base = _highway(env, self.name)
        if self._drivers is None:
            raise RuntimeError("call reset(env) after env.reset() before act(env)")
        traffic, ego = base.road, base.vehicle
        others = traffic.vehicles
        state = EgoView(float(ego.position[0]), float(ego.position[1]), float(ego.speed),
                        float(ego.applied_acceleration))
        cmd = self._drivers.commands(traffic.time, {EGO_ID: EgoObservation(state)})[EGO_ID]
        if cmd is None:  # handed back at a standstill, as the PIRL drivers are: IDM until it drives again
            a = traffic._limit(ego, others, traffic._occupancy(others), free_v0=traffic.v_des(ego), delta=IDM_DELTA)
        else:
            a = min((cmd - ego.speed) / STEP_LENGTH, interaction_limit(base))
        return action_of(a, base.action_type.acceleration_range)


#: the ``"exit"`` reward's terms [s] an episode of :func:`drive_episode` sums (``info["rewards"]`` keys)
EPISODE_TERMS = ("progress_time", "near_miss_time", "comfort_acc_time", "comfort_jerk_time", "comfort_lateral_time")


def drive_episode(env, act, seed: int, *, options: dict | None = None, on_reset=None) -> dict:
    """One episode: ``act(obs) -> action`` every step after ``env.reset(seed=seed, options=options)`` and
    ``on_reset(env)`` (a scripted ego's ``reset``); returns ``seed``, ``return``, ``arrived``, ``crashed``,
    ``time`` [s], ``steps``, and the ``"exit"`` reward's terms summed over the episode (:data:`EPISODE_TERMS`,
    unweighted, in seconds: ``progress_time``, ``near_miss_time``, ``comfort_acc_time``, ``comfort_jerk_time``,
    ``comfort_lateral_time``; see the env's docstring), whatever reward the env pays."""
    obs, _ = env.reset(seed=int(seed), options=options)
    if on_reset is not None:
        on_reset(env)
    total, steps = 0.0, 0
    sums = dict.fromkeys(EPISODE_TERMS, 0.0)
    while True:
        obs, reward, terminated, truncated, info = env.step(act(obs))
        total += float(reward)
        for k in EPISODE_TERMS:
            sums[k] += info["rewards"][k]
        steps += 1
        if terminated or truncated:
            break
    return {"seed": int(seed), "return": total, "arrived": bool(info["arrived"]), "crashed": bool(info["crashed"]),
            "time": float(info["time"]), "steps": steps, **sums}


def make_baseline(name: str, theta: Mapping[str, float] | None = None):
    """A baseline by name (:data:`BASELINES`); ``theta`` for ``"mpc"`` (default: "tracks desired speed",
    speed_dev 3, acc_sq 0.3)."""
    if name == "hold-speed":
        return HoldSpeed()
    if name == "idm":
        return IdmEgo()
    if name == "mpc":
        return MpcEgo(theta if theta is not None else {"speed_dev": 3.0, "acc_sq": 0.3})
    raise ValueError(f"baseline must be one of {BASELINES}, got {name!r}")


def _wrapper_bases():
    import gymnasium as gym

    return gym.Wrapper, gym.utils.RecordConstructorArgs  # the latter: gymnasium can recreate the wrapped env


def _rate_and_observation(wrapper, env, max_change, observe: bool, key: str, size: int, unit: str) -> None:
    """Check and set an action wrapper's ``max_change`` (> 0 in ``unit`` per step, or None) and ``observe``; with
    ``observe`` its observation space becomes a ``Dict`` of the env's (``"kinematics"``) and ``key``, a
    ``Box(-1, 1, (size,))``."""
    if max_change is not None and (isinstance(max_change, bool) or not isinstance(max_change, (int, float))
                                   or not np.isfinite(max_change) or max_change <= 0):
        raise ValueError(f"max_change must be a finite number > 0 ({unit} per step) or None, got {max_change!r}")
    wrapper.max_change = None if max_change is None else float(max_change)
    if not isinstance(observe, bool):
        raise TypeError(f"observe must be True or False, got {observe!r}")
    wrapper.observe = observe
    if observe:
        from gymnasium import spaces

        wrapper.observation_space = spaces.Dict({"kinematics": env.observation_space,
                                                 key: spaces.Box(-1.0, 1.0, shape=(size,), dtype=np.float32)})


def _towards(current: float, target: float, max_change: float | None) -> float:
    """``target``, or with ``max_change`` the value at most that far from ``current`` on the way to it."""
    if max_change is None:
        return target
    return min(max(target, current - max_change), current + max_change)


class ResidualAction(*_wrapper_bases()):  # type: ignore[misc]
    """The agent's action as a correction to a baseline ego's (module doc; "The gymnasium environment" page).

    Parameters
    ----------
    env : gymnasium.Env                  ``pirl_sim/Roundabout-v0`` (possibly wrapped)
    baseline : str or baseline object    a name of `BASELINES`, or an object with ``reset(env)`` and ``act(env)``
    scale : float                        > 0: action in [-1, 1] moves the baseline's by up to ``scale`` action units
    shield : bool                        cap the applied action at the traffic's rules (`interaction_limit`)
    max_change : float or None           > 0: the correction follows ``scale * action`` by at most this per step
    observe : bool                       add a ``"residual"`` Box(-1, 1, (3,)) to the observation: the baseline's
                                         action, the correction in force / ``scale`` and the shield's cap

    ``info["baseline_action"]`` and ``info["applied_action"]`` give both actions of each step.
    """

    def __init__(self, env, baseline="idm", scale: float = 0.5, shield: bool = False,
                 max_change: float | None = None, observe: bool = False) -> None:
        from gymnasium.utils import RecordConstructorArgs

        RecordConstructorArgs.__init__(self, baseline=baseline, scale=scale, shield=shield, max_change=max_change,
                                       observe=observe)
        super().__init__(env)
        self.baseline = make_baseline(baseline) if isinstance(baseline, str) else baseline
        if not (hasattr(self.baseline, "act") and hasattr(self.baseline, "reset")):
            raise TypeError(f"baseline must be one of {BASELINES} or have reset(env) and act(env), got "
                            f"{type(baseline).__name__}")
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not np.isfinite(scale) or scale <= 0:
            raise ValueError(f"scale must be a finite number > 0 (action units), got {scale!r}")
        self.scale = float(scale)
        if not isinstance(shield, bool):
            raise TypeError(f"shield must be True or False, got {shield!r}")
        self.shield = shield
        _rate_and_observation(self, env, max_change, observe, "residual", 3, "action units")
        self.correction = 0.0  #: the correction applied in the last step (action units)
        self._next = None  # (baseline action, cap in action units) of the coming step, once computed

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.baseline.reset(self.env.unwrapped)
        self.correction = 0.0
        self._next = None
        return self._observation(obs), info

    def _actions(self) -> tuple[float, float]:
        """(the baseline's action, the shield's cap in action units, 1 where none) in the env's state now,
        computed once per state: the observation shows what the next step applies."""
        if self._next is None:
            base = float(self.baseline.act(self.env.unwrapped)[0])
            cap = interaction_limit(self.env) if self.shield else math.inf
            cap = float(action_of(cap, self.env.unwrapped.action_type.acceleration_range)[0]) \
                if math.isfinite(cap) else 1.0
            self._next = (base, cap)  # type: ignore[assignment]
        return self._next  # type: ignore[return-value]

    def _observation(self, obs):
        if not self.observe:
            return obs
        base, cap = self._actions()
        extra = np.clip([base, self.correction / self.scale, cap], -1.0, 1.0).astype(np.float32)
        return {"kinematics": obs, "residual": extra}

    def step(self, action):
        x = check_action(action)
        base, cap = self._actions()
        self.correction = _towards(self.correction, self.scale * x, self.max_change)
        a = min(base + self.correction, cap)
        applied = np.array([min(max(a, -1.0), 1.0)], dtype=np.float32)
        obs, reward, terminated, truncated, info = self.env.step(applied)
        self._next = None
        info = {**info, "baseline_action": base, "applied_action": float(applied[0])}
        return self._observation(obs), reward, terminated, truncated, info


class DesiredSpeedAction(*_wrapper_bases()):  # type: ignore[misc]
    """The agent's action as the IDM ego's desired-speed factor (module doc; "The gymnasium environment" page).

    Parameters
    ----------
    env : gymnasium.Env           ``pirl_sim/Roundabout-v0`` on the highway backend (possibly wrapped)
    scale : float                 in (0, 1): the action in [-1, 1] sets the factor ``1 + scale * action`` on v_des(s)
    max_change : float or None    > 0: the factor follows its target by at most this per agent step; None: at once
    observe : bool                add a ``"speed"`` Box(-1, 1, (2,)): ``(factor - 1) / scale`` and v_des(s) / v_max
    on_approach : bool            apply the factor on the approach too, not only from the ring on

    ``info["speed_factor"]`` (the factor set), ``info["applied_factor"]`` (the one the IDM drove with) and
    ``info["applied_action"]`` (the acceleration action) describe each step.
    """

    def __init__(self, env, scale: float = 0.3, max_change: float | None = None, observe: bool = False,
                 on_approach: bool = False) -> None:
        from gymnasium.utils import RecordConstructorArgs

        RecordConstructorArgs.__init__(self, scale=scale, max_change=max_change, observe=observe,
                                       on_approach=on_approach)
        super().__init__(env)
        _highway(env, "desired-speed action")
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0 < scale < 1:
            raise ValueError(f"scale must be a number in (0, 1) (the largest change of the desired-speed factor), "
                             f"got {scale!r}")
        self.scale = float(scale)
        _rate_and_observation(self, env, max_change, observe, "speed", 2, "factor")
        if not isinstance(on_approach, bool):
            raise TypeError(f"on_approach must be True or False, got {on_approach!r}")
        self.on_approach = on_approach
        self.factor = 1.0  #: the desired-speed factor applied in the last step

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.factor = 1.0
        return self._observation(obs), info

    def _observation(self, obs):
        if not self.observe:
            return obs
        base = self.env.unwrapped
        v_des = base.road.v_des(base.vehicle) / base.config["drivers"].v_max
        extra = np.clip([(self.factor - 1.0) / self.scale, v_des], -1.0, 1.0).astype(np.float32)
        return {"kinematics": obs, "speed": extra}

    def step(self, action):
        self.factor = _towards(self.factor, 1.0 + self.scale * check_action(action), self.max_change)
        factor = self.factor if self.on_approach or not self.env.unwrapped.vehicle.entering else 1.0
        applied = idm_action(self.env, factor)
        obs, reward, terminated, truncated, info = self.env.step(applied)
        info = {**info, "speed_factor": self.factor, "applied_factor": factor, "applied_action": float(applied[0])}
        return self._observation(obs), reward, terminated, truncated, info
