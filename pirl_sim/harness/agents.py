"""Agents in a crowd of known styles: PPO on ``pirl_sim/Roundabout-v0`` per observation mode, against scripted egos.

    python3 -m pirl_sim.harness.agents --out results/agents            # the committed experiment
    python3 -m pirl_sim.harness.agents --out /tmp/a --steps 512 --seeds 0 --episodes 2   # a tiny run

One command trains stable-baselines3's PPO on the env's ``"exit"`` reward in dense traffic (12 vehicles at
reset, one departure every 2 s on average) for every observation mode
(``style_observation``: none, truth, inferred) and training seed, evaluates each trained policy
(deterministic actions) on the same fixed evaluation seeds as the scripted baselines
(:mod:`pirl_sim.envs.baselines`: hold speed, IDM, MPC with the "tracks desired speed" weights), and writes
under ``--out``:

- ``runs/<name>.json``: one file per finished (mode, seed) run or baseline, written atomically when it
  finishes (its evaluation episodes, training curve, wall time, the settings it ran with). A rerun with the
  same settings keeps and skips finished runs, so an interrupted experiment resumes where it stopped; a run
  whose settings differ is redone.
- ``episodes.csv``: every evaluation episode (policy, mode, training seed, evaluation seed, return, arrived,
  crashed, time [s], time to exit [s] for arriving episodes, near-miss time [s]).
- ``table.csv`` / ``table.md``: per policy, mean return, success rate, time to exit, collision rate and
  near-miss time with 95 % intervals, and PPO's paired difference in return against each baseline on the
  same evaluation seeds.
- ``learning_curves.png``: training-episode returns against environment steps, per mode (mean over training
  seeds, band min to max), with the baselines' mean evaluation returns as lines.
- ``README.md``: settings, table, wall time.

PPO's action (``--action``). ``"residual-idm"`` (default): a correction of at most ``residual_scale`` (0.25
action units: 0.75 m/s^2 up, 1 m/s^2 down) to the IDM ego's action
(:class:`~pirl_sim.envs.baselines.ResidualAction`), so that training starts from the IDM's driving.
``"direct"``: the env's acceleration itself. Measured on one training seed, 10 evaluation episodes: with
the direct action PPO ends below holding the speed after 20,000 steps (return -41.5 against -31.4, no episode
reaches the exit: it learns to crawl; with independent exploration noise instead of gSDE -58.6 with 4
crashes), while the residual one ends level with or above the IDM (scale 0.5: -20.4 against -16.9, faster but
2 crashes; scale 0.25: -14.4, 10 of 10 arrive, no crash).

Intervals. Returns and times: Student-t 95 % intervals; for PPO over the training seeds' mean returns (each
seed's mean over the evaluation episodes: the seeds are the independent replicates), for the baselines over
the evaluation episodes. Success and collision rates: Wilson 95 % intervals over the pooled episodes. Paired
differences: per evaluation seed, PPO's return (mean over training seeds) minus the baseline's, t-interval over
the evaluation seeds.

The style learner of the ``"inferred"`` mode is PIRL-kNN (receding-horizon IRL, 2 s windows, k = 10) fitted
on the PIRL tracks of one highway-env scenario recording of the env's population (seed
``learner_seed``, not an env seed), refitted in each process (about 10 s; learners over route-set models are
not yet savable by ``learners/model_io``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pirl_sim.io.atomic import atomic_write_text

__all__ = ["AgentsConfig", "MODES", "ACTIONS", "BASELINE_POLICIES", "run_experiment", "env_config", "fit_style_learner", "main"]

MODES = ("none", "truth", "inferred")  #: observation modes (the env's ``style_observation``)
#: what PPO's action is: ``"residual-idm"`` a correction to the IDM ego's action
#: (:class:`~pirl_sim.envs.baselines.ResidualAction`), ``"direct"`` the env's acceleration itself
ACTIONS = ("residual-idm", "direct")
BASELINE_POLICIES = ("hold-speed", "idm", "mpc")  #: scripted egos (:data:`pirl_sim.envs.baselines.BASELINES`)
ENV_ID = "pirl_sim/Roundabout-v0"
DEFAULT_COMMAND = "python3 -m pirl_sim.harness.agents --out results/agents"  #: the committed experiment's command


@dataclass(frozen=True)
class AgentsConfig:
    """Settings of the experiment (validated on construction; ``ValueError`` naming the value).

    Attributes
    ----------
    modes : tuple of str
        Observation modes to train (:data:`MODES`).
    action : str
        PPO's action (:data:`ACTIONS`).
    residual_scale : float
        With ``"residual-idm"``: the largest correction, in action units (> 0).
    seeds : tuple of int
        Training seeds (PPO's and its env's), >= 0.
    steps : int
        Environment steps of PPO training per run (agent steps of 0.2 s).
    eval_seeds : tuple of int
        Env seeds of the evaluation episodes (the same for every policy), disjoint from ``seeds``.
    baselines : tuple of str
        Scripted egos to evaluate (:data:`BASELINE_POLICIES`).
    initial_vehicles : int
        Vehicles on the road at reset.
    depart_interval : float
        [s] mean time between the traffic's departures (the population's; default population otherwise).
    duration : float
        [s] episode time limit.
    learner_seed : int
        Seed of the highway-env recording the ``"inferred"`` mode's learner is fitted on.
    n_steps, batch_size, n_epochs : int
        PPO's rollout length, minibatch size and epochs per update.
    gamma : float
        PPO's discount.
    learning_rate : float
    log_std_init : float
        Initial log standard deviation of PPO's Gaussian actions.
    use_sde : bool
        Generalised state-dependent exploration (SB3's gSDE): the exploration noise is a function of the
        observation, redrawn every rollout, so the explored accelerations change smoothly. With independent
        noise every 0.2 s the jerk of the exploration alone costs more than the rest of the comfort term.
    """

    modes: tuple[str, ...] = MODES
    action: str = "residual-idm"
    residual_scale: float = 0.25
    seeds: tuple[int, ...] = (0, 1, 2)
    steps: int = 16_000
    eval_seeds: tuple[int, ...] = tuple(range(1000, 1020))
    baselines: tuple[str, ...] = BASELINE_POLICIES
    initial_vehicles: int = 12
    depart_interval: float = 2.0
    duration: float = 40.0
    learner_seed: int = 7
    n_steps: int = 1024
    batch_size: int = 128
    n_epochs: int = 10
    gamma: float = 0.99
    learning_rate: float = 3e-4
    log_std_init: float = -2.0
    use_sde: bool = True

    def __post_init__(self) -> None:
        for name, allowed in (("modes", MODES), ("baselines", BASELINE_POLICIES)):
            values = tuple(getattr(self, name))
            bad = [v for v in values if v not in allowed]
            if bad or len(set(values)) != len(values):
                raise ValueError(f"{name} must be distinct values out of {allowed}, got {list(values)}")
            object.__setattr__(self, name, values)
        if self.action not in ACTIONS:
            raise ValueError(f"action must be one of {ACTIONS}, got {self.action!r}")
        check_training_fields(self, integers={"steps": 1, "initial_vehicles": 0, "n_steps": 1, "batch_size": 1,
                                              "n_epochs": 1, "learner_seed": 0},
                              positive=("depart_interval", "duration", "learning_rate", "residual_scale"),
                              flags=("use_sde",))
        if not (isinstance(self.log_std_init, (int, float)) and math.isfinite(self.log_std_init)):
            raise ValueError(f"log_std_init must be a finite number, got {self.log_std_init!r}")


def check_training_fields(cfg, *, integers: dict, positive: tuple, flags: tuple) -> None:
    """Validate (and normalise) the fields a PPO experiment's frozen config shares: ``seeds`` and ``eval_seeds``
    (non-empty, distinct, disjoint integers >= 0; stored as tuples of int), the ``integers`` {name: lowest
    allowed}, the finite ``positive`` numbers, ``gamma`` in (0, 1] and the boolean ``flags``; ValueError naming
    the field."""
    for name in ("seeds", "eval_seeds"):
        values = tuple(getattr(cfg, name))
        if not values or any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0 for v in values) \
                or len(set(values)) != len(values):
            raise ValueError(f"{name} must be a non-empty list of distinct integers >= 0, got {list(values)}")
        object.__setattr__(cfg, name, tuple(int(v) for v in values))
    overlap = sorted(set(cfg.seeds) & set(cfg.eval_seeds))
    if overlap:
        raise ValueError(f"training seeds and evaluation seeds must differ; both have {overlap}")
    for name, low in integers.items():
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
    for name in positive:
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
    if isinstance(cfg.gamma, bool) or not isinstance(cfg.gamma, (int, float)) or not 0 < cfg.gamma <= 1:
        raise ValueError(f"gamma must be in (0, 1], got {cfg.gamma!r}")
    for name in flags:
        if not isinstance(getattr(cfg, name), bool):
            raise ValueError(f"{name} must be true or false, got {getattr(cfg, name)!r}")


def env_config(cfg: AgentsConfig, mode: str = "none", learner=None) -> dict:
    """The env's configuration for an observation mode (the ``"exit"`` reward, the experiment's traffic)."""
    return {"reward": "exit", "initial_vehicles": cfg.initial_vehicles, "duration": cfg.duration,
            "population": {"depart_interval": cfg.depart_interval}, "style_observation": mode,
            "style_learner": learner if mode == "inferred" else None}


def fit_style_learner(cfg: AgentsConfig):
    """PIRL-kNN fitted on one highway-env recording of the env's population (see the module docstring)."""
    from pirl_sim.learners import make_learner
    from pirl_sim.scenarios.highway.scenario import HighwayScenarioConfig, run_highway_scenario
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, population_from_dict

    pop = population_from_dict({**DEFAULT_POPULATION.to_dict(), "depart_interval": cfg.depart_interval})
    run = run_highway_scenario(HighwayScenarioConfig(population=pop), seed=cfg.learner_seed)
    return make_learner("pirl-knn", model=run.model, n_neighbors=10, window=20, stride=5, likelihood="receding",
                        horizon=30).fit(run.demonstrations(selection="steps"))


