"""Agents in a crowd of known styles: PPO on ``pirl_sim/Roundabout-v0`` per observation mode, against scripted egos.

    pirl-sim agents --out results/agents --workers 2     # the committed experiment
    pirl-sim agents --out /tmp/a --steps 512 --seeds 0 --episodes 2   # a tiny run

One command trains stable-baselines3's PPO on the env's ``"exit"`` reward in dense traffic (12 vehicles at
reset, one departure every 2 s on average) for every observation mode (``style_observation``: none, truth,
inferred) and training seed, evaluates each trained policy (deterministic actions) on the same fixed evaluation
seeds as the scripted baselines (:mod:`pirl_sim.envs.baselines`: hold speed, IDM, MPC with the "tracks desired
speed" weights), and writes under ``--out``. The runs are cells of the sweep engine's ``agents`` scenario
(:mod:`pirl_sim.experiments.agents`, config :func:`sweep_data`), run by `pirl_sim.engine.presets.run_agents` on
``--workers`` worker processes:

- ``cells/<key>.json``, ``sweep.json``: the sweep's store, one file per finished run, written atomically when it
  finishes (evaluation episodes, training curve, timings, the settings it ran with). A rerun keeps finished
  runs, so an interrupted experiment resumes where it stopped; a run whose settings or code changed is redone.
- ``episodes.csv``: every evaluation episode (policy, mode, training seed, evaluation seed, return, arrived,
  crashed, time [s], time to exit [s] for arriving episodes, and the exit reward's unweighted terms summed
  over the episode [s]: progress time, near-miss time, the comfort term's acceleration, jerk and lateral parts).
- ``table.csv`` / ``table.md``: per policy, mean return, success rate, time to exit, collision rate and
  near-miss time with 95 % intervals, and PPO's paired difference in return against each baseline on the
  same evaluation seeds.
- ``terms.csv``: where each policy's return comes from: the mean of each weighted term of the exit reward
  (progress, time, acceleration, jerk, lateral acceleration, near misses, collision, arrival) per episode.
- ``learning_curves.png``: training-episode returns against environment steps, per mode (mean over training
  seeds, band min to max), with the baselines' mean evaluation returns as lines.
- ``README.md``: settings, table, wall time.

PPO's action (``--action``). ``"idm-speed"`` (default, :class:`~pirl_sim.envs.baselines.DesiredSpeedAction`):
the factor on the IDM ego's desired speed, ``1 + residual_scale * action`` times v_des(s) (``residual_scale``
0.3: between 0.7 and 1.3 times v_des), moving towards the action's target by at most ``max_change`` (0.05) per
0.2 s step, applied from the ring on (on the approach the ego drives as the IDM ego); the acceleration is the
IDM's towards that speed behind the ego's leader and with the traffic's gap acceptance, so every action keeps
the IDM's gaps and yielding and action 0 drives as the IDM ego. How it was chosen: on design-probe seeds with the
factor applied everywhere (``--modes none --direct-modes '' --baselines idm --eval-seed 3000 --episodes 50
--action idm-speed --residual-scale S``; 3 training seeds, env seeds 3000-3049, where
the IDM ego scores -13.2 and misses 5 exits): S = 0.3: -10.3, Δreturn vs IDM +2.9 [0.4, 5.4]; S = 0.5: -9.0,
+4.2 [0.5, 8.0]; S = 0.7: -9.5, +3.7 [0.4, 7.0]; no collision in those 450 episodes. The first full run with
S = 0.5 applied everywhere then beat the IDM ego's return on the evaluation seeds but collided in up to 2 of
200 episodes per training seed (9 in the 1,600 episodes of the 8 runs it finished), at the entry 6-8 s in: the
traffic's gap acceptance sends a vehicle that can no longer stop before the line into the ring whatever the
conflict, and a faster approach gets there more often. That result on the evaluation seeds prompted the
ring-only factor; ad-hoc scans with constant factors on env seeds 3000-3199 (not in the repository) showed the
same collisions at the entry and, at the highest factors, at the exit's diverge, and set S = 0.3.

``"shielded-residual-idm"`` (:class:`~pirl_sim.envs.baselines.ResidualAction`): a
correction of at most ``residual_scale`` (1 action unit: 3 m/s^2 up, 4 m/s^2 down) to the IDM ego's
acceleration, rate-limited by ``max_change`` (0.1 units in that run) and capped by the traffic's leader and yielding
limits; in a run of 200 evaluation episodes it was level with the IDM ego in return (-0.5
[-1.2, 0.3]), paying in acceleration, jerk and lateral comfort what it gained in time. ``"residual-idm"``: the
same without cap and rate limit; ``"direct"``: the env's acceleration itself (``--direct-modes``: the modes that
also train it, as a reference). Measured on one training seed (``--seeds 0 --episodes 10 --modes none
--direct-modes '' --baselines idm`` and the action's options; IDM ego: return -16.9, 9 of 10 arrive, 29.6 s to
exit, no crash): the plain residual ended below the IDM (``--action residual-idm --max-change none``, scale
0.25: -18.4, one crash; scale 0.5: -19.7, 26.5 s, two crashes); capped at scale 1 without the rate limit it
arrived 10 of 10 in 26.2 s without a crash but scored -17.8; with the rate limit -11.4, 27.0 s.

Observation of what the action changes (``--observe-residual``, the default; ``--no-observe-residual``): with
``"idm-speed"`` the agent also sees the desired-speed factor in force and v_des(s) / v_max here
(``DesiredSpeedAction(observe=True)``; not probed without). The residual agent also observes what it corrects,
the IDM ego's action for the coming step, its correction in force and the shield's cap
(``ResidualAction(observe=True)``; with the rate limit the correction is state the agent could not see otherwise).
Chosen on design-probe seeds, not on the evaluation seeds: ``--modes none --direct-modes '' --baselines idm
--eval-seed 3000`` (3 training seeds, 20 episodes of env seeds 3000-3019; 275 s and 295 s) gave return -12.3
[-25.4, 0.8] with it against -15.4 [-27.1, -3.7] without (IDM ego -16.1), Δreturn vs IDM +3.9 [-3.9, 11.7] against
+0.7 [-5.3, 6.8], 58 against 54 of 60 episodes arriving, one collision against none.

Model selection (``--select-every N``, off by default): PPO's policy is checked every N environment steps on
``--select-episodes`` validation episodes (env seeds 2000, 2001, ...) and the best check's policy is evaluated.
Measured with ``--modes none --direct-modes '' --baselines idm --workers 2 --select-every 5000`` (3 training seeds,
10 validation episodes, 8 checks per run; 379 s; without the residual observation): return -17.8 against -16.6
for the last policies of the same training runs (the table committed before the residual observation), Δreturn
vs IDM -0.76 [-4.31, 2.79], one collision in 60 episodes: 10 validation episodes rank these policies no better
than chance (training seed 0's last policy scored -15.6 on them, worst of its checks, and -14.2 on the
evaluation episodes, better than the selected check's -15.3).

Intervals. Returns and times: Student-t 95 % intervals; for PPO over the training seeds' mean returns (each
seed's mean over the evaluation episodes: the seeds are the independent replicates), for the baselines over
the evaluation episodes. Success and collision rates: Wilson 95 % intervals over the pooled episodes. Paired
differences: per evaluation seed, PPO's return (mean over training seeds) minus the baseline's, t-interval over
the evaluation seeds; the same for the time to exit, over the evaluation seeds on which the baseline and at
least one training seed's policy arrived (PPO's time the mean over its arriving seeds).

The style learner of the ``"inferred"`` mode is PIRL-kNN (receding-horizon IRL, 2 s windows, k = 10) fitted
on the PIRL tracks of one highway-env scenario recording of the env's population (seed
``learner_seed``, not an env seed), refitted in each worker process (about 10 s; learners over route-set
models are not yet savable by ``learners/model_io``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pirl_sim.evaluation.stats import ci95
from pirl_sim.evaluation.tables import markdown
from pirl_sim.io.atomic import atomic_write_text
from pirl_sim.validation import int_at_least, number
from pirl_sim.experiments.agents import ACTIONS, MODES, PPOEgo

__all__ = ["AgentsConfig", "MODES", "ACTIONS", "BASELINE_POLICIES", "sweep_data", "ExperimentResult",
           "collect_records", "write_results", "terms_table", "terms_markdown"]

BASELINE_POLICIES = ("hold-speed", "idm", "mpc")  #: scripted egos (:data:`pirl_sim.envs.baselines.BASELINES`)
DEFAULT_COMMAND = "pirl-sim agents --out results/agents"  #: the committed experiment's command
#: PPO's action -> its default ``residual_scale`` (the residuals' in action units, the desired-speed factor's)
DEFAULT_SCALES = {"residual-idm": 1.0, "shielded-residual-idm": 1.0, "idm-speed": 0.3, "direct": 1.0}


@dataclass(frozen=True)
class AgentsConfig:
    """Settings of the experiment (validated on construction; ``ValueError`` naming the value).

    Attributes
    ----------
    modes : tuple of str
        Observation modes to train (:data:`MODES`).
    action : str
        PPO's action (:data:`ACTIONS`).
    direct_modes : tuple of str
        Observation modes in which PPO also learns the direct action (a reference: what the residual buys);
        empty: none.
    residual_scale : float or None
        With a residual action: the largest correction, in action units (> 0); with ``"idm-speed"``: the largest
        change of the IDM's desired-speed factor, in (0, 1). None: the action's default
        (:data:`DEFAULT_SCALES`).
    max_change : float or None
        The largest change of the correction (or factor) per agent step (> 0; the action sets its target);
        None: unbounded.
    seeds : tuple of int
        Training seeds (PPO's and its env's), >= 0.
    steps : int
        Environment steps of PPO training per run (agent steps of 0.2 s).
    eval_seeds : tuple of int
        Env seeds of the evaluation episodes (the same for every policy): consecutive integers, disjoint from
        ``seeds``. 200 by default: with 50 the paired interval of PPO's return against the IDM ego's was
        about +-1.7 wide, wider than the differences it had to decide, as the baselines' rare missed exits
        (-10 each) dominate the spread.
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
    observe_residual : bool
        PPO also observes what its action changes: with a residual action the IDM ego's action, its correction in
        force and the shield's cap (`pirl_sim.envs.baselines.ResidualAction`'s ``observe``), with ``"idm-speed"``
        the desired-speed factor in force and v_des here (`pirl_sim.envs.baselines.DesiredSpeedAction`'s
        ``observe``); the direct runs never do.
    select_every : int or None
        Model selection: every this many environment steps (and at the end) the policy is scored on
        ``select_episodes`` validation episodes (env seeds from ``select_seed``, disjoint from ``eval_seeds`` and
        ``seeds``) and the best one is evaluated (`pirl_sim.experiments.agents.PPOEgo`); None: the last policy.
    select_episodes : int
    select_seed : int
    """

    modes: tuple[str, ...] = MODES
    action: str = "idm-speed"
    direct_modes: tuple[str, ...] = ("none",)
    residual_scale: float | None = None
    max_change: float | None = 0.05
    seeds: tuple[int, ...] = (0, 1, 2)
    steps: int = 80_000
    eval_seeds: tuple[int, ...] = tuple(range(1000, 1200))
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
    observe_residual: bool = True
    select_every: int | None = None
    select_episodes: int = 10
    select_seed: int = 2000

    def __post_init__(self) -> None:
        if self.residual_scale is None and self.action in DEFAULT_SCALES:
            object.__setattr__(self, "residual_scale", DEFAULT_SCALES[self.action])
        for name, allowed in (("modes", MODES), ("direct_modes", MODES), ("baselines", BASELINE_POLICIES)):
            values = tuple(getattr(self, name))
            bad = [v for v in values if v not in allowed]
            if bad or len(set(values)) != len(values) or (name == "modes" and not values):
                raise ValueError(f"{name} must be distinct values out of {allowed}, got {list(values)}")
            object.__setattr__(self, name, values)
        check_training_fields(self, integers={"initial_vehicles": 0, "learner_seed": 0},
                              positive=("depart_interval", "duration"), flags=())
        PPOEgo(action=self.action, **ppo_params(self))._check_common()  # PPO's own settings, as the sweep checks them
        first = self.eval_seeds[0]
        if self.eval_seeds != tuple(range(first, first + len(self.eval_seeds))):
            raise ValueError(f"eval_seeds must be consecutive integers, got {list(self.eval_seeds)}")
        if self.select_every is not None:
            vals = set(range(self.select_seed, self.select_seed + self.select_episodes))
            clash = sorted(vals & (set(self.eval_seeds) | set(self.seeds)))
            if clash:
                last = self.select_seed + self.select_episodes - 1
                raise ValueError(f"the validation seeds {self.select_seed}..{last} (select_seed, select_episodes) "
                                 f"must differ from the evaluation and training seeds; both have {clash}")


#: AgentsConfig fields that are `pirl_sim.experiments.agents.PPOEgo` parameters of the same name
PPO_FIELDS = ("residual_scale", "max_change", "steps", "n_steps", "batch_size", "n_epochs", "gamma", "learning_rate",
              "log_std_init", "use_sde", "observe_residual", "select_every", "select_episodes", "select_seed")


def ppo_params(cfg) -> dict:
    """PPO's parameters of every PPO run of the experiment (the action and observation mode aside)."""
    return {k: getattr(cfg, k) for k in PPO_FIELDS}


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
        int_at_least(name, getattr(cfg, name), low)
    for name in positive:
        number(name, getattr(cfg, name), low=0, allow_equal=False)
    if isinstance(cfg.gamma, bool) or not isinstance(cfg.gamma, (int, float)) or not 0 < cfg.gamma <= 1:
        raise ValueError(f"gamma must be in (0, 1], got {cfg.gamma!r}")
    for name in flags:
        if not isinstance(getattr(cfg, name), bool):
            raise ValueError(f"{name} must be true or false, got {getattr(cfg, name)!r}")


