"""Recovery tests for policies: drive the ego of ``pirl_sim/Roundabout-v0``, record it, fit its weights.

A policy of known weights drives the ego of the gymnasium env (highway backend) with ``record_tracks``; each
episode's ego track is read back as a longitudinal demonstration (`ego_demonstration`) and
:meth:`pirl_sim.recovery.RecoveryReport.from_trajectories` fits one weight vector per episode with the
receding-horizon likelihood and compares it with the policy's weights. :func:`mpc_ego_report` does this for the
scripted :class:`~pirl_sim.envs.baselines.MpcEgo`; ``pirl-sim policy-recovery`` for stable-baselines3's PPO
trained on the env's ``"theta"`` reward, as the engine kind ``policy-recovery`` (`SPEC`,
`PpoRecoveryConfig.sweep_data`, `LEARNERS`), whose cells `collect_records` gathers and `write_results` writes.

The method and the measurements are explained in the documentation's "Weight recovery on simulated runs" page
(policy recovery).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator

from . import agents
from .spec import Param, ScenarioSpec, TrainShape

__all__ = ["ENV_ID", "ego_demonstration", "mpc_ego_demonstrations", "mpc_ego_report", "PpoRecoveryConfig",
           "SPEC", "LEARNERS", "run_policy_cells", "collect_records", "write_results"]

ENV_ID = "pirl_sim/Roundabout-v0"
#: the two styles of the tests: the population presets' mean weights (speed_dev, acc_sq; jerk_sq = 1)
STYLES: dict[str, dict[str, float]] = {
    "tracks desired speed": {"speed_dev": 3.0, "acc_sq": 0.3},
    "minimises acceleration": {"speed_dev": 0.3, "acc_sq": 3.0},
}
_OWN_TOL = 1e-6  # [m/s^2] the applied acceleration is the MPC's command when this close to it


def _env_routes(env):
    from pirl_sim.envs.roundabout import _routes_for

    drv = env.config["drivers"]
    return _routes_for(env.config["roundabout_radius"], drv.smoothing, drv.speed_smoothing)[2]


def _theta_vector(theta: Mapping[str, float]) -> np.ndarray:
    """Normalised weights over the env's features (speed_dev, acc_sq, jerk_sq = 1)."""
    from pirl_sim.envs.common import reward_weights

    return reward_weights(theta)


def ego_demonstration(env, *, theta: Mapping[str, float], style_name: str, track_id: int,
                      own: np.ndarray | None = None, min_steps: int = 10):
    """The ego's track of the episode so far as a demonstration with known weights.

    Parameters
    ----------
    env : PirlRoundaboutEnv       (unwrapped) made with ``record_tracks=True``
    theta : mapping               the policy's normalised weights ``{"speed_dev", "acc_sq"}``
    style_name, track_id : str, int   the metadata ``style_name`` (a group of the report) and ``track_id`` (unique)
    own : bool array (frames,), optional   per frame: the applied action was the policy's own command;
        ``step_mask`` is it, without `~pirl_sim.scenarios.demonstrations.SETTLE_FRAMES` frames after a False
    min_steps : int               a shorter ego track raises ValueError

    Returns
    -------
    Trajectory   states (n + 1, 3) [m, m/s, m/s^2], controls (n, 1) [m/s^3], dt 0.1 s
    """
    from pirl_sim.envs.common import EGO_ID
    from pirl_sim.receding import STEP_MASK
    from pirl_sim.scenarios.demonstrations import SETTLE_FRAMES, recorded_demonstrations, settled

    demos = recorded_demonstrations(env.recording(), _env_routes(env), pirl_only=False, non_interacting=False,
                                    min_steps=min_steps)
    mine = [d for d in demos if d.metadata["agent_id"] == EGO_ID]
    if not mine:
        raise ValueError(f"the ego's track has fewer than {min_steps} steps (episode too short?)")
    d = mine[0]
    meta = {"theta": _theta_vector(theta), "style_name": str(style_name), "track_id": int(track_id)}
    if own is not None:
        first = int(d.metadata["first_frame"])  # the action of agent step k moves frame k to k + 1
        own = np.asarray(own, dtype=bool)
        if own.shape[0] < first + d.n_steps:
            raise ValueError(f"own has {own.shape[0]} steps; the ego's track needs {first + d.n_steps}")
        meta[STEP_MASK] = settled(own, SETTLE_FRAMES)[first:first + d.n_steps]
    return d.with_metadata(**meta)