# ------------------------------------------------------------------------------------------ one run

def _key(record: dict) -> str:
    return hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()[:16]


def _settings(cfg: AgentsConfig, kind: str) -> dict:
    """What a run's result depends on (its key): the env and evaluation settings, and PPO's for PPO runs."""
    env = {k: getattr(cfg, k) for k in ("eval_seeds", "initial_vehicles", "depart_interval", "duration")}
    if kind == "ppo":
        env.update({k: getattr(cfg, k) for k in ("action", "residual_scale", "steps", "learner_seed", "n_steps", "batch_size", "n_epochs",
                                                  "gamma", "learning_rate", "log_std_init", "use_sde")})
    return {k: list(v) if isinstance(v, tuple) else v for k, v in env.items()}


def _episode(env, act, seed: int, on_reset=None) -> dict:
    """One evaluation episode: ``act(obs) -> action``; ``on_reset(env)`` after the reset (baselines)."""
    obs, _ = env.reset(seed=seed)
    if on_reset is not None:
        on_reset(env)
    total, near = 0.0, 0.0
    while True:
        obs, reward, terminated, truncated, info = env.step(act(obs))
        total += float(reward)
        near += info["rewards"]["near_miss_time"]
        if terminated or truncated:
            break
    arrived = bool(info["arrived"])
    return {"eval_seed": seed, "return": total, "arrived": arrived, "crashed": bool(info["crashed"]),
            "time": float(info["time"]), "time_to_exit": float(info["time"]) if arrived else math.nan,
            "near_miss_time": near}