# ------------------------------------------------------------------------------------------ the experiment

def sweep_data(cfg: AgentsConfig) -> dict:
    """The experiment as sweep config data over the ``agents`` scenario (`pirl_sim.experiments.agents`; a mapping
    for `pirl_sim.engine.config.parse_config`): PPO for every observation mode (and ``direct_modes`` with the
    direct action) and training seed, the scripted egos once."""
    params = {"initial_vehicles": cfg.initial_vehicles, "depart_interval": cfg.depart_interval,
              "duration": cfg.duration, "reward": "exit", "eval_episodes": len(cfg.eval_seeds),
              "eval_seed": cfg.eval_seeds[0], "learner_seed": cfg.learner_seed}
    ppo = ppo_params(cfg)
    learners = [{"name": "ppo", "label": f"ppo {cfg.action}", "params": {**ppo, "action": cfg.action},
                 "grid": {"style_observation": list(cfg.modes)}}]
    if cfg.direct_modes and cfg.action != "direct":
        learners.append({"name": "ppo", "label": "ppo direct", "params": {**ppo, "action": "direct",
                                                                          "observe_residual": False},
                         "grid": {"style_observation": list(cfg.direct_modes)}})
    experiments = [{"scenario": "agents", "label": "ppo", "params": params, "seeds": list(cfg.seeds),
                    "protocols": ["paper"], "learners": learners}]
    if cfg.baselines:  # deterministic: one cell each
        experiments.append({"scenario": "agents", "label": "scripted", "params": params, "seeds": [cfg.seeds[0]],
                            "protocols": ["paper"], "learners": list(cfg.baselines)})
    return {"name": "agents", "description": "PPO against scripted egos on pirl_sim/Roundabout-v0",
            "experiments": experiments}


