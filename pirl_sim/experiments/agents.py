"""The ``agents`` scenario of sweeps: egos on ``pirl_sim/Roundabout-v0``, trained (PPO) or scripted, each cell
evaluated on fixed evaluation episodes.

Every cell is one policy run: a scripted ego (:mod:`pirl_sim.envs.baselines`) is evaluated, PPO
(stable-baselines3) is trained for ``steps`` environment steps with the cell's seed and then evaluated with
deterministic actions, on the env seeds ``eval_seed``, ``eval_seed + 1``, ... The policies
(`POLICIES`: ``"hold-speed"``, ``"idm"``, ``"mpc"``, ``"ppo"``, `PPOEgo`) are learners of this scenario only.
The code of these cells (this module and :mod:`pirl_sim.envs`) is part of this scenario's cell keys only.

A sweep config over agents, the policies and a cell's stored scores are explained in the documentation's
"Agents among drivers of known styles" page.
"""

from __future__ import annotations

import copy
import math
import time

from sklearn.base import BaseEstimator

from pirl_sim.validation import number

from .spec import Param, ScenarioSpec, TrainShape

__all__ = ["POLICIES", "ACTIONS", "MODES", "PPOEgo", "HoldSpeedEgo", "IdmEgo", "MpcEgo", "run_agent_cells",
           "env_config", "fit_style_learner", "episode", "select_seeds"]

ENV_ID = "pirl_sim/Roundabout-v0"
MODES = ("none", "truth", "inferred")  #: observation modes (the env's ``style_observation``)
#: PPO's action: ``"residual-idm"`` a correction to the IDM ego's action
#: (:class:`~pirl_sim.envs.baselines.ResidualAction`), ``"shielded-residual-idm"`` the same capped by the
#: traffic's leader and yielding limits (``shield``), ``"idm-speed"`` the IDM ego's desired-speed factor
#: (:class:`~pirl_sim.envs.baselines.DesiredSpeedAction`), ``"direct"`` the env's acceleration itself
ACTIONS = ("residual-idm", "shielded-residual-idm", "idm-speed", "direct")
REWARDS = ("exit", "task")  #: the env's rewards an experiment can train on (``"theta"`` needs weights)

_PARAMS = {
    "initial_vehicles": Param("int", 12, "vehicles on the road at reset"),
    "depart_interval": Param("float", 2.0, "[s] mean time between the traffic's departures"),
    "duration": Param("float", 40.0, "[s] episode time limit"),
    "reward": Param("choice", "exit", "the env's reward", REWARDS),
    "eval_episodes": Param("int", 20, "evaluation episodes per cell"),
    "eval_seed": Param("int", 1000, "env seed of the first evaluation episode (the others follow it)"),
    "learner_seed": Param("int", 7, "seed of the highway-env recording the 'inferred' mode's learner is fitted on"),
}


def _check(params: dict) -> dict:
    out = dict(params)
    for name, low in (("initial_vehicles", 0), ("eval_episodes", 1), ("eval_seed", 0), ("learner_seed", 0)):
        if out[name] < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {out[name]!r}")
    for name in ("depart_interval", "duration"):
        out[name] = number(name, out[name], low=0.0, allow_equal=False)
    return out


def _check_protocol(params: dict, protocol: dict) -> None:
    if protocol.get("kind", "paper") != "paper":
        raise ValueError(f"runs agents, not predictions: its one protocol is \"paper\", got {protocol.get('kind')!r}")


def eval_seeds(params: dict) -> list[int]:
    """The evaluation episodes' env seeds."""
    return list(range(params["eval_seed"], params["eval_seed"] + params["eval_episodes"]))


# ------------------------------------------------------------------------------------------ the policies

class _Policy(BaseEstimator):
    """A policy as a pseudo-learner of the sweep (its parameters are the cell's learner parameters)."""

    scenarios = ("agents",)  #: the scenarios that run it
    name = ""

    def _check_common(self) -> None:
        """Nothing to check."""

    def fit(self, trajectories=None, y=None):
        raise ValueError(f"{self.name!r} is a policy of the 'agents' scenario (pirl_sim.experiments.agents), not a learner")


class HoldSpeedEgo(_Policy):
    """Action 0: the ego keeps its initial speed."""

    name = "hold-speed"

    def __init__(self, model=None, window=None, windows="first") -> None:
        self.model, self.window, self.windows = model, window, windows


class IdmEgo(HoldSpeedEgo):
    """The ego driven as the env's IDM background traffic."""

    name = "idm"