def _evaluate_baseline(cfg: AgentsConfig, name: str) -> dict:
    import gymnasium as gym

    import pirl_sim.envs  # noqa: F401  (registers the env)
    from pirl_sim.envs.baselines import make_baseline

    env = gym.make(ENV_ID, config=env_config(cfg)).unwrapped
    policy = make_baseline(name)
    t0 = time.perf_counter()
    episodes = [_episode(env, lambda obs: policy.act(env), seed, policy.reset) for seed in cfg.eval_seeds]
    env.close()
    return {"policy": name, "mode": "", "seed": -1, "episodes": episodes, "curve": [],
            "wall_time_s": time.perf_counter() - t0}


def _train_ppo(cfg: AgentsConfig, mode: str, seed: int, learner) -> dict:
    """`_train_ppo_run` with torch on one thread (small networks on a shared machine), the caller's thread
    count restored afterwards."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _train_ppo_run(cfg, mode, seed, learner)
    finally:
        torch.set_num_threads(threads)


def _train_ppo_run(cfg: AgentsConfig, mode: str, seed: int, learner) -> dict:
    import gymnasium as gym
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.monitor import Monitor

    import pirl_sim.envs  # noqa: F401  (registers the env)
    from pirl_sim.envs.baselines import ResidualAction

    t0 = time.perf_counter()

    def make_env():
        env = gym.make(ENV_ID, config=env_config(cfg, mode, learner))
        if cfg.action == "residual-idm":
            env = ResidualAction(env, "idm", cfg.residual_scale)
        return gym.wrappers.FlattenObservation(env)

    env = Monitor(make_env())
    model = PPO("MlpPolicy", env, n_steps=cfg.n_steps, batch_size=cfg.batch_size, n_epochs=cfg.n_epochs,
                gamma=cfg.gamma, learning_rate=cfg.learning_rate, use_sde=cfg.use_sde, seed=seed, verbose=0, device="cpu",
                policy_kwargs={"log_std_init": cfg.log_std_init})
    model.set_logger(Logger(folder=None, output_formats=[]))  # no SB3-<date> folder in the temp directory
    model.learn(total_timesteps=cfg.steps)
    train_time = time.perf_counter() - t0
    ends = np.cumsum(env.get_episode_lengths())
    curve = [[int(n), float(r)] for n, r in zip(ends, env.get_episode_rewards())]
    env.close()
    eval_env = make_env()
    episodes = [_episode(eval_env, lambda obs: model.predict(obs, deterministic=True)[0], s) for s in cfg.eval_seeds]
    eval_env.close()
    return {"policy": f"ppo {cfg.action}", "mode": mode, "seed": seed, "episodes": episodes, "curve": curve,
            "train_time_s": train_time, "wall_time_s": time.perf_counter() - t0}


# ------------------------------------------------------------------------------------------ the experiment

@dataclass
class ExperimentResult:
    """Every run's record (finished now or kept from before), and what was run now."""

    records: list[dict]
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    wall_time_s: float = 0.0
    learner_time_s: float = 0.0