@dataclass
class ExperimentResult:
    """Every run's record (finished now or kept from the store), and what was run now (cell labels)."""

    records: list[dict]
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    wall_time_s: float = 0.0


def collect_records(cells, keys, records: dict, computed, wall_time_s: float = 0.0) -> ExperimentResult:
    """Every run's record from a finished sweep of :func:`sweep_data`'s config: its ``cells`` and their ``keys``
    (config order), the stored ``records`` {key: record} and the keys ``computed`` now; each record has policy,
    mode, seed (-1 for scripted egos), episodes, curve, train_time_s, wall_time_s."""
    result = ExperimentResult(records=[], wall_time_s=wall_time_s)
    computed = set(computed)
    for cell, key in zip(cells, keys):
        rec = records[key]
        res = rec["result"]
        scripted = not res["policy"].startswith("ppo")
        record = {**res, "seed": -1 if scripted else cell.seed, "wall_time_s": rec["timings"]["cell_s"],
                  "episodes": [{**e, "time_to_exit": math.nan if e["time_to_exit"] is None else e["time_to_exit"]}
                               for e in res["episodes"]],
                  "settings": dict(cell.learner_params), "key": key}
        result.records.append(record)
        label = f"{res['policy']}" + (f" ({res['mode']}) seed {cell.seed}" if not scripted else "")
        (result.ran if key in computed else result.skipped).append(label)
    result.records.sort(key=lambda r: (r["policy"].startswith("ppo"), r["policy"],
                                       MODES.index(r["mode"]) if r["mode"] in MODES else -1, r["seed"]))
    return result