class _LoggedMpcEgo:
    """:class:`~pirl_sim.envs.baselines.MpcEgo` that also says, per step, whether its action is its MPC's own
    command (not capped by the IDM limit, not handed back to IDM at a standstill, not clipped)."""

    def __init__(self, theta: Mapping[str, float]) -> None:
        from pirl_sim.envs.baselines import MpcEgo

        self.policy = MpcEgo(theta)
        self.own: list[bool] = []

    def reset(self, env) -> None:
        from pirl_sim.envs.common import EGO_ID

        self.policy.reset(env)
        self.own = []
        drivers = self.policy._drivers
        commands = drivers.commands  # type: ignore[attr-defined]
        self._last = None

        def logged(t, observations):
            out = commands(t, observations)
            self._last = out[EGO_ID]
            return out

        drivers.commands = logged  # type: ignore[attr-defined]

    def act(self, env) -> np.ndarray:
        from pirl_sim.scenarios.highway.traffic import STEP_LENGTH

        v0 = float(env.vehicle.speed)
        action = self.policy.act(env)
        cmd = self._last
        applied = env.action_type.acceleration(action)
        self.own.append(cmd is not None and abs(applied - (cmd - v0) / STEP_LENGTH) < _OWN_TOL)
        return action


def _check_env_config(config: Mapping | None) -> dict:
    if config is not None and not isinstance(config, Mapping):
        raise TypeError(f"config must be a mapping of env options, got {type(config).__name__}")
    config = dict(config or {})
    for key in ("record_tracks", "policy_frequency"):
        if key in config:
            raise ValueError(f"config sets {key!r}, which the recovery run fixes (record_tracks True, "
                             "policy_frequency 10: one action per 0.1 s frame)")
    return {**config, "record_tracks": True, "policy_frequency": 10}


def _check_seeds(label: str, seeds) -> list[int]:
    seeds = list(seeds)
    if not seeds or any(isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0 for s in seeds) \
            or len(set(seeds)) != len(seeds):
        raise ValueError(f"{label} must be a non-empty list of distinct integers >= 0, got {seeds!r}")
    return [int(s) for s in seeds]


def mpc_ego_demonstrations(policies: Mapping[str, Mapping[str, float]], seeds: Sequence[int], *,
                           ego_speeds: Sequence[float] | None = None, config: Mapping | None = None):
    """Drive the env's ego by :class:`~pirl_sim.envs.baselines.MpcEgo` of each named weight set, one episode
    per seed (``ego_speeds[i]`` [m/s]: the ego's start speed in episode i, default the env's), and record
    each ego track (:func:`ego_demonstration` with its own-command mask).

    Returns
    -------
    (model, horizon, demonstrations, episodes)
        The drivers' model and MPC horizon [steps] of the env, the demonstrations (metadata ``theta``,
        ``style_name`` = the policy's name, ``track_id``, ``step_mask``) and one dict per episode.
    """
    import gymnasium as gym

    import pirl_sim.envs  # noqa: F401  (registers the env)
    from pirl_sim.envs.baselines import drive_episode

    if not isinstance(policies, Mapping) or not policies:
        raise ValueError(f"policies must be a non-empty mapping name -> weights, got {policies!r}")
    seeds = _check_seeds("seeds", seeds)
    if ego_speeds is not None:
        ego_speeds = [float(v) for v in ego_speeds]
        if len(ego_speeds) != len(seeds) or not all(math.isfinite(v) and v >= 0 for v in ego_speeds):
            raise ValueError(f"ego_speeds must be {len(seeds)} speeds >= 0 m/s (one per seed), got {ego_speeds!r}")
    env = gym.make(ENV_ID, config=_check_env_config(config)).unwrapped
    demos, episodes = [], []  # type: ignore[var-annotated]
    try:
        for name, theta in policies.items():
            ego = _LoggedMpcEgo(theta)
            for i, seed in enumerate(seeds):
                options = None if ego_speeds is None else {"config": {"ego_speed": ego_speeds[i]}}
                ep = drive_episode(env, lambda obs: ego.act(env), seed, options=options, on_reset=ego.reset)
                d = ego_demonstration(env, theta=theta, style_name=name, track_id=len(demos), own=np.array(ego.own))
                demos.append(d)
                episodes.append({"policy": name, **ep, "own_steps": int(np.sum(ego.own))})
        model, horizon = env.road.model, int(env.config["drivers"].horizon)  # type: ignore[attr-defined]
    finally:
        env.close()
    return model, horizon, demos, episodes