def _runs(cfg: AgentsConfig) -> list[tuple[str, str, str, int]]:
    """(file name, kind, policy or mode, seed) of every run, baselines first."""
    out = [(f"baseline-{b}", "baseline", b, -1) for b in cfg.baselines]
    out += [(f"ppo-{cfg.action}-{m}-seed{s}", "ppo", m, s) for m in cfg.modes for s in cfg.seeds]
    return out


def run_experiment(cfg: AgentsConfig, out, *, log=print, command: str = DEFAULT_COMMAND) -> ExperimentResult:
    """Run (or resume) the experiment into ``out``/runs and return every record (see the module docstring);
    ``command`` is stored with each new run (the README lists the commands of its runs)."""
    runs_dir = Path(out) / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    result = ExperimentResult(records=[])
    learner = None
    for name, kind, what, seed in _runs(cfg):
        settings = _settings(cfg, kind)
        key = _key({"run": name, **settings})
        path = runs_dir / f"{name}.json"
        if path.exists():
            try:
                record = json.loads(path.read_text())
            except json.JSONDecodeError:
                record = None
            if record is not None and record.get("key") == key:
                result.records.append(record)
                result.skipped.append(name)
                log(f"{name}: finished before, kept")
                continue
        if kind == "baseline":
            record = _evaluate_baseline(cfg, what)
        else:
            if what == "inferred" and learner is None:
                t1 = time.perf_counter()
                learner = fit_style_learner(cfg)
                result.learner_time_s = time.perf_counter() - t1
                log(f"style learner fitted in {result.learner_time_s:.1f} s")
            record = _train_ppo(cfg, what, seed, learner)
        record.update({"name": name, "key": key, "settings": settings, "command": command})
        atomic_write_text(path, json.dumps(record, indent=1, allow_nan=True) + "\n")
        result.records.append(record)
        result.ran.append(name)
        log(f"{name}: done in {record['wall_time_s']:.0f} s")
    result.wall_time_s = time.perf_counter() - t0
    return result