# ------------------------------------------------------------------------------------------ tables and figure

def _t_interval(x) -> tuple[float, float, float]:
    """(mean, low, high) of a Student-t 95 % interval; NaN bounds for fewer than two values."""
    x = np.asarray([v for v in x if np.isfinite(v)], dtype=float)
    m, h = (float(x.mean()), ci95(x)) if len(x) else (math.nan, math.nan)
    return m, m - h, m + h


def _wilson(k: int, n: int) -> tuple[float, float, float]:
    """(rate, low, high) of a Wilson 95 % interval for k successes in n trials."""
    if n == 0:
        return math.nan, math.nan, math.nan
    z = 1.959963984540054
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return p, (0.0 if k == 0 else centre - half), (1.0 if k == n else centre + half)  # 0 and 1 exactly, not 1e-18 off


def episodes_table(records: Sequence[dict]) -> pd.DataFrame:
    """Every evaluation episode of every record, one row each."""
    return pd.DataFrame([{"policy": f"{r['policy']} ({r['mode']})" if r["policy"].startswith("ppo") else r["policy"],
                          "mode": r["mode"], "train_seed": r["seed"], **e} for r in records for e in r["episodes"]])


def summary_table(episodes: pd.DataFrame) -> pd.DataFrame:
    """One row per policy (see the module docstring for the intervals)."""
    rows = []
    baselines = {p: g.set_index("eval_seed")[["return", "time_to_exit"]] for p, g in episodes.groupby("policy")
                 if not p.startswith("ppo")}
    for policy, g in episodes.groupby("policy", sort=False):
        ppo = policy.startswith("ppo")
        row = {"policy": policy, "train_seeds": g["train_seed"].nunique() if ppo else 0, "episodes": len(g),
               **_columns("return", _policy_interval(g, "return", ppo)),
               **_columns("success", _wilson(int(g["arrived"].sum()), len(g))),
               **_columns("time_to_exit", _policy_interval(g, "time_to_exit", ppo), "time_to_exit_s"),
               **_columns("collision", _wilson(int(g["crashed"].sum()), len(g))),
               **_columns("near_miss", _policy_interval(g, "near_miss_time", ppo), "near_miss_s")}
        if ppo:
            mine = g.groupby("eval_seed")[["return", "time_to_exit"]].mean()  # time: over arriving seeds
            for b, theirs in baselines.items():
                theirs = theirs.reindex(mine.index)
                row.update(_columns(f"vs_{b}", _t_interval((mine["return"] - theirs["return"]).to_numpy())))
                row.update(_columns(f"tte_vs_{b}", _t_interval(  # both arrived
                    (mine["time_to_exit"] - theirs["time_to_exit"]).to_numpy())))
        rows.append(row)
    return pd.DataFrame(rows)


