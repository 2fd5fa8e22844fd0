"""What both backends of ``pirl_sim/Roundabout-v0`` share: the ego's reward, the neighbours' info, checks.

- :class:`EgoReward`: the ego's features along its route's reference path, frame by frame, and the reward
  terms of an agent step (``"exit"``: reach the exit soon, safely and comfortably, in seconds; ``"task"``:
  progress, comfort, collision, arrival; ``"theta"``: minus the cost of a chosen style, with the crash's
  cost-to-go); the env's module docstring states the formulas.
- :func:`neighbour_info`: the neighbours' ground truth (ids, PIRL or not, style, weights) of the
  observation's rows.
- :func:`check_common` / :func:`reward_weights`: the configuration keys both backends have.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from pirl_sim.scenarios.contract import STEP
from pirl_sim.scenarios.population_config import (
    DEFAULT_POPULATION,
    FEATURE_NAMES,
    FREE_FEATURES,
    REFERENCE_FEATURE,
    PopulationConfig,
    population_from_dict,
)
from pirl_sim.validation import check_keys, number

__all__ = ["REWARDS", "EXIT_REWARD_DEFAULTS", "VEHICLE_LENGTH", "EGO_ID", "ACC_REF", "JERK_REF", "LAT_ACC_REF",
           "EMPTY_ROW_STYLE", "MAX_EGO_SPEED", "ORDERS", "EgoReward", "clearance", "neighbour_info", "common_defaults", "check_common", "check_kinematics", "check_action", "acceleration",
           "reward_weights", "StepGuard"]

REWARDS = ("task", "theta", "exit")  #: values of the ``reward`` option
#: the ``"exit"`` reward's weights (``exit_reward`` option; every one >= 0, see the env's module docstring):
#: progress [s per (m / v_max)], time [1], comfort [1], near_miss [1], near_miss_gap [m], collision [s],
#: arrival [s]
EXIT_REWARD_DEFAULTS: dict[str, float] = {
    "progress": 1.0,  # per second it would take at v_max to drive the step's progress
    "time": 1.0,  # per second of the episode
    "comfort": 0.5,  # per second at comfort index 1 (see EgoReward)
    "near_miss": 2.0,  # per second with a vehicle nearer than near_miss_gap
    "near_miss_gap": 2.0,  # [m] clearance below which a frame counts as a near miss
    "collision": 50.0,  # [s] once, when the ego crashes (more than any duration the crash could save)
    "arrival": 10.0,  # [s] once, when the ego reaches the end of its route
}
VEHICLE_LENGTH = 5.0  #: [m] the vehicles' length in both backends (highway-env's Vehicle.LENGTH, SUMO's default)
EGO_ID = "ego"  #: the ego's vehicle id (and ``agent_id`` in recordings)
ACC_REF, JERK_REF = 3.0, 8.0  #: [m/s^2], [m/s^3] comfort-term scales (the driver model's bounds)
LAT_ACC_REF = 3.0  #: [m/s^2] scale of the lateral acceleration in the ``"exit"`` reward's comfort index
EMPTY_ROW_STYLE = -2  #: ``neighbour_styles`` of an empty observation row
FRAME_DT = STEP  # [s] simulation frame = driver-model step (the simulator contract's)
MAX_EGO_SPEED = 30.0  #: [m/s] largest ego_speed: the driver model's speed bound
ORDERS = ("sorted", "shuffled")  #: values of the Kinematics observation's ``order``
_ACTION_FORM = "a finite number, or an array of shape (1,) holding one, in [-1, 1]"


def check_action(action) -> float:
    """The agent's action as a float clipped to [-1, 1], the same check on both backends.

    Accepts a real number or an array-like of shape ``()`` or ``(1,)`` holding one (``Box(-1, 1, (1,))``'s
    samples); values outside [-1, 1] are clipped.

    Raises
    ------
    TypeError
        For ``None``, strings, bools and anything else that is not a real number (naming it and the allowed form).
    ValueError
        For another shape (e.g. ``(2,)``) or a NaN or infinite value.
    """
    if action is None or isinstance(action, (str, bytes, bool, np.bool_)):
        raise TypeError(f"action must be {_ACTION_FORM}, got {action!r}")
    try:
        arr = np.asarray(action)
    except (TypeError, ValueError):  # ragged sequences
        raise ValueError(f"action must be {_ACTION_FORM}, got {action!r}") from None
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"action must be {_ACTION_FORM}, got {action!r} (dtype {arr.dtype})")
    if arr.shape not in ((), (1,)):
        raise ValueError(f"action must be {_ACTION_FORM}, got shape {arr.shape}: {action!r}")
    x = float(arr.reshape(-1)[0])
    if not np.isfinite(x):
        raise ValueError(f"action must be {_ACTION_FORM}, got {action!r}")
    return min(max(x, -1.0), 1.0)


def acceleration(action, acceleration_range) -> float:
    """The ego's acceleration [m/s^2] of an action (checked by :func:`check_action`): positive values scale
    ``a_max``, negative ones ``-a_min`` of ``acceleration_range = (a_min, a_max)``."""
    x = check_action(action)
    lo, hi = (float(a) for a in acceleration_range)
    return x * hi if x >= 0 else -x * lo


class StepGuard:
    """Warns, as gymnasium's own envs do, when ``step()`` is called after the episode ended (terminated or
    truncated) without a ``reset()``; once per episode."""

    def __init__(self) -> None:
        self.ended: str | None = None  # "terminated" / "truncated" once the episode returned it
        self._warned = False

    def reset(self) -> None:
        self.ended, self._warned = None, False

    def before_step(self) -> None:
        if self.ended is not None and not self._warned:
            from gymnasium import logger

            self._warned = True
            logger.warn(f"You are calling 'step()' even though this environment has already returned {self.ended} "
                        f"= True. You should always call 'reset()' once you receive '{self.ended} = True' -- any "
                        "further steps are undefined behavior.")

    def after_step(self, terminated: bool, truncated: bool) -> None:
        if self.ended is None and (terminated or truncated):
            self.ended = "terminated" if terminated else "truncated"


def clearance(xy, others_xy) -> float:
    """[m] the ego's clearance to the nearest other vehicle: least centre distance from ``xy`` (2,) to the rows
    of ``others_xy`` (n, 2), minus :data:`VEHICLE_LENGTH` (bumper to bumper for vehicles in line; inf for none)."""
    others = np.asarray(others_xy, dtype=float).reshape(-1, 2)
    if not len(others):
        return float("inf")
    return float(np.sqrt(((others - np.asarray(xy, dtype=float)) ** 2).sum(axis=1)).min()) - VEHICLE_LENGTH


_PROJECT_MAX_ITER = 50  # as RouteSet.project
_PROJECT_MIN_SLOPE = -0.05  # as RouteSet.project: floor on the Newton slope


def _project_point(path, x: float, y: float, s_guess: float, tol: float = 1e-7) -> float | None:
    """Arc length [m] of the foot point of (x, y) [m] on ``path`` (a ReferencePath, extended straight beyond
    its ends), by Newton's method from ``s_guess`` [m]: `pirl_sim.scenarios.drivers.RouteSet.project` for
    one point in scalar arithmetic (one vehicle per frame: numpy's per-call cost dominated). None when the
    iteration does not converge or the guess is not finite."""
    if not math.isfinite(s_guess):
        return None
    s_tab, x_tab, y_tab, h_tab = path.s, path.x, path.y, path.heading
    n = len(s_tab)
    step_len = float(s_tab[1] - s_tab[0])
    inv_step, length = 1.0 / step_len, float(path.length)
    s = float(s_guess)
    for _ in range(_PROJECT_MAX_ITER):
        if s < 0.0 or s > length:  # the straight extension beyond an end
            e = 0 if s < 0.0 else n - 1
            he = float(h_tab[e])
            c, sn = math.cos(he), math.sin(he)
            over = s if s < 0.0 else s - length
            px, py, dx, dy, h, dh = float(x_tab[e]) + over * c, float(y_tab[e]) + over * sn, c, sn, he, 0.0
        else:
            j = min(max(int(s * inv_step), 0), n - 2)
            s0, ds = float(s_tab[j]), float(s_tab[j + 1] - s_tab[j])
            x0, y0, h0 = float(x_tab[j]), float(y_tab[j]), float(h_tab[j])
            ddx, ddy, ddh = float(x_tab[j + 1]) - x0, float(y_tab[j + 1]) - y0, float(h_tab[j + 1]) - h0
            u = min(max((s - s0) / ds, 0.0), 1.0)
            px, py, h = x0 + u * ddx, y0 + u * ddy, h0 + u * ddh
            dx, dy, dh = ddx / ds, ddy / ds, ddh / ds
        c, sn = math.cos(h), math.sin(h)
        rx, ry = x - px, y - py
        f = rx * c + ry * sn
        fprime = -(dx * c + dy * sn) + dh * (-rx * sn + ry * c)
        step = min(max(-f / min(fprime, _PROJECT_MIN_SLOPE), -step_len), step_len)
        s = s + step
        if abs(step) <= tol:
            return s
    return None


def reward_weights(theta: Mapping[str, float]) -> np.ndarray:
    """Normalised weights (3,) of the ``"theta"`` reward over :data:`FEATURE_NAMES` (``jerk_sq`` = 1)."""
    return np.array([float(theta.get(f, 1.0)) for f in FEATURE_NAMES])


class EgoReward:
    """The ego's cost features frame by frame and the reward terms of each agent step.

    Parameters
    ----------
    config : mapping          the env's configuration (``reward``, ``reward_theta``, the reward scales, ``duration``,
                              ``policy_frequency``; ``drivers.v_max`` scales the progress)
    routes : RouteSet         reference paths of the routes
    profile : callable        desired speed along the routes' global axis, ``profile(s) -> (v_des, dv_des, d2v_des)``
    route : str               the ego's route id
    xy : array (2,)           the ego's position [m] at the start
    """

    def __init__(self, config: Mapping, routes, profile, route: str, xy) -> None:
        self.config = config
        self.weights = reward_weights(config["reward_theta"])
        self.routes, self.profile = routes, profile
        self.route = routes.index(route)
        self.s_path = float(routes.project([self.route], np.asarray(xy, dtype=float)[None, :])[0])
        self.v_des = self._desired_speed()
        self._prev_acc = 0.0
        # ((v - v_des)^2 [m^2/s^2], a [m/s^2], jerk [m/s^3], lateral acceleration [m/s^2], near miss 0/1) per frame
        self._frames: list[tuple[float, float, float, float, float]] = []
        self._crash_charged = False
        self.features = np.zeros(len(FEATURE_NAMES))
        self.terms = self.step_terms(progress=0.0, crashed=False, arrived=False, time=0.0)

    def _desired_speed(self) -> float:
        return float(self.profile(self.routes.offsets[self.route] + np.array([self.s_path]))[0][0])

    def log_frame(self, xy, speed: float, accel: float, clearance: float = np.inf) -> None:
        """After each simulation frame: the ego's position [m], speed [m/s], applied acceleration [m/s^2] and
        clearance [m] to the nearest other vehicle (centre distance minus :data:`VEHICLE_LENGTH`; inf: none)."""
        x, y = (float(c) for c in xy)
        s = _project_point(self.routes.paths[self.route], x, y, self.s_path)
        if s is None:  # the warm start lost the ego (e.g. pushed by a crash): project from scratch
            s = float(self.routes.project([self.route], np.array([[x, y]]))[0])
        self.s_path = s
        s_global = self.routes.offsets[self.route] + np.array([self.s_path])
        k = self.routes.curvature(s_global)[0]
        kappa = float(k[0])
        a_lat, v_max = getattr(self.profile, "a_lat", None), getattr(self.profile, "v_max", None)
        if a_lat is not None and v_max is not None and hasattr(self.profile, "routes"):
            # a RouteSetProfile: its desired speed of this curvature, without evaluating the curvature again
            k2 = kappa * kappa
            self.v_des = float(np.power(k2 * k2 * (1.0 / a_lat**4) + v_max**-8.0, -0.125))
        else:
            self.v_des = self._desired_speed()
        near = float(clearance < self.config["exit_reward"]["near_miss_gap"])
        self._frames.append(((speed - self.v_des) ** 2, accel, (accel - self._prev_acc) / FRAME_DT,
                             speed**2 * abs(kappa), near))
        self._prev_acc = accel

    def begin_step(self) -> None:
        """Before the frames of an agent step."""
        self._frames = []

    def step_terms(self, *, progress: float, crashed: bool, arrived: bool, time: float) -> dict[str, float]:
        """The reward terms of the step whose frames were logged (``progress`` [m] along the route, ``time``
        [s] since the reset)."""
        c = self.config
        period = 1.0 / c["policy_frequency"]
        f = np.array(self._frames) if self._frames else np.zeros((1, 5))
        self.features = np.array([f[:, 0].mean(), (f[:, 1] ** 2).mean(), (f[:, 2] ** 2).mean()])
        # the comfort index's parts, mean over the step's frames: acceleration, jerk, lateral acceleration
        acc_part, jerk_part, lateral = (float(((f[:, i] / ref) ** 2).mean()) if self._frames else 0.0
                                        for i, ref in ((1, ACC_REF), (2, JERK_REF), (3, LAT_ACC_REF)))
        comfort = acc_part + jerk_part
        cost_to_go = 0.0
        if crashed and not self._crash_charged:
            # a crashed vehicle stands still: over the rest of the episode it would cost speed_dev = v_des^2
            # per second (acc_sq and jerk_sq 0), so that a crash never ends the style cost early
            self._crash_charged = True
            cost_to_go = float(self.weights[0] * self.v_des**2 * max(c["duration"] - time, 0.0))
        self.terms = {
            "progress": progress / (c["drivers"].v_max * period),
            "comfort": comfort,
            "style_cost": float(self.weights @ self.features) * period,
            "crash_cost_to_go": cost_to_go,
            "collision": float(crashed),
            "arrival": float(arrived),
            # the "exit" reward's terms [s]
            "progress_time": progress / c["drivers"].v_max,
            "time": period,
            "comfort_time": (comfort + lateral) * period,
            # comfort_time's three parts (they sum to it up to rounding): acceleration, jerk, lateral acceleration
            "comfort_acc_time": acc_part * period,
            "comfort_jerk_time": jerk_part * period,
            "comfort_lateral_time": lateral * period,
            "near_miss_time": float(f[:, 4].mean()) * period if self._frames else 0.0,
        }
        return self.terms

    def reward(self) -> float:
        """The step's reward from its terms (``reward``: ``"task"`` or ``"theta"``)."""
        c, t = self.config, self.terms
        if c["reward"] == "exit":
            w = c["exit_reward"]
            return float(w["progress"] * t["progress_time"] - w["time"] * t["time"] - w["comfort"] * t["comfort_time"]
                         - w["near_miss"] * t["near_miss_time"] - w["collision"] * t["collision"]
                         + w["arrival"] * t["arrival"])
        r = c["collision_reward"] * t["collision"] + c["arrival_reward"] * t["arrival"]
        if c["reward"] == "task":
            r += c["progress_reward"] * t["progress"] + c["comfort_reward"] * t["comfort"]
        else:
            r -= t["style_cost"] + t["crash_cost_to_go"]
        return float(r)