# ------------------------------------------------------------------------------------------ tables and figure

def _t_interval(x) -> tuple[float, float, float]:
    """(mean, low, high) of a Student-t 95 % interval; NaN bounds for fewer than two values."""
    from scipy import stats

    x = np.asarray([v for v in x if np.isfinite(v)], dtype=float)
    if not len(x):
        return math.nan, math.nan, math.nan
    m = float(x.mean())
    if len(x) < 2:
        return m, math.nan, math.nan
    h = float(stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x)))
    return m, m - h, m + h


def _wilson(k: int, n: int) -> tuple[float, float, float]:
    """(rate, low, high) of a Wilson 95 % interval for k successes in n trials."""
    if n == 0:
        return math.nan, math.nan, math.nan
    z = 1.959963984540054
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return p, centre - half, centre + half


def episodes_table(records: Sequence[dict]) -> pd.DataFrame:
    """Every evaluation episode of every record, one row each."""
    rows = []
    for r in records:
        label = r["policy"] if not r["policy"].startswith("ppo") else f"{r['policy']} ({r['mode']})"
        for e in r["episodes"]:
            rows.append({"policy": label, "mode": r["mode"], "train_seed": r["seed"], **e})
    return pd.DataFrame(rows)


def summary_table(episodes: pd.DataFrame) -> pd.DataFrame:
    """One row per policy (see the module docstring for the intervals)."""
    rows = []
    baselines = {p: g.set_index("eval_seed")["return"] for p, g in episodes.groupby("policy")
                 if not p.startswith("ppo")}
    for policy, g in episodes.groupby("policy", sort=False):
        ppo = policy.startswith("ppo")
        by_seed = g.groupby("train_seed")
        ret = _t_interval(by_seed["return"].mean()) if ppo else _t_interval(g["return"])
        tte = _t_interval(by_seed["time_to_exit"].mean()) if ppo else _t_interval(g["time_to_exit"])
        near = _t_interval(by_seed["near_miss_time"].mean()) if ppo else _t_interval(g["near_miss_time"])
        n = len(g)
        succ = _wilson(int(g["arrived"].sum()), n)
        coll = _wilson(int(g["crashed"].sum()), n)
        row = {"policy": policy, "train_seeds": g["train_seed"].nunique() if ppo else 0, "episodes": n,
               "return": ret[0], "return_lo": ret[1], "return_hi": ret[2],
               "success": succ[0], "success_lo": succ[1], "success_hi": succ[2],
               "time_to_exit_s": tte[0], "time_to_exit_lo": tte[1], "time_to_exit_hi": tte[2],
               "collision": coll[0], "collision_lo": coll[1], "collision_hi": coll[2],
               "near_miss_s": near[0], "near_miss_lo": near[1], "near_miss_hi": near[2]}
        if ppo:
            mine = g.groupby("eval_seed")["return"].mean()
            for b, theirs in baselines.items():
                d = _t_interval((mine - theirs.reindex(mine.index)).to_numpy())
                row.update({f"vs_{b}": d[0], f"vs_{b}_lo": d[1], f"vs_{b}_hi": d[2]})
        rows.append(row)
    return pd.DataFrame(rows)


def _fmt(x, lo=None, hi=None, digits=3) -> str:
    if x is None or not np.isfinite(x):
        return "–"
    s = f"{x:.{digits}g}"
    if lo is not None and np.isfinite(lo) and np.isfinite(hi):
        s += f" [{lo:.{digits}g}, {hi:.{digits}g}]"
    return s


def markdown_table(table: pd.DataFrame) -> str:
    """The summary as a Markdown table (95 % intervals in brackets)."""
    head = ["policy", "return", "success", "time to exit [s]", "collisions", "near miss [s]"]
    vs = [c for c in table.columns if c.startswith("vs_") and not c.endswith(("_lo", "_hi"))]
    head += [f"Δreturn vs {c[3:]}" for c in vs]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in table.iterrows():
        cells = [r["policy"], _fmt(r["return"], r["return_lo"], r["return_hi"]),
                 _fmt(r["success"], r["success_lo"], r["success_hi"], 2),
                 _fmt(r["time_to_exit_s"], r["time_to_exit_lo"], r["time_to_exit_hi"]),
                 _fmt(r["collision"], r["collision_lo"], r["collision_hi"], 2),
                 _fmt(r["near_miss_s"], r["near_miss_lo"], r["near_miss_hi"], 2)]
        cells += [_fmt(r.get(c), r.get(f"{c}_lo"), r.get(f"{c}_hi")) for c in vs]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