def _policy_interval(episodes: pd.DataFrame, column: str, ppo: bool) -> tuple[float, float, float]:
    """`_t_interval` of a policy's ``column``: for PPO over the training seeds' means, for a baseline over its
    episodes."""
    return _t_interval(episodes.groupby("train_seed")[column].mean() if ppo else episodes[column])


def _columns(prefix: str, interval: tuple, mean: str | None = None) -> dict:
    """A (value, low, high) interval as the columns ``mean`` (default ``prefix``), ``prefix_lo``, ``prefix_hi``."""
    return dict(zip((mean or prefix, f"{prefix}_lo", f"{prefix}_hi"), interval))


#: columns of :func:`terms_table`: (name, episode column, sign, exit_reward weight) of each term of the return
_TERMS = (("progress", "progress_time", 1.0, "progress"), ("time", "time", -1.0, "time"),
          ("acceleration", "comfort_acc_time", -1.0, "comfort"), ("jerk", "comfort_jerk_time", -1.0, "comfort"),
          ("lateral", "comfort_lateral_time", -1.0, "comfort"), ("near miss", "near_miss_time", -1.0, "near_miss"),
          ("collision", "crashed", -1.0, "collision"), ("arrival", "arrived", 1.0, "arrival"))


def terms_table(episodes: pd.DataFrame, weights=None) -> pd.DataFrame:
    """Where each policy's return comes from: per policy the mean over its evaluation episodes (pooled over
    training seeds) of each weighted term of the ``"exit"`` reward (signed: a cost is negative), their sum
    (``total``, equal to ``return`` up to rounding) and the mean ``return``. ``weights``: the env's
    ``exit_reward`` (default :data:`~pirl_sim.envs.common.EXIT_REWARD_DEFAULTS`, the experiment's). Empty
    when the episodes lack the terms (cells stored before they were logged)."""
    from pirl_sim.envs.common import EXIT_REWARD_DEFAULTS

    w = dict(EXIT_REWARD_DEFAULTS if weights is None else weights)
    if any(col not in episodes.columns for _, col, _, _ in _TERMS):
        return pd.DataFrame()
    rows = []
    for policy, g in episodes.groupby("policy", sort=False):
        row = {"policy": policy, "episodes": len(g)}
        for name, col, sign, weight in _TERMS:
            row[name] = sign * w[weight] * float(g[col].astype(float).mean())
        row["total"] = sum(row[name] for name, *_ in _TERMS)
        row["return"] = float(g["return"].mean())
        rows.append(row)
    return pd.DataFrame(rows)