def neighbour_info(rows: Sequence) -> dict:
    """``neighbour_ids``, ``neighbour_is_pirl``, ``neighbour_styles``, ``neighbour_theta`` of observation rows
    1..V-1 (vehicles with ``vehicle_id``, ``kind``, ``style``, ``theta``; None for empty rows)."""
    k = len(FEATURE_NAMES)
    ids, pirl, styles, theta = [], [], [], np.zeros((len(rows), k))
    for i, v in enumerate(rows):
        if v is None:
            ids.append("")
            pirl.append(False)
            styles.append(EMPTY_ROW_STYLE)
            continue
        ids.append(getattr(v, "vehicle_id", ""))
        is_pirl = getattr(v, "kind", None) == "pirl"
        pirl.append(is_pirl)
        styles.append(int(v.style) if is_pirl else -1)
        if is_pirl:
            theta[i] = v.theta
    return {"neighbour_ids": tuple(ids), "neighbour_is_pirl": np.array(pirl, dtype=bool),
            "neighbour_styles": np.array(styles, dtype=np.int64), "neighbour_theta": theta}


def common_defaults() -> dict:
    """The configuration keys both backends share, with their defaults (a fresh dict)."""
    return {
        "observation": {
            "type": "Kinematics",
            "vehicles_count": 8,
            "features": ["presence", "x", "y", "vx", "vy", "cos_h", "sin_h"],
            "features_range": {"x": [-100, 100], "y": [-100, 100], "vx": [-15, 15], "vy": [-15, 15]},
            "absolute": False,
            "normalize": True,
            "clip": True,
            "see_behind": True,
            "order": "sorted",
        },
        "action": {"type": "LongitudinalAcceleration", "acceleration_range": [-4.0, 3.0]},
        "policy_frequency": 5,  # [Hz]
        "duration": 40.0,  # [s]
        "population": DEFAULT_POPULATION,
        "ego_route": "arm0_to_arm2",
        "ego_speed": 8.0,  # [m/s]
        "reward": "task",
        "reward_theta": {"speed_dev": 1.0, "acc_sq": 1.0},
        "progress_reward": 1.0,
        "comfort_reward": -0.1,
        "collision_reward": -10.0,
        "arrival_reward": 1.0,
        "exit_reward": dict(EXIT_REWARD_DEFAULTS),
        "style_observation": "none",  # "truth" / "inferred": the neighbours' weights as columns (envs.styles)
        "style_learner": None,  # a fitted learner (or a saved one's path) for "inferred"
        "style_history": 20,  # [frames of 0.1 s] inference window when the learner has none
        "record_tracks": False,
    }