def mpc_ego_report(policies: Mapping[str, Mapping[str, float]] = STYLES, seeds: Sequence[int] = (0, 1, 2, 3), *,
                   ego_speeds: Sequence[float] | None = (5.0, 8.0, 11.0, 13.0), config: Mapping | None = None,
                   stride: int = 1, **report_kwargs):
    """:func:`mpc_ego_demonstrations`, then one receding-horizon fit per episode against the policy's weights.

    Returns
    -------
    (RecoveryReport, episodes)
    """
    from pirl_sim.recovery import RecoveryReport

    model, horizon, demos, episodes = mpc_ego_demonstrations(policies, seeds, ego_speeds=ego_speeds, config=config)
    report_kwargs.setdefault("source", "MPC ego in pirl_sim/Roundabout-v0")
    return RecoveryReport.from_trajectories(model, demos, likelihood="receding", horizon=horizon, stride=stride,
                                            **report_kwargs), episodes


# ---------------------------------------------------------------------------------------------- PPO
KIND = "policy-recovery"  #: the engine kind (`SPEC`)
PPO, MPC = "ppo-theta", "mpc-theta"  #: its learners (`LEARNERS`)
#: `PpoRecoveryConfig` fields that are the kind's parameters (with the weights) and the PPO learner's
ENV_SETTINGS = ("n_vehicles", "initial_vehicles", "depart_interval", "duration")
PPO_SETTINGS = ("steps", "normalize_reward", "n_steps", "batch_size", "n_epochs", "gamma", "learning_rate",
                "log_std_init", "use_sde")
TRACK_FIELDS = ("true", "estimated", "styles", "converged", "fitted_steps")  #: per-track fields of a cell's fit