class MpcEgo(_Policy):
    """The ego driven as a PIRL driver of normalised weights (``speed_dev``, ``acc_sq``; ``jerk_sq`` = 1)."""

    name = "mpc"

    def __init__(self, speed_dev=3.0, acc_sq=0.3, model=None, window=None, windows="first") -> None:
        self.speed_dev, self.acc_sq = speed_dev, acc_sq
        self.model, self.window, self.windows = model, window, windows

    def _check_common(self) -> None:
        for name in ("speed_dev", "acc_sq"):
            number(name, getattr(self, name), low=0.0, allow_equal=False)


class PPOEgo(_Policy):
    """stable-baselines3's PPO ("MlpPolicy" on the flattened observation), trained in the cell (every parameter in full:
    the "Agents among drivers of known styles" page, "In detail: AgentsConfig and PPOEgo").

    Parameters
    ----------
    style_observation, action : str        the observation mode (`MODES`); `ACTIONS`
    residual_scale : float                 largest correction in action units (> 0), or of the desired-speed factor
    max_change, steps : float or None, int   largest change of the correction per agent step (None: any); training steps
    n_steps, batch_size, n_epochs, gamma, learning_rate, log_std_init, use_sde : PPO's settings (see the page)
    observe_residual : bool
        Also observe what the action changes (``observe`` of `~pirl_sim.envs.baselines.ResidualAction`,
        `~pirl_sim.envs.baselines.DesiredSpeedAction`).
    select_every, select_episodes, select_seed : int or None, int, int   model selection (see the page)
    random_state : int or None             training seed (PPO's and its env's); the sweep sets the cell's seed
    """

    name = "ppo"

    def __init__(self, style_observation="none", action="residual-idm", residual_scale=0.25, max_change=None,
                 steps=16_000, n_steps=1024, batch_size=128, n_epochs=10, gamma=0.99, learning_rate=3e-4,
                 log_std_init=-2.0, use_sde=True, observe_residual=False, select_every=None, select_episodes=10,
                 select_seed=2000, random_state=None, model=None, window=None, windows="first") -> None:
        self.style_observation, self.action, self.residual_scale = style_observation, action, residual_scale
        self.max_change = max_change
        self.steps, self.n_steps, self.batch_size, self.n_epochs = steps, n_steps, batch_size, n_epochs
        self.gamma, self.learning_rate, self.log_std_init, self.use_sde = gamma, learning_rate, log_std_init, use_sde
        self.observe_residual = observe_residual
        self.select_every, self.select_episodes, self.select_seed = select_every, select_episodes, select_seed
        self.random_state = random_state
        self.model, self.window, self.windows = model, window, windows

    def _check_common(self) -> None:
        if self.style_observation not in MODES:
            raise ValueError(f"style_observation must be one of {MODES}, got {self.style_observation!r}")
        if self.action not in ACTIONS:
            raise ValueError(f"action must be one of {ACTIONS}, got {self.action!r}")
        for name in ("steps", "n_steps", "batch_size", "n_epochs", "select_episodes"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        v = self.select_every
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise ValueError(f"select_every must be an integer >= 1 (environment steps) or None, got {v!r}")
        v = self.select_seed
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ValueError(f"select_seed must be an integer >= 0, got {v!r}")
        for name in ("residual_scale", "learning_rate"):
            number(name, getattr(self, name), low=0.0, allow_equal=False)
        number("log_std_init", self.log_std_init)
        if self.action == "idm-speed" and not self.residual_scale < 1:
            raise ValueError(f"residual_scale is the largest change of the desired-speed factor with action "
                             f"'idm-speed': it must be in (0, 1), got {self.residual_scale!r}")
        if self.max_change is not None:
            number("max_change", self.max_change, low=0.0, allow_equal=False)
        g = self.gamma
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not 0 < g <= 1:
            raise ValueError(f"gamma must be in (0, 1], got {g!r}")
        for name in ("use_sde", "observe_residual"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if self.observe_residual and self.action == "direct":
            raise ValueError("observe_residual shows the agent what its action changes: it needs a residual or the "
                             f"'idm-speed' action, not {self.action!r}")


#: sweep name -> policy class (pseudo-learners of this scenario, `pirl_sim.engine.config.sweep_learners`)
POLICIES = {c.name: c for c in (HoldSpeedEgo, IdmEgo, MpcEgo, PPOEgo)}


# ------------------------------------------------------------------------------------------ one cell

def env_config(params: dict, mode: str = "none", learner=None) -> dict:
    """The env's configuration of a cell (the scenario's traffic and reward, an observation mode)."""
    return {"reward": params["reward"], "initial_vehicles": params["initial_vehicles"],
            "duration": params["duration"], "population": {"depart_interval": params["depart_interval"]},
            "style_observation": mode, "style_learner": learner if mode == "inferred" else None}


_LEARNERS: dict = {}  # fitted style learners of this process, by (learner_seed, depart_interval)


def fit_style_learner(learner_seed: int, depart_interval: float):
    """PIRL-kNN (receding-horizon IRL, 2 s windows, k = 10) fitted on the PIRL tracks of one highway-env scenario
    recording of the env's population (seed ``learner_seed``, not an env seed): the ``"inferred"`` mode's style
    learner. Kept per process (about 10 s to fit; learners over route-set models are not savable yet)."""
    key = (int(learner_seed), float(depart_interval))
    if key not in _LEARNERS:
        from pirl_sim.learners import make_learner
        from pirl_sim.scenarios.highway.scenario import HighwayScenarioConfig, run_highway_scenario
        from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, population_from_dict

        pop = population_from_dict({**DEFAULT_POPULATION.to_dict(), "depart_interval": depart_interval})
        run = run_highway_scenario(HighwayScenarioConfig(population=pop), seed=learner_seed)
        _LEARNERS[key] = make_learner("pirl-knn", model=run.model, n_neighbors=10, window=20, stride=5,
                                      likelihood="receding", horizon=30).fit(run.demonstrations(selection="steps"))
    return _LEARNERS[key]


def episode(env, act, seed: int, on_reset=None) -> dict:
    """One evaluation episode (`pirl_sim.envs.baselines.drive_episode`) as a cell stores it: ``eval_seed``,
    ``return``, ``arrived``, ``crashed``, ``time`` [s], ``time_to_exit`` [s] (None unless it arrived), and the
    exit reward's terms summed over the episode, unweighted (`pirl_sim.envs.baselines.EPISODE_TERMS`:
    ``progress_time``, ``near_miss_time``, ``comfort_acc_time``, ``comfort_jerk_time``,
    ``comfort_lateral_time`` [s])."""
    from pirl_sim.envs.baselines import EPISODE_TERMS, drive_episode

    e = drive_episode(env, act, seed, on_reset=on_reset)
    return {"eval_seed": e["seed"], "return": e["return"], "arrived": e["arrived"], "crashed": e["crashed"],
            "time": e["time"], "time_to_exit": e["time"] if e["arrived"] else None,
            **{k: e[k] for k in EPISODE_TERMS}}


def _scripted(params: dict, name: str, lp: dict) -> dict:
    import gymnasium as gym

    import pirl_sim.envs  # noqa: F401  (registers the env)
    from pirl_sim.envs.baselines import make_baseline

    env = gym.make(ENV_ID, config=env_config(params)).unwrapped
    policy = make_baseline(name, {"speed_dev": lp["speed_dev"], "acc_sq": lp["acc_sq"]} if name == "mpc" else None)
    episodes = [episode(env, lambda obs: policy.act(env), s, policy.reset) for s in eval_seeds(params)]
    env.close()
    return {"policy": name, "mode": "", "episodes": episodes, "curve": [], "train_time_s": 0.0}


def _ppo(params: dict, lp: dict, seed: int) -> dict:
    """Train and evaluate PPO with torch on one thread (small networks on a shared machine; restored after)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _ppo_run(params, lp, seed)
    finally:
        torch.set_num_threads(threads)


def _ppo_run(params: dict, lp: dict, seed: int) -> dict:
    import gymnasium as gym
    import numpy as np
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.monitor import Monitor

    import pirl_sim.envs  # noqa: F401  (registers the env)
    from pirl_sim.envs.baselines import DesiredSpeedAction, ResidualAction

    mode = lp["style_observation"]
    learner_time = 0.0
    learner = None
    if mode == "inferred":
        t0 = time.perf_counter()
        fresh = (params["learner_seed"], float(params["depart_interval"])) not in _LEARNERS
        learner = fit_style_learner(params["learner_seed"], params["depart_interval"])
        learner_time = time.perf_counter() - t0 if fresh else 0.0

    def make_env():
        env = gym.make(ENV_ID, config=env_config(params, mode, learner))
        if lp["action"] == "idm-speed":
            env = DesiredSpeedAction(env, lp["residual_scale"], max_change=lp["max_change"],
                                     observe=lp["observe_residual"])
        elif lp["action"] != "direct":
            env = ResidualAction(env, "idm", lp["residual_scale"], shield=lp["action"].startswith("shielded"),
                                 max_change=lp["max_change"], observe=lp["observe_residual"])
        return gym.wrappers.FlattenObservation(env)

    t0 = time.perf_counter()
    env = Monitor(make_env())
    model = PPO("MlpPolicy", env, n_steps=lp["n_steps"], batch_size=lp["batch_size"], n_epochs=lp["n_epochs"],
                gamma=lp["gamma"], learning_rate=lp["learning_rate"], use_sde=lp["use_sde"], seed=seed, verbose=0,
                device="cpu", policy_kwargs={"log_std_init": lp["log_std_init"]})
    model.set_logger(Logger(folder=None, output_formats=[]))  # no SB3-<date> folder in the temp directory

    def act(obs):
        return model.predict(obs, deterministic=True)[0]

    selection, select_time = [], 0.0
    if lp["select_every"] is None:
        model.learn(total_timesteps=lp["steps"])
    else:  # train in chunks; after each, score the policy on the validation episodes and keep the best
        val_env, best = make_env(), (-math.inf, None)
        while model.num_timesteps < lp["steps"]:
            model.learn(total_timesteps=min(lp["select_every"], lp["steps"] - model.num_timesteps),
                        reset_num_timesteps=model.num_timesteps == 0)
            t1 = time.perf_counter()
            score = float(np.mean([episode(val_env, act, s)["return"] for s in select_seeds(lp)]))
            select_time += time.perf_counter() - t1
            selection.append([int(model.num_timesteps), score])
            if score > best[0]:
                best = (score, copy.deepcopy(model.policy.state_dict()))  # type: ignore[assignment]
        val_env.close()
        model.policy.load_state_dict(best[1])  # type: ignore[arg-type]
    train_time = time.perf_counter() - t0
    ends = np.cumsum(env.get_episode_lengths())
    curve = [[int(n), float(r)] for n, r in zip(ends, env.get_episode_rewards())]
    env.close()
    eval_env = make_env()
    episodes = [episode(eval_env, act, s) for s in eval_seeds(params)]
    eval_env.close()
    out = {"policy": f"ppo {lp['action']}", "mode": mode, "episodes": episodes, "curve": curve,
           "train_time_s": train_time, "learner_time_s": learner_time}
    if selection:
        out.update(selection=selection, selected_steps=max(selection, key=lambda c: c[1])[0],
                   select_time_s=select_time)
    return out


def select_seeds(lp: dict) -> list[int]:
    """The validation episodes' env seeds of a PPO cell with model selection (``select_every``), else []."""
    if lp.get("select_every") is None:
        return []
    return list(range(lp["select_seed"], lp["select_seed"] + lp["select_episodes"]))


def run_agent_cells(specs: list[dict]) -> list[tuple[dict, dict]]:
    """Run cells of the ``agents`` scenario (`pirl_sim.engine.worker.run_cells` calls it; each cell alone): (scores,
    timings) per spec, see the module doc."""
    out = []
    for spec in specs:
        params, lp, seed = spec["scenario_params"], spec["learner_params"], spec["seed"]
        if spec["learner"] not in POLICIES:
            raise ValueError(f"the agents scenario runs the policies {tuple(POLICIES)}, got {spec['learner']!r}")
        t0 = time.perf_counter()
        if spec["learner"] == "ppo":
            evals, vals = eval_seeds(params), select_seeds(lp)
            if seed in evals or seed in vals:
                also = f" or validation seeds {vals[0]}..{vals[-1]}" if vals else ""
                raise ValueError(f"training seed {seed} is one of the evaluation seeds {evals[0]}..{evals[-1]}{also}: "
                                 "use other seeds")
            if set(vals) & set(evals):
                raise ValueError(f"validation seeds {vals[0]}..{vals[-1]} (select_seed, select_episodes) overlap the "
                                 f"evaluation seeds {evals[0]}..{evals[-1]}: choose another select_seed")
            result = _ppo(params, lp, seed)
        else:
            result = _scripted(params, spec["learner"], lp)
        out.append((result, {"fit_s": result["train_time_s"], "evaluate_s": time.perf_counter() - t0
                             - result["train_time_s"]}))
    return out


#: the agents kind
SPEC = ScenarioSpec(
    "agents", "egos on pirl_sim/Roundabout-v0 trained with PPO or scripted, evaluated on fixed episodes (module "
    "pirl_sim.experiments.agents)",
    _PARAMS, _check, None, lambda params: TrainShape(0, (), exact=False),
    run_cells=run_agent_cells, check_protocol=_check_protocol, learners=tuple(POLICIES),
    code=("pirl_sim.experiments.agents", "pirl_sim.envs.*"),
)