def check_common(c: dict) -> None:
    """Check (and normalise in place) the configuration keys both backends share; ``ValueError`` naming the
    bad value and what is allowed."""
    pf = c["policy_frequency"]
    if isinstance(pf, bool) or not isinstance(pf, (int, np.integer)) or pf < 1 or 10 % pf:
        raise ValueError(f"policy_frequency must divide 10 Hz (1, 2, 5 or 10), got {pf!r}")
    act = c["action"]
    if not isinstance(act, Mapping) or act.get("type") != "LongitudinalAcceleration":
        raise ValueError("action must be {'type': 'LongitudinalAcceleration', 'acceleration_range': "
                         f"[a_min, a_max]}}, got {act!r}")
    check_keys("action", act, ("type", "acceleration_range"))
    rng = act.get("acceleration_range", (-4.0, 3.0))
    if not isinstance(rng, (list, tuple, np.ndarray)) or len(rng) != 2 or not \
            number("action acceleration_range[0]", rng[0]) < 0 < number("action acceleration_range[1]", rng[1]):
        raise ValueError(f"action acceleration_range must be [a_min < 0, a_max > 0] m/s^2, got {rng!r}")
    number("duration", c["duration"], low=0.0, allow_equal=False)
    pop = c["population"]
    if isinstance(pop, Mapping):
        c["population"] = population_from_dict(pop, source="config population")
    elif not isinstance(pop, PopulationConfig):
        raise ValueError(f"population must be a PopulationConfig or a mapping, got {type(pop).__name__}")
    if number("ego_speed", c["ego_speed"], low=0.0) > MAX_EGO_SPEED:
        raise ValueError(f"ego_speed must be in [0, {MAX_EGO_SPEED:g}] m/s (the driver model's speed bound), got "
                         f"{c['ego_speed']!r}")
    if c["reward"] not in REWARDS:
        raise ValueError(f"reward must be one of {REWARDS}, got {c['reward']!r}")
    theta = c["reward_theta"]
    if not isinstance(theta, Mapping):
        raise ValueError(f"reward_theta must be a mapping feature -> weight, got {theta!r}")
    check_keys("reward_theta", theta, (*FREE_FEATURES, REFERENCE_FEATURE))
    missing = [f for f in FREE_FEATURES if f not in theta]
    if missing:
        raise ValueError(f"reward_theta misses {missing}; give {', '.join(FREE_FEATURES)}")
    for f, w in theta.items():
        number(f"reward_theta[{f!r}]", w, low=0.0, allow_equal=False)
    if theta.get(REFERENCE_FEATURE, 1.0) != 1.0:
        raise ValueError(f"reward_theta[{REFERENCE_FEATURE!r}] is the reference weight, fixed at 1")
    for name in ("progress_reward", "comfort_reward", "collision_reward", "arrival_reward"):
        number(name, c[name])
    ex = c["exit_reward"]
    if not isinstance(ex, Mapping):
        raise ValueError(f"exit_reward must be a mapping name -> weight >= 0 (names {', '.join(EXIT_REWARD_DEFAULTS)}), "
                         f"got {ex!r}")
    check_keys("exit_reward", ex, tuple(EXIT_REWARD_DEFAULTS))
    c["exit_reward"] = {k: number(f"exit_reward[{k!r}]", ex.get(k, d), low=0.0)
                        for k, d in EXIT_REWARD_DEFAULTS.items()}  # missing weights take their defaults
    if not isinstance(c["record_tracks"], bool):
        raise ValueError(f"record_tracks must be true or false, got {c['record_tracks']!r}")