@dataclass(frozen=True)
class PpoRecoveryConfig:
    """Settings of the PPO recovery experiment (validated on construction).

    Attributes
    ----------
    theta : mapping          the ``"theta"`` reward's normalised weights {speed_dev, acc_sq} (jerk_sq = 1)
    seeds, steps : tuple of int, int   PPO training seeds (PPO's and its env's); env steps of training per seed (0.1 s)
    eval_seeds : tuple of int   env seeds of the evaluation episodes, disjoint from ``seeds``
    n_vehicles, initial_vehicles : int   vehicles of an episode's population, and those on the road at reset
    depart_interval, duration : float   [s] mean time between departures; episode time limit
    normalize_reward : bool   train on rewards scaled by a running estimate of the return's std (``VecNormalize``)
    n_steps, batch_size, n_epochs : int   PPO's rollout length, minibatch size, epochs per update
    gamma, learning_rate : float   PPO's discount (per 0.1 s step) and learning rate
    log_std_init : float     initial log standard deviation of PPO's Gaussian actions
    use_sde : bool           generalised state-dependent exploration (smooth exploration noise)
    """

    theta: tuple[tuple[str, float], ...] = (("speed_dev", 3.0), ("acc_sq", 0.3))
    seeds: tuple[int, ...] = (0, 1, 2)
    steps: int = 30_000
    eval_seeds: tuple[int, ...] = tuple(range(1000, 1010))
    n_vehicles: int = 8
    initial_vehicles: int = 2
    depart_interval: float = 8.0
    duration: float = 40.0
    normalize_reward: bool = True
    n_steps: int = 2048
    batch_size: int = 128
    n_epochs: int = 10
    gamma: float = 0.995
    learning_rate: float = 3e-4
    log_std_init: float = -1.0
    use_sde: bool = True

    def __post_init__(self) -> None:
        from pirl_sim.scenarios.population_config import FREE_FEATURES

        theta = dict(self.theta.items() if isinstance(self.theta, Mapping) else self.theta)
        if sorted(theta) != sorted(FREE_FEATURES) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
                for v in theta.values()):
            raise ValueError(f"theta must give {', '.join(FREE_FEATURES)} each a finite weight > 0, got {theta!r}")
        object.__setattr__(self, "theta", tuple((f, float(theta[f])) for f in FREE_FEATURES))
        from pirl_sim.experiments.agents_study import check_training_fields

        check_training_fields(self, integers={"steps": 1, "n_steps": 1, "batch_size": 1, "n_epochs": 1,
                                              "initial_vehicles": 0, "n_vehicles": 1},
                              positive=("duration", "learning_rate", "depart_interval"),
                              flags=("use_sde", "normalize_reward"))
        if self.initial_vehicles > self.n_vehicles:
            raise ValueError(f"initial_vehicles = {self.initial_vehicles} exceeds n_vehicles = {self.n_vehicles}")

    @property
    def theta_map(self) -> dict[str, float]:
        return dict(self.theta)

    def sweep_data(self) -> dict:
        """The study as sweep config data (`pirl_sim.engine.config.parse_config`) of the ``policy-recovery``
        kind: the MPC ego's cell (seed 0: it draws nothing) and a PPO cell per training seed."""
        params = {**self.theta_map, **{f: getattr(self, f) for f in ENV_SETTINGS}}
        evals = {"eval_seeds": list(self.eval_seeds)}
        ppo = {"name": PPO, "params": {**evals, **{f: getattr(self, f) for f in PPO_SETTINGS}}}
        return {"name": KIND, "experiments": [
            {"scenario": KIND, "label": "mpc", "params": params, "seeds": [0],
             "learners": [{"name": MPC, "params": evals}]},
            {"scenario": KIND, "label": "ppo", "params": params, "seeds": list(self.seeds), "learners": [ppo]}]}


_D = PpoRecoveryConfig


class MpcThetaEgo(BaseEstimator):
    """The kind's MPC ego of the reward's weights, driven on the env seeds ``eval_seeds``."""

    name = MPC
    scenarios = (KIND,)

    def __init__(self, eval_seeds=_D.eval_seeds, model=None, window=None, windows="first"):
        self.eval_seeds = eval_seeds
        self.model, self.window, self.windows = model, window, windows  # the engine's learner keys, unused here

    def _check_common(self) -> None:
        _check_seeds("eval_seeds", self.eval_seeds)


class PpoThetaEgo(MpcThetaEgo):
    """The kind's PPO ego: `PpoRecoveryConfig`'s settings; ``random_state`` is the training seed (the cell's)."""

    name = PPO

    def __init__(self, eval_seeds=_D.eval_seeds, steps=_D.steps, normalize_reward=_D.normalize_reward,
                 n_steps=_D.n_steps, batch_size=_D.batch_size, n_epochs=_D.n_epochs, gamma=_D.gamma,
                 learning_rate=_D.learning_rate, log_std_init=_D.log_std_init, use_sde=_D.use_sde,
                 random_state=None, model=None, window=None, windows="first"):
        super().__init__(eval_seeds, model, window, windows)
        self.steps, self.normalize_reward, self.n_steps, self.batch_size = steps, normalize_reward, n_steps, batch_size
        self.n_epochs, self.gamma, self.learning_rate = n_epochs, gamma, learning_rate
        self.log_std_init, self.use_sde, self.random_state = log_std_init, use_sde, random_state

    def _check_common(self) -> None:
        PpoRecoveryConfig(seeds=(self.random_state,), eval_seeds=self.eval_seeds,
                          **{f: getattr(self, f) for f in PPO_SETTINGS})


LEARNERS = {MPC: MpcThetaEgo, PPO: PpoThetaEgo}  #: the kind's learners, by name


