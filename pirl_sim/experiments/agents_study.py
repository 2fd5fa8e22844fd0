"""Agents in a crowd of known styles: PPO on ``pirl_sim/Roundabout-v0`` per observation mode, against scripted egos.

    pirl-sim agents --out results/agents --workers 2     # the committed experiment
    pirl-sim agents --out /tmp/a --steps 512 --seeds 0 --episodes 2   # a tiny run

One command trains stable-baselines3's PPO on the env's ``"exit"`` reward for every observation mode
(``style_observation``) and training seed and evaluates each policy and the scripted egos
(:mod:`pirl_sim.envs.baselines`) on the same evaluation seeds. The runs are cells of the sweep engine's
``agents`` scenario (:mod:`pirl_sim.experiments.agents`, config :func:`sweep_data`); :func:`write_results` writes
``episodes.csv``, ``table.csv`` / ``table.md``, ``terms.csv``, ``learning_curves.png`` and ``README.md``.

The actions and why they are chosen, the output files and the intervals are explained in the documentation's
"Agents among drivers of known styles" page.
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
    """Settings of the experiment (validated on construction; ``ValueError`` naming the value). Every attribute in full:
    the "Agents among drivers of known styles" page, "In detail: AgentsConfig and PPOEgo".

    Attributes
    ----------
    modes, direct_modes, action : tuple of str, tuple of str, str   modes to train (`MODES`); also direct; `ACTIONS`
    residual_scale, max_change : float or None   largest correction (None: `DEFAULT_SCALES`); its change per step
    seeds, steps, eval_seeds : tuple of int, int, tuple of int   training seeds; env steps of training; evaluation seeds
    baselines : tuple of str              scripted egos to evaluate (`BASELINE_POLICIES`)
    initial_vehicles, depart_interval, duration : int, float, float   vehicles at reset; [s] mean headway; [s] limit
    learner_seed : int                    seed of the highway-env recording the ``"inferred"`` learner is fitted on
    n_steps, batch_size, n_epochs, gamma, learning_rate, log_std_init, use_sde : PPO's settings (see the page)
    observe_residual, select_every, select_episodes, select_seed : bool, int or None, int, int   see the page
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
            vals = range(self.select_seed, self.select_seed + self.select_episodes)
            clash = sorted(set(vals) & (set(self.eval_seeds) | set(self.seeds)))
            if clash:
                raise ValueError(f"the validation seeds {self.select_seed}..{vals[-1]} (select_seed, select_episodes) "
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
        direct = {**ppo, "action": "direct", "observe_residual": False}
        learners.append({"name": "ppo", "label": "ppo direct", "params": direct,
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
    result, computed = ExperimentResult(records=[], wall_time_s=wall_time_s), set(computed)
    for cell, key in zip(cells, keys):
        rec = records[key]
        res = rec["result"]
        scripted = not res["policy"].startswith("ppo")
        result.records.append({
            **res, "seed": -1 if scripted else cell.seed, "wall_time_s": rec["timings"]["cell_s"],
            "episodes": [{**e, "time_to_exit": math.nan if e["time_to_exit"] is None else e["time_to_exit"]}
                         for e in res["episodes"]], "settings": dict(cell.learner_params), "key": key})
        label = res["policy"] + ("" if scripted else f" ({res['mode']}) seed {cell.seed}")
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
    z, p = 1.959963984540054, k / n
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
                diff = mine - theirs.reindex(mine.index)  # time to exit: on the seeds where both arrived
                row.update(_columns(f"vs_{b}", _t_interval(diff["return"])))
                row.update(_columns(f"tte_vs_{b}", _t_interval(diff["time_to_exit"])))
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
        terms = {name: sign * w[weight] * float(g[col].astype(float).mean()) for name, col, sign, weight in _TERMS}
        rows.append({"policy": policy, "episodes": len(g), **terms, "total": sum(terms.values()),
                     "return": float(g["return"].mean())})
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
    interval = lo is not None and np.isfinite(lo) and np.isfinite(hi)
    return f"{x:.{digits}g}" + (f" [{lo:.{digits}g}, {hi:.{digits}g}]" if interval else "")


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
    from pirl_sim.evaluation.figures import pyplot, write_png

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    grid, ppo = np.linspace(0, steps, 41)[1:], [r for r in records if r["policy"].startswith("ppo")]
    for k, (policy, mode) in enumerate(dict.fromkeys((r["policy"], r["mode"]) for r in ppo)):
        runs = [r for r in ppo if r["mode"] == mode and r["policy"] == policy]
        finals = [np.mean([e["return"] for e in r["episodes"]]) for r in runs]
        curves = [c for c in (_binned_curve(r["curve"], grid) for r in runs) if c is not None]
        if not curves:
            continue
        stacked, col = np.array(curves), f"C{k}"  # col: the colour cycle's k-th (modulo its length)
        ax.plot(grid, stacked.mean(axis=0), color=col, label=f"{policy.upper()[:3]}{policy[3:]}, {mode} "
                f"({len(stacked)} seeds; dots: evaluation)")
        ax.fill_between(grid, stacked.min(axis=0), stacked.max(axis=0), color=col, alpha=0.2, lw=0)
        ax.plot(np.full(len(finals), grid[-1]), finals, "o", color=col, ms=4)
    for k, r in enumerate(r for r in records if not r["policy"].startswith("ppo")):
        ax.axhline(np.mean([e["return"] for e in r["episodes"]]), color="0.3", ls=["--", ":", "-."][k % 3], lw=1,
                   label=f"{r['policy']} (evaluation mean)")
    ax.set(xlabel="environment steps (0.2 s each)", ylabel="episode return (exit reward) [s]",
           title="PPO training on pirl_sim/Roundabout-v0: mean over seeds, band min-max")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=2, fontsize=8, frameon=False)
    fig.tight_layout()
    path = write_png(path, fig, dpi=120)
    plt.close(fig)
    return path


def _binned_curve(curve, grid: np.ndarray) -> np.ndarray | None:
    """A training curve [(step, return), ...] on ``grid``: the mean return of the episodes that ended in each bin
    of steps, carried forward over empty bins (None for fewer than two episodes)."""
    c = np.array(curve, dtype=float).reshape(-1, 2)
    if len(c) < 2:
        return None
    idx = np.searchsorted(grid, c[:, 0])
    means = pd.Series([c[idx == b, 1].mean() if (idx == b).any() else np.nan for b in range(len(grid))])
    return means.ffill().fillna(c[0, 1]).to_numpy()


def write_results(cfg: AgentsConfig, result: ExperimentResult, out, command: str) -> dict[str, Path]:
    """``episodes.csv``, ``table.csv``, ``table.md``, ``learning_curves.png``, ``README.md`` under ``out``, from
    the records of :func:`collect_records`."""
    out, records = Path(out), result.records
    episodes = episodes_table(records)
    table = summary_table(episodes)
    md, terms = markdown_table(table), terms_table(episodes)
    files = {"episodes": atomic_write_text(out / "episodes.csv", episodes.to_csv(index=False, float_format="%.6g")),
             "table": atomic_write_text(out / "table.csv", table.to_csv(index=False, float_format="%.6g")),
             "table_md": atomic_write_text(out / "table.md", md)}
    if len(terms):
        files["terms"] = atomic_write_text(out / "terms.csv", terms.to_csv(index=False, float_format="%.6g"))
    files["figure"] = learning_curves(records, out / "learning_curves.png", cfg.steps)
    compute = sum(r["wall_time_s"] for r in records)
    ppo_times = [r["train_time_s"] for r in records if r["policy"].startswith("ppo")]
    learner_time = sum(r.get("learner_time_s", 0.0) for r in records)
    readme = [
        "# PPO against scripted egos on pirl_sim/Roundabout-v0 (exit reward)", "",
        f"Made by `{command}` (the sweep engine's ``agents`` scenario, `pirl_sim.experiments.agents`; finished runs "
        "are kept in `cells/`, so the same command resumes an interrupted experiment).", "",
        "Settings (`pirl_sim.experiments.agents_study.AgentsConfig`; every run's own are in its `cells/*.json`):", "",
        "```json", json.dumps({k: list(v) if isinstance(v, tuple) else v for k, v in asdict(cfg).items()}, indent=1),
        "```", "",
        "95 % intervals in brackets: returns, times to exit and near-miss times over the training seeds' means "
        "for PPO and over the evaluation episodes for the baselines (Student t); success and collision rates "
        "Wilson over the pooled episodes; Δreturn is PPO minus the baseline on the same evaluation seeds (PPO "
        "averaged over its training seeds), t over the evaluation seeds; Δtime to exit likewise over the "
        "evaluation seeds on which both arrived. Time to exit counts arriving episodes only.", "", md,
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