def learning_curves(records: Sequence[dict], path, steps: int) -> Path:
    """Training-episode returns against environment steps per mode (see the module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    grid = np.linspace(0, steps, 41)[1:]
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    ppo = [r for r in records if r["policy"].startswith("ppo")]
    for k, (policy, mode) in enumerate(dict.fromkeys((r["policy"], r["mode"]) for r in ppo)):
        curves = []
        finals = []
        for r in (r for r in ppo if r["mode"] == mode and r["policy"] == policy):
            finals.append(np.mean([e["return"] for e in r["episodes"]]))
            c = np.array(r["curve"], dtype=float).reshape(-1, 2)
            if len(c) < 2:
                continue
            # mean return of the episodes that ended in each bin of steps (carried forward over empty bins)
            idx = np.searchsorted(grid, c[:, 0])
            vals, last = [], c[0, 1]
            for b in range(len(grid)):
                sel = c[idx == b, 1]
                last = sel.mean() if len(sel) else last
                vals.append(last)
            curves.append(vals)
        if not curves:
            continue
        curves = np.array(curves)
        col = colours[k % len(colours)]
        ax.plot(grid, curves.mean(axis=0), color=col, label=f"{policy.upper()[:3]}{policy[3:]}, {mode} "
                f"({len(curves)} seeds; dots: evaluation)")
        ax.fill_between(grid, curves.min(axis=0), curves.max(axis=0), color=col, alpha=0.2, lw=0)
        ax.plot(np.full(len(finals), grid[-1]), finals, "o", color=col, ms=4)
    styles = ["--", ":", "-."]
    for k, r in enumerate(r for r in records if not r["policy"].startswith("ppo")):
        ax.axhline(np.mean([e["return"] for e in r["episodes"]]), color="0.3", ls=styles[k % 3], lw=1,
                   label=f"{r['policy']} (evaluation mean)")
    ax.set_xlabel("environment steps (0.2 s each)")
    ax.set_ylabel("episode return (exit reward) [s]")
    ax.set_title("PPO training on pirl_sim/Roundabout-v0: mean over seeds, band min-max")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=2, fontsize=8, frameon=False)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def collect_records(cfg: AgentsConfig, out) -> list[dict]:
    """Every finished run in ``out``/runs evaluated like ``cfg``'s (same evaluation seeds and traffic): this
    invocation's and those of others into the same directory (e.g. ``--action direct``), baselines first."""
    shared = _settings(cfg, "baseline")
    records = []
    for path in sorted((Path(out) / "runs").glob("*.json")):
        try:
            record = json.loads(path.read_text())
        except json.JSONDecodeError:
            continue
        if all(record.get("settings", {}).get(k) == v for k, v in shared.items()):
            records.append(record)
    return sorted(records, key=lambda r: (r["policy"].startswith("ppo"), r["policy"],
                                          MODES.index(r["mode"]) if r["mode"] in MODES else -1, r["seed"]))