def check_kinematics(obs: Mapping, features_allowed, label: str) -> None:
    """Check the values of a ``Kinematics`` observation config (its keys are checked by the caller):
    ``features`` a non-empty list of distinct names in ``features_allowed``, ``vehicles_count`` an integer >= 1,
    ``features_range`` None or a mapping of such a name to ``[low < high]``, ``order`` in :data:`ORDERS` and
    the flags booleans; ``ValueError`` naming the key, the value and what is allowed."""
    allowed = tuple(features_allowed)
    if "features" in obs:
        f = obs["features"]
        if isinstance(f, (str, Mapping)) or not isinstance(f, (list, tuple)) or not f:
            raise ValueError(f"{label} features must be a non-empty list of names out of {', '.join(allowed)}; "
                             f"got {f!r}")
        unknown = [x for x in f if not isinstance(x, str) or x not in allowed]
        if unknown:
            raise ValueError(f"{label} features: unknown name(s) {unknown}; valid: {', '.join(allowed)}")
        if len(set(f)) != len(f):
            raise ValueError(f"{label} features repeats a name: {list(f)}")
    if "vehicles_count" in obs:
        n = obs["vehicles_count"]
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"{label} vehicles_count must be an integer >= 1 (the ego's row and its neighbours'), "
                             f"got {n!r}")
    fr = obs.get("features_range")
    if fr is not None:
        if not isinstance(fr, Mapping):
            raise ValueError(f"{label} features_range must be a mapping feature -> [low, high] or None, got {fr!r}")
        for name, bounds in fr.items():
            if name not in allowed:
                raise ValueError(f"{label} features_range: unknown feature {name!r}; valid: {', '.join(allowed)}")
            if not isinstance(bounds, (list, tuple)) or len(bounds) != 2 or not \
                    number(f"{label} features_range[{name!r}][0]", bounds[0]) < \
                    number(f"{label} features_range[{name!r}][1]", bounds[1]):
                raise ValueError(f"{label} features_range[{name!r}] must be [low, high] with low < high, got "
                                 f"{bounds!r}")
    if "order" in obs and obs["order"] not in ORDERS:
        raise ValueError(f"{label} order must be one of {ORDERS}, got {obs['order']!r}")
    for flag in ("absolute", "normalize", "clip", "see_behind", "observe_intentions", "include_obstacles"):
        if flag in obs and not isinstance(obs[flag], bool):
            raise ValueError(f"{label} {flag} must be true or false, got {obs[flag]!r}")