def terms_markdown(terms: pd.DataFrame) -> str:
    """:func:`terms_table` as a Markdown table ([s] per episode)."""
    columns = ["policy", *(name for name, *_ in _TERMS), "total", "return"]
    return markdown(terms[columns], lambda x: x if isinstance(x, str) else f"{x:+.2f}")


def _fmt(r, mean: str, prefix: str | None = None, digits: int = 3) -> str:
    """``r[mean]`` and, in brackets, the interval ``r[prefix_lo]``, ``r[prefix_hi]`` (prefix default: mean)."""
    x, lo, hi = (r.get(c) for c in (mean, f"{prefix or mean}_lo", f"{prefix or mean}_hi"))
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
    head += [f"Δreturn vs {c[3:]}" for c in vs] + [f"Δtime to exit vs {c[3:]} [s]" for c in vs]
    vs += [f"tte_{c}" for c in vs]
    rows = [[r["policy"], _fmt(r, "return"), _fmt(r, "success", digits=2), _fmt(r, "time_to_exit_s", "time_to_exit"),
             _fmt(r, "collision", digits=2), _fmt(r, "near_miss_s", "near_miss", 2), *(_fmt(r, c) for c in vs)]
            for _, r in table.iterrows()]
    return markdown(pd.DataFrame(rows, columns=head), str)