def env_config(params: dict) -> dict:
    """The env's options of a cell: the ``"theta"`` reward of the kind's weights, the traffic."""
    from pirl_sim.scenarios.population_config import FREE_FEATURES

    return {"reward": "theta", "reward_theta": {f: params[f] for f in FREE_FEATURES},
            "initial_vehicles": params["initial_vehicles"], "duration": params["duration"],
            "population": {"n_vehicles": params["n_vehicles"], "depart_interval": params["depart_interval"]}}


def _train_ppo(config: dict, lp: dict, seed: int):
    """A PPO policy trained on the env's ``"theta"`` reward (torch on one thread, the caller's count restored)."""
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import pirl_sim.envs  # noqa: F401

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        env = DummyVecEnv([lambda: gym.wrappers.FlattenObservation(
            gym.make(ENV_ID, config={**config, "policy_frequency": 10}))])
        if lp["normalize_reward"]:
            env = VecNormalize(env, norm_obs=False, norm_reward=True, gamma=lp["gamma"])  # type: ignore[assignment]
        model = PPO("MlpPolicy", env, n_steps=lp["n_steps"], batch_size=lp["batch_size"], n_epochs=lp["n_epochs"],
                    gamma=lp["gamma"], learning_rate=lp["learning_rate"], use_sde=lp["use_sde"], seed=seed,
                    verbose=0, device="cpu", policy_kwargs={"log_std_init": lp["log_std_init"]})
        model.set_logger(Logger(folder=None, output_formats=[]))  # no SB3-<date> folder
        model.learn(total_timesteps=lp["steps"])
        env.close()
    finally:
        torch.set_num_threads(threads)
    return model


def _ppo_demonstrations(policy, config: dict, eval_seeds: list[int], seed: int):
    """The PPO ``policy`` of training seed ``seed`` driven deterministically on the evaluation seeds: (model,
    horizon, demonstrations, episodes) as :func:`mpc_ego_demonstrations`."""
    import gymnasium as gym

    from pirl_sim.envs.baselines import drive_episode

    env = gym.wrappers.FlattenObservation(gym.make(ENV_ID, config=_check_env_config(config)))
    base, demos, episodes = env.unwrapped, [], []  # type: ignore[var-annotated]
    for s in eval_seeds:
        ep = drive_episode(env, lambda obs: policy.predict(obs, deterministic=True)[0], s)
        episodes.append({"policy": "ppo", "train_seed": seed, **ep})
        demos.append(ego_demonstration(base, theta=config["reward_theta"], style_name=f"ppo seed {seed}",
                                       track_id=len(demos)))
    model, horizon = base.road.model, int(base.config["drivers"].horizon)  # type: ignore[attr-defined]
    env.close()
    return model, horizon, demos, episodes


def run_policy_cells(specs: list[dict]) -> list[tuple[dict, dict]]:
    """Run cells of the ``policy-recovery`` kind (`pirl_sim.engine.worker.run_cells` calls it): the cell's policy
    drives the evaluation seeds and each episode's ego track is fitted on its own.

    Returns
    -------
    list of (record, timings)
        One per spec; the record (a cell's result): ``policy`` ("ppo" or "mpc"), ``train_seed`` (-1: the MPC
        ego), ``episodes`` (``columns`` and one of ``rows`` per episode), ``fit`` (``features``, ``reference`` and
        per track :data:`TRACK_FIELDS` of its `pirl_sim.recovery.RecoveryReport`), ``train_s``, ``drive_s``,
        ``fit_s`` [s].
    """
    from pirl_sim.recovery import RecoveryReport

    out = []
    for spec in specs:
        params, lp = spec["scenario_params"], spec["learner_params"]
        config = env_config(params)
        t0 = time.perf_counter()
        if spec["learner"] == MPC:
            model, horizon, demos, episodes = mpc_ego_demonstrations({"mpc": config["reward_theta"]},
                                                                     lp["eval_seeds"], config=config)
            episodes, seed, train_s = [{**e, "train_seed": -1} for e in episodes], -1, 0.0
        else:
            seed = lp["random_state"]
            policy = _train_ppo(config, lp, seed)
            train_s = time.perf_counter() - t0
            model, horizon, demos, episodes = _ppo_demonstrations(policy, config, lp["eval_seeds"], seed)
        t1 = time.perf_counter()
        rep = RecoveryReport.from_trajectories(model, demos, likelihood="receding", horizon=horizon)
        record = {"policy": "mpc" if spec["learner"] == MPC else "ppo", "train_seed": seed,
                  "episodes": {"columns": list(episodes[0]), "rows": [list(e.values()) for e in episodes]},
                  "fit": {"features": list(rep.features), "reference": rep.reference,
                          **{k: np.asarray(getattr(rep, k)).tolist() for k in TRACK_FIELDS}},
                  "train_s": train_s, "drive_s": t1 - t0 - train_s, "fit_s": time.perf_counter() - t1}
        out.append((record, {"fit_s": record["fit_s"], "evaluate_s": t1 - t0}))
    return out