def write_results(cfg: AgentsConfig, result: ExperimentResult, out, command: str) -> dict[str, Path]:
    """``episodes.csv``, ``table.csv``, ``table.md``, ``learning_curves.png``, ``README.md`` under ``out``, from
    :func:`collect_records`."""
    out = Path(out)
    records = collect_records(cfg, out)
    episodes = episodes_table(records)
    table = summary_table(episodes)
    files = {"episodes": atomic_write_text(out / "episodes.csv", episodes.to_csv(index=False, float_format="%.6g")),
             "table": atomic_write_text(out / "table.csv", table.to_csv(index=False, float_format="%.6g"))}
    md = markdown_table(table)
    files["table_md"] = atomic_write_text(out / "table.md", md)
    files["figure"] = learning_curves(records, out / "learning_curves.png",
                                      max([r["settings"].get("steps", 0) for r in records] + [cfg.steps]))
    compute = sum(r["wall_time_s"] for r in records)
    ppo_times = [r["train_time_s"] for r in records if r["policy"].startswith("ppo")]
    commands = list(dict.fromkeys(r.get("command", DEFAULT_COMMAND) for r in records))
    readme = [
        "# PPO against scripted egos on pirl_sim/Roundabout-v0 (exit reward)", "",
        "Made by " + ", then ".join(f"`{c}`" for c in commands) + f" (tables last written by `{command}`).", "",
        "Settings of the last invocation (`pirl_sim.harness.agents.AgentsConfig`; each run's own are in its "
        "`runs/*.json`):", "",
        "```json", json.dumps({k: list(v) if isinstance(v, tuple) else v for k, v in asdict(cfg).items()}, indent=1),
        "```", "",
        "95 % intervals in brackets: returns, times to exit and near-miss times over the training seeds' means "
        "for PPO and over the evaluation episodes for the baselines (Student t); success and collision rates "
        "Wilson over the pooled episodes; Δreturn is PPO minus the baseline on the same evaluation seeds (PPO "
        "averaged over its training seeds), t over the evaluation seeds. Time to exit counts arriving episodes "
        "only.", "",
        md,
        f"Compute: {compute:.0f} s summed over the {len(records)} runs' wall times (PPO training {np.sum(ppo_times):.0f} s, "
        f"{np.mean(ppo_times) if ppo_times else 0:.0f} s per run); this invocation {result.wall_time_s:.0f} s, "
        f"ran {len(result.ran)}, kept {len(result.skipped)} finished runs"
        + (f"; the style learner was fitted in {result.learner_time_s:.0f} s" if result.learner_time_s else "")
        + ". Shared 2-core machine, one thread for torch and BLAS.", "",
        "Files: `runs/*.json` (one per run, kept on reruns), `episodes.csv`, `table.csv`, `table.md`, "
        "`learning_curves.png`.", ""]
    files["readme"] = atomic_write_text(out / "README.md", "\n".join(readme))
    return files


# ------------------------------------------------------------------------------------------ command line

def _csv_list(kind):
    def parse(text: str):
        try:
            return tuple(kind(x) for x in text.split(",") if x.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}") from None
    return parse


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python3 -m pirl_sim.harness.agents", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="results/agents", help="output directory (default results/agents)")
    ap.add_argument("--modes", type=_csv_list(str), default=MODES, help="observation modes, e.g. none,truth")
    ap.add_argument("--action", default=AgentsConfig.action, help=f"PPO's action, one of {ACTIONS}")
    ap.add_argument("--residual-scale", type=float, default=AgentsConfig.residual_scale,
                    help="largest residual correction in action units (default %(default)s)")
    ap.add_argument("--seeds", type=_csv_list(int), default=AgentsConfig.seeds, help="training seeds, e.g. 0,1,2")
    ap.add_argument("--steps", type=int, default=AgentsConfig.steps, help="PPO steps per run")
    ap.add_argument("--episodes", type=int, default=len(AgentsConfig.eval_seeds),
                    help="evaluation episodes (seeds 1000, 1001, ...)")
    ap.add_argument("--baselines", type=_csv_list(str), default=BASELINE_POLICIES)
    ap.add_argument("--n-steps", type=int, default=AgentsConfig.n_steps, help="PPO rollout length")
    args = ap.parse_args(argv)
    try:
        cfg = AgentsConfig(modes=args.modes, action=args.action, residual_scale=args.residual_scale, seeds=args.seeds, steps=args.steps, baselines=args.baselines,
                           eval_seeds=tuple(range(1000, 1000 + args.episodes)), n_steps=args.n_steps,
                           batch_size=min(AgentsConfig.batch_size, args.n_steps))
    except ValueError as exc:
        ap.error(str(exc))
    from pirl_sim.threads import blas_threads

    import sys

    command = "python3 -m pirl_sim.harness.agents " + " ".join(argv if argv is not None else sys.argv[1:])
    with blas_threads(1):
        result = run_experiment(cfg, args.out, command=command.strip())
        files = write_results(cfg, result, args.out, command.strip())
    print(markdown_table(pd.read_csv(files["table"])))
    print(f"wrote {', '.join(str(p) for p in files.values())} ({result.wall_time_s:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