def learning_curves(records: Sequence[dict], path, steps: int) -> Path:
    """Training-episode returns against environment steps per mode (see the module docstring)."""
    from pirl_sim.evaluation.figures import pyplot

    plt = pyplot()
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
            means = pd.Series([c[idx == b, 1].mean() if (idx == b).any() else np.nan for b in range(len(grid))])
            curves.append(means.ffill().fillna(c[0, 1]).to_numpy())
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


def write_results(cfg: AgentsConfig, result: ExperimentResult, out, command: str) -> dict[str, Path]:
    """``episodes.csv``, ``table.csv``, ``table.md``, ``learning_curves.png``, ``README.md`` under ``out``, from
    the records of :func:`collect_records`."""
    out = Path(out)
    records = result.records
    episodes = episodes_table(records)
    table = summary_table(episodes)
    files = {"episodes": atomic_write_text(out / "episodes.csv", episodes.to_csv(index=False, float_format="%.6g")),
             "table": atomic_write_text(out / "table.csv", table.to_csv(index=False, float_format="%.6g"))}
    md = markdown_table(table)
    files["table_md"] = atomic_write_text(out / "table.md", md)
    terms = terms_table(episodes)
    if len(terms):
        files["terms"] = atomic_write_text(out / "terms.csv", terms.to_csv(index=False, float_format="%.6g"))
    files["figure"] = learning_curves(records, out / "learning_curves.png", cfg.steps)
    compute = sum(r["wall_time_s"] for r in records)
    ppo_times = [r["train_time_s"] for r in records if r["policy"].startswith("ppo")]
    learner_time = sum(r.get("learner_time_s", 0.0) for r in records)
    readme = [
        "# PPO against scripted egos on pirl_sim/Roundabout-v0 (exit reward)", "",
        f"Made by `{command}` (the sweep engine's ``agents`` scenario, `pirl_sim.experiments.agents`; finished runs are "
        "kept in `cells/`, so the same command resumes an interrupted experiment).", "",
        "Settings (`pirl_sim.experiments.agents_study.AgentsConfig`; every run's own are in its `cells/*.json`):", "",
        "```json", json.dumps({k: list(v) if isinstance(v, tuple) else v for k, v in asdict(cfg).items()}, indent=1),
        "```", "",
        "95 % intervals in brackets: returns, times to exit and near-miss times over the training seeds' means "
        "for PPO and over the evaluation episodes for the baselines (Student t); success and collision rates "
        "Wilson over the pooled episodes; Δreturn is PPO minus the baseline on the same evaluation seeds (PPO "
        "averaged over its training seeds), t over the evaluation seeds; Δtime to exit likewise over the "
        "evaluation seeds on which both arrived. Time to exit counts arriving episodes only.", "",
        md,
        *(["Where the return comes from (`terms.csv`): per policy the mean over its evaluation episodes of each "
           "weighted term of the exit reward [s] (progress along the route at v_max, minus the time, the comfort "
           "term's three parts, near misses and collisions, plus the arrival bonus); `total` is their sum, equal "
           "to the mean return up to rounding.", "", terms_markdown(terms)] if len(terms) else []),
        f"Compute: {compute:.0f} s summed over the {len(records)} runs' wall times (PPO training "
        f"{np.sum(ppo_times):.0f} s, {np.mean(ppo_times) if ppo_times else 0:.0f} s per run"
        + (f"; style learner fits {learner_time:.0f} s" if learner_time else "")
        + f"); this invocation {result.wall_time_s:.0f} s, ran {len(result.ran)}, kept {len(result.skipped)} "
        "finished runs. Shared 2-core machine, one thread for torch and BLAS per worker.", "",
        "Files: `cells/*.json` (the sweep's store, one per run), `sweep.json`, `episodes.csv`, `table.csv`, "
        "`table.md`, " + ("`terms.csv`, " if len(terms) else "") + "`learning_curves.png`.", ""]
    files["readme"] = atomic_write_text(out / "README.md", "\n".join(readme))
    return files