def _check(params: dict) -> dict:
    PpoRecoveryConfig(theta=env_config(params)["reward_theta"], **{f: params[f] for f in ENV_SETTINGS})
    return params


SPEC = ScenarioSpec(
    KIND, "weights recovered from PPO trained on the theta reward of pirl_sim/Roundabout-v0 and from the MPC ego of "
    "the same weights (module pirl_sim.experiments.policy_recovery)",
    {**{f: Param("float", w, f"the theta reward's normalised weight of {f} (jerk_sq 1)") for f, w in _D.theta},
     "n_vehicles": Param("int", _D.n_vehicles, "vehicles of the env's population in an episode"),
     "initial_vehicles": Param("int", _D.initial_vehicles, "of them on the road at reset"),
     "depart_interval": Param("float", _D.depart_interval, "[s] mean time between the population's departures"),
     "duration": Param("float", _D.duration, "[s] episode time limit")},
    _check, None, lambda params: TrainShape(0, (), exact=False), run_cells=run_policy_cells,
    check_protocol=agents._check_protocol, learners=(PPO, MPC),
    code=("pirl_sim.experiments.policy_recovery", "pirl_sim.envs.*"),
)


def collect_records(records: Sequence[dict]) -> dict:
    """The study's results from its cells' records (`run_policy_cells`; the PPO cells in training seed order), as
    :func:`write_results` takes them.

    Returns
    -------
    dict
        ``reports``: {"ppo": RecoveryReport (one track per (seed, evaluation episode), style = "ppo seed <s>"),
        "mpc": RecoveryReport of the MPC ego}; ``episodes``: DataFrame (policy, eval seed, return, arrived,
        crashed, time, ..., train seed); ``times``: wall times [s].
    """
    from pirl_sim.recovery import RecoveryReport

    mpc, ppo = ([r for r in records if r["policy"] == p] for p in ("mpc", "ppo"))

    def report(recs: list[dict], source: str) -> RecoveryReport:
        fit = {k: [v for r in recs for v in r["fit"][k]] for k in TRACK_FIELDS}
        return RecoveryReport(tuple(recs[0]["fit"]["features"]), fit["true"],  # type: ignore[arg-type]
                              fit["estimated"],  # type: ignore[arg-type]
                              np.arange(len(fit["styles"])), tuple(fit["styles"]),
                              fit["converged"],  # type: ignore[arg-type]
                              fit["fitted_steps"],  # type: ignore[arg-type]
                              reference=recs[0]["fit"]["reference"], source=source)

    episodes = [dict(zip(r["episodes"]["columns"], row)) for r in mpc + ppo for row in r["episodes"]["rows"]]
    times = {"mpc_drive_s": mpc[0]["drive_s"], **{f"ppo_train_seed{r['train_seed']}_s": r["train_s"] for r in ppo},
             "fit_s": sum(r["fit_s"] for r in records)}
    return {"reports": {"ppo": report(ppo, "PPO ego (theta reward)"), "mpc": report(mpc, "MPC ego (same weights)")},
            "episodes": pd.DataFrame(episodes), "times": times}


# ---------------------------------------------------------------------------------------------- files
def _csv(df: pd.DataFrame) -> str:
    return df.to_csv(index=False, float_format="%.4g", lineterminator="\n")


def write_results(result: dict, cfg: PpoRecoveryConfig, out, command: str, wall_s: float) -> dict[str, Path]:
    """Write ``summary.csv`` / ``summary.md`` / ``tracks.csv`` / ``episodes.csv`` / ``README.md`` into ``out``."""
    from pirl_sim.io.atomic import atomic_write_text

    out = Path(out)
    reports = result["reports"]
    summary = pd.concat([r.summary().assign(policy=name) for name, r in reports.items()], ignore_index=True)
    summary = summary[["policy", *[c for c in summary.columns if c != "policy"]]]
    tracks = pd.concat([r.per_track().assign(policy=name) for name, r in reports.items()], ignore_index=True)
    tracks = tracks[["policy", *[c for c in tracks.columns if c != "policy"]]]
    eps = result["episodes"]
    ok = eps.groupby("policy").agg(episodes=("seed", "size"), arrived=("arrived", "sum"), crashed=("crashed", "sum"),
                                   mean_return=("return", "mean"))
    ppo, mpc = reports["ppo"], reports["mpc"]
    lines = []
    for f in ppo.features:
        lines.append(f"- `{f}`: PPO median |log(theta_hat / theta)| {ppo.value(f, 'median'):.3g} "
                     f"[{ppo.value(f, 'median', bound='low'):.3g}, {ppo.value(f, 'median', bound='high'):.3g}] "
                     f"(x{math.exp(ppo.value(f, 'median')):.3g} off), signed median log error "
                     f"{float(np.median(ppo.log_errors[:, ppo.features.index(f)])):+.3g}; MPC ego "
                     f"{mpc.value(f, 'median'):.3g}")
    files = {
        "summary.csv": _csv(summary),
        "tracks.csv": _csv(tracks),
        "episodes.csv": _csv(eps),
        "summary.md": "## PPO ego\n\n" + ppo.to_markdown() + "\n## MPC ego (same weights, same seeds)\n\n"
                      + mpc.to_markdown(),
        "README.md": (
            "# Weights recovered from a PPO agent trained on the `theta` reward\n\n"
            f"Made by `{command}` in {wall_s:.0f} s wall time (2-core machine shared with other jobs).\n\n"
            f"PPO (stable-baselines3, direct acceleration action every 0.1 s) is trained on "
            f"`pirl_sim/Roundabout-v0` with `reward = \"theta\"`, `reward_theta = {cfg.theta_map}` (jerk_sq = 1), "
            f"{cfg.steps} steps per training seed {list(cfg.seeds)}, traffic of {cfg.n_vehicles} vehicles "
            f"({cfg.initial_vehicles} at reset, one departure every {cfg.depart_interval:g} s), rewards "
            f"{'scaled by VecNormalize' if cfg.normalize_reward else 'unscaled'}; each "
            f"trained policy then drives the evaluation seeds {cfg.eval_seeds[0]}-{cfg.eval_seeds[-1]} "
            "deterministically with `record_tracks`. Every episode's ego track is fitted on its own by the "
            "receding-horizon likelihood (the drivers' MPC horizon) and compared with `reward_theta` "
            "(`pirl_sim.recovery.RecoveryReport`); the scripted MPC ego of the same weights on the same seeds is "
            "the reference (a policy that is exactly optimal for that cost under the model).\n\n"
            "## Result\n\n" + "\n".join(lines) + "\n\n"
            "Episodes (arrived / crashed / mean return):\n\n"
            + "\n".join(f"- {p}: {int(r.episodes)} episodes, {int(r.arrived)} arrived, {int(r.crashed)} crashed, "
                        f"mean return {r.mean_return:.4g}" for p, r in ok.iterrows()) + "\n\n"
            + "## Errors per feature and training seed\n\n" + ppo.to_markdown() + "\n"
            + "## MPC ego\n\n" + mpc.to_markdown() + "\n"
            + "## Settings\n\n```json\n" + json.dumps(asdict(cfg), indent=1) + "\n```\n\n"
            + "Wall times [s]: " + ", ".join(f"{k} {v:.0f}" for k, v in result["times"].items()) + "\n"),
    }
    return {name: atomic_write_text(out / name, text) for name, text in files.items()}
