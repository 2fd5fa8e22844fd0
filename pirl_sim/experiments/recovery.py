"""Weight recovery of the receding-horizon IRL on simulated roundabouts whose drivers' weights are known.

`recovery_report` fits the receding-horizon IRL to every usable PIRL track of one recorded run (one weight
vector per track) and TIRL per style, and compares them with the true weights; `SPEC` is the engine kind
``recovery`` (a cell: one simulated run and its fit); `recovery_jobs` lists a study's runs, `recovery_result`
collects their cells and `write_recovery` writes the tables and README (``pirl-sim recover``). Every file but
``times.csv`` is a deterministic function of the seeds (floats written with 4 significant digits).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator

from pirl_sim.evaluation.tables import markdown
from pirl_sim.io.atomic import atomic_write_text

# the features whose weights differ between drivers (jerk_sq is the reference, 1 for everybody) and, for drivers who
# interact, the weights of the gaps to the vehicle ahead and to the obstacle they yield to: the populations' own
from pirl_sim.scenarios.population_config import FREE_FEATURES, INTERACTION_FEATURES

from .recovery_styles import identified, style_mixtures
from .spec import Param, ScenarioSpec, TrainShape

__all__ = ["SIMULATORS", "TARGETS", "RunRecovery", "recovery_report", "summary_row", "check_targets",
           "RecoveryJob", "recovery_jobs", "recovery_result", "RecoveryResult", "SPEC",
           "LEARNERS", "to_record", "from_record", "write_recovery", "compact_table", "FREE_FEATURES",
           "INTERACTION_FEATURES"]

#: simulators of ``pirl-sim recover`` (the ``simulator`` entry of a run's ``run.json`` in brackets):
#: sumo ("sumo"), highway ("highway-env")
SIMULATORS: tuple[str, ...] = ("sumo", "highway")
_RUN_SIMULATOR = {"sumo": "sumo", "highway-env": "highway"}
#: [m] a step is within reach of an interaction's obstacle when its gap is below the feature's safe gap plus this
#: margin plus what the car covers over the drivers' horizon at its speed (a plan can reach the obstacle; farther,
#: the weight has no measurable effect on the plan; nearer, it may still have none, see `IDENTIFIED_SE`)
NEAR_MARGIN = 3.0
#: an interaction weight of a track counts as identified (its "identified" scores) when the fit's standard error of
#: its log (`pirl_sim.receding.log_standard_errors`) is at most this and at least `MIN_NEAR_STEPS` usable steps were
#: within reach of the obstacle (`near_steps`): the track's data determine it. A car that never came near a vehicle
#: ahead leaves its headway weight undetermined (standard error large or infinite); one or two steps near it
#: determine it locally (a small standard error on noise-free data) but can leave the fit in another basin
IDENTIFIED_SE = 0.3
#: usable steps within reach of the obstacle (`near_steps`) a track needs for an interaction weight to count as
#: identified
MIN_NEAR_STEPS = 5
_FLOAT = "%.4g"

#: the recovery targets, per simulator: (column of a summary row, "<=" or ">=", threshold)
TARGETS: dict[str, tuple[tuple[str, str, float], ...]] = {
    "sumo": (
        ("median_abs_log_err_speed_dev", "<=", 0.05),
        ("median_abs_log_err_acc_sq", "<=", 0.05),
        ("p90_abs_log_err_speed_dev", "<=", 0.3),
        ("p90_abs_log_err_acc_sq", "<=", 0.3),
        ("spearman_speed_dev", ">=", 0.9),
        ("tirl_max_abs_log_err_speed_dev", "<=", 0.05),
        ("tirl_max_abs_log_err_acc_sq", "<=", 0.05),
        ("usable_fraction", ">=", 0.9),
    ),
    "highway": (
        ("median_abs_log_err_speed_dev", "<=", 0.01),
        ("median_abs_log_err_acc_sq", "<=", 0.01),
    ),
}


# ---------------------------------------------------------------------------------------------- one run
@dataclass(frozen=True, eq=False)
class RunRecovery:
    """Recovered weights of one run, per track and per style (TIRL); columns: "Weight recovery on simulated runs".

    Attributes
    ----------
    simulator : str                 "sumo" or "highway"
    seed : int
    control_noise : float           [m/s^3] standard deviation of the noise on every applied jerk
    n_pirl_tracks : int             PIRL tracks in the run (usable or not)
    tracks : pandas.DataFrame       one row per usable PIRL track (``tracks.csv``)
    styles : pandas.DataFrame       one row per style, TIRL on its usable tracks (``styles.csv``)
    selection : pandas.DataFrame    rows per style and "all"
                                    (`~pirl_sim.scenarios.demonstrations.RecordedRun.step_selection_summary`)
    fit_time_s, tirl_time_s : float   wall time [s] of the per-track fit and of the per-style TIRL fits
    weights : pirl_sim.recovery.RecoveryReport   the per-track weights as the recovery API's report
    """

    simulator: str
    seed: int
    control_noise: float
    n_pirl_tracks: int
    tracks: pd.DataFrame
    styles: pd.DataFrame
    selection: pd.DataFrame
    fit_time_s: float
    tirl_time_s: float
    weights: Any = None

    def summary(self) -> dict[str, Any]:
        """This run's row of the recovery table (:func:`summary_row`)."""
        return summary_row(self.tracks, self.styles, self.n_pirl_tracks)


def recovery_report(run, *, min_steps: int = 10, stride: int = 1) -> RunRecovery:
    """Fit per-track and per-style receding-horizon IRL to a recorded run and compare with the truth.

    Parameters
    ----------
    run : RecordedRun
        A run read back by ``load_sumo_run`` / ``load_highway_run`` (it needs ``driver_steps``).
    min_steps : int
        A PIRL track is usable when its step mask keeps at least this many steps (0.1 s each).
    stride : int
        Score every ``stride``-th usable step (:func:`pirl_sim.receding.fit_receding`).

    Returns
    -------
    RunRecovery
    """
    from pirl_sim.learners import TIRL
    from pirl_sim.receding import STEP_MASK
    from pirl_sim.recovery import RecoveryReport, fit_track_weights, run_demonstrations

    demos = run_demonstrations(run, min_steps)  # the tracks RecoveryReport.from_run fits
    RecedingRecovery(min_steps, stride)._check_common()  # the stride (min_steps: checked above)
    info = run.recording.info
    simulator = _RUN_SIMULATOR.get(info.get("simulator"))
    if simulator is None:
        raise ValueError(f"unknown simulator {info.get('simulator')!r} in the run's info")
    names = tuple(run.model.features.names)
    free_names = tuple(f for f in FREE_FEATURES + INTERACTION_FEATURES if f in names)
    free = [names.index(f) for f in free_names]
    gt = run.recording.ground_truth
    n_pirl = int(gt["is_pirl"].sum())
    selection = run.step_selection_summary(min_steps=min_steps)
    t0 = time.perf_counter()
    res = fit_track_weights(run.model, demos, likelihood="receding", horizon=run.horizon, stride=stride)
    fit_time = time.perf_counter() - t0
    truth = np.array([d.metadata["theta"] for d in demos])
    rows = {
        "track_id": [d.metadata["track_id"] for d in demos],
        "style_name": [d.metadata["style_name"] for d in demos],
        "steps": [d.n_steps for d in demos],
        "usable_steps": [int(np.sum(d.metadata[STEP_MASK])) for d in demos],
        "fitted_steps": res.fitted_steps,
    }
    for f, k in zip(free_names, free):
        rows[f"theta_{f}"] = truth[:, k]
        rows[f"theta_hat_{f}"] = res.normalized[:, k]
        rows[f"log_err_{f}"] = np.log(res.normalized[:, k] / truth[:, k])
        rows[f"se_log_{f}"] = res.log_se[:, k]
    for f in INTERACTION_FEATURES:
        if f in names:
            rows[f"{f}_steps"] = [near_steps(run.model, d, f, run.horizon) for d in demos]
    rows["sigma"] = res.sigma
    rows["converged"] = res.converged
    rows["at_bound"] = res.at_bound
    tracks = pd.DataFrame(rows)
    weights = RecoveryReport(free_names, truth[:, free], res.normalized[:, free], np.asarray(rows["track_id"]),
                             tuple(rows["style_name"]), res.converged, res.fitted_steps,  # type: ignore[arg-type]
                             reference=names[run.model.features.reference_index],
                             source=f"{simulator} seed {int(info['seed'])}")

    style_rows = []
    t0 = time.perf_counter()
    for name in sorted(set(tracks["style_name"])):
        members = [d for d in demos if d.metadata["style_name"] == name]
        tirl = TIRL(run.model, likelihood="receding", horizon=run.horizon, step_stride=stride).fit(members)
        mean = np.mean([d.metadata["theta"] for d in members], axis=0)
        row = {"style_name": name, "tracks": len(members),
               "fitted_steps": int(tirl.irl_result_.n_steps[0])}
        for f, k in zip(free_names, free):
            row[f"theta_mean_{f}"] = mean[k]
            row[f"theta_tirl_{f}"] = tirl.theta_[k]
            row[f"log_err_{f}"] = float(np.log(tirl.theta_[k] / mean[k]))
        row["sigma"] = float(tirl.irl_result_.sigma[0])
        row["converged"] = bool(tirl.irl_result_.converged[0])
        style_rows.append(row)
    tirl_time = time.perf_counter() - t0
    return RunRecovery(simulator, int(info["seed"]), float(run.control_noise), n_pirl, tracks,
                       pd.DataFrame(style_rows), selection, fit_time, tirl_time, weights)


def near_steps(model, demo, feature: str, horizon: int) -> int:
    """Usable steps of a demonstration whose gap of an interaction ``feature`` (``headway``: the vehicle ahead,
    ``yielding``: the obstacle yielded to) is within reach of a plan of ``horizon`` steps (`NEAR_MARGIN`): the
    steps that can inform its weight. A demonstration without a step mask (`pirl_sim.receding.STEP_MASK`, e.g. a
    recorded car, whose every step is its own) counts all its steps."""
    from pirl_sim.receding import STEP_MASK

    res = model.features.features[list(model.features.names).index(feature)].residual
    x = demo.states[:-1]
    reach = np.maximum(x[:, 1], 0.0) * horizon * model.dynamics.dt
    near = x[:, res.gap_index] < res.standstill + res.time_gap * x[:, 1] + NEAR_MARGIN + reach
    if STEP_MASK in demo.metadata:
        near &= np.asarray(demo.metadata[STEP_MASK], dtype=bool)
    return int(np.sum(near))


def summary_row(tracks: pd.DataFrame, styles: pd.DataFrame, n_pirl_tracks: int) -> dict[str, Any]:
    """One row of the recovery table from per-track and per-style rows (one run's, or several runs'
    concatenated: then medians, percentiles and Spearman are over the pooled tracks and the TIRL error is
    the largest over every run's styles).

    Keys: ``pirl_tracks``, ``usable_tracks``, ``usable_fraction``, ``usable_steps``, ``fitted_steps``; per
    free feature f: ``median_abs_log_err_f``, ``p90_abs_log_err_f``, ``max_abs_log_err_f``, ``spearman_f``
    (true vs fitted over the usable tracks), ``tirl_max_abs_log_err_f`` (largest over styles); ``converged``
    / ``groups`` (per-track fits), ``at_bound`` (tracks with a log weight at its bound), ``tirl_converged`` /
    ``tirl_groups``, ``sigma_median`` [m/s^3] (of the per-track fits).
    """
    from pirl_sim.recovery import spearman

    n = len(tracks)
    row: dict[str, Any] = {
        "pirl_tracks": int(n_pirl_tracks),
        "usable_tracks": int(n),
        "usable_fraction": n / n_pirl_tracks if n_pirl_tracks else math.nan,
        "usable_steps": int(tracks["usable_steps"].sum()),
        "fitted_steps": int(tracks["fitted_steps"].sum()),
    }
    features = [f for f in FREE_FEATURES + INTERACTION_FEATURES if f"log_err_{f}" in tracks]
    for f in features:
        err = np.abs(tracks[f"log_err_{f}"].to_numpy())
        row[f"median_abs_log_err_{f}"] = float(np.median(err)) if n else math.nan
        row[f"p90_abs_log_err_{f}"] = float(np.percentile(err, 90)) if n else math.nan
        row[f"max_abs_log_err_{f}"] = float(err.max()) if n else math.nan
        row[f"spearman_{f}"] = spearman(tracks[f"theta_{f}"].to_numpy(), tracks[f"theta_hat_{f}"].to_numpy())
    for f in INTERACTION_FEATURES:  # the weights of the gaps, over the tracks whose data determine them
        if f"se_log_{f}" not in tracks:
            continue
        known = tracks[identified(tracks, f, identified_se=IDENTIFIED_SE, min_near_steps=MIN_NEAR_STEPS)]
        err = np.abs(known[f"log_err_{f}"].to_numpy())
        row[f"{f}_tracks"] = int(len(known))
        row[f"median_abs_log_err_{f}_identified"] = float(np.median(err)) if len(known) else math.nan
        row[f"p90_abs_log_err_{f}_identified"] = float(np.percentile(err, 90)) if len(known) else math.nan
        row[f"spearman_{f}_identified"] = spearman(known[f"theta_{f}"].to_numpy(),
                                                   known[f"theta_hat_{f}"].to_numpy())
    for f in features:
        row[f"tirl_max_abs_log_err_{f}"] = float(np.abs(styles[f"log_err_{f}"]).max()) if len(styles) else math.nan
    row["converged"] = int(tracks["converged"].sum())
    row["groups"] = int(n)
    row["at_bound"] = int(tracks["at_bound"].sum())
    row["tirl_converged"] = int(styles["converged"].sum())
    row["tirl_groups"] = int(len(styles))
    row["sigma_median"] = float(tracks["sigma"].median()) if n else math.nan
    return row


def check_targets(row: dict[str, Any], simulator: str) -> list[tuple[str, str, float, float, bool]]:
    """The targets of :data:`TARGETS` for ``simulator`` against a summary row: (column, op, threshold,
    value, met) each."""
    if simulator not in TARGETS:
        raise ValueError(f"simulator must be one of {tuple(TARGETS)}, got {simulator!r}")
    out = []
    for col, op, limit in TARGETS[simulator]:
        value = float(row[col])
        met = value <= limit if op == "<=" else value >= limit
        out.append((col, op, limit, value, bool(met)))
    return out


# ---------------------------------------------------------------------------------------------- the engine kind
@dataclass(frozen=True)
class RecoveryJob:
    """One run of the study: a simulator, seed and control noise, and how its tracks are fitted.

    Attributes
    ----------
    simulator : {"sumo", "highway"}
    seed : int
    control_noise : float or None     [m/s^3]; None: the population's own (the main table, not the noise study)
    population : dict                 the population TOML's table (empty: the embedded default)
    n_vehicles : int or None          override the population's number of vehicles
    min_steps, stride : int           as :func:`recovery_report`
    scenario : dict                   a SUMO scenario's keys and tables besides its population (empty: the ring)
    """

    simulator: str
    seed: int
    control_noise: float | None
    population: dict = dataclasses.field(default_factory=dict)
    n_vehicles: int | None = None
    min_steps: int = 10
    stride: int = 1
    scenario: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.simulator not in SIMULATORS:
            raise ValueError(f"simulator must be one of {SIMULATORS}, got {self.simulator!r}")
        if self.control_noise is not None and not (math.isfinite(self.control_noise) and self.control_noise >= 0):
            raise ValueError(f"control_noise must be >= 0 m/s^3, got {self.control_noise!r}")

    def experiment(self) -> dict:
        """This job as an experiment of a sweep config (the ``recovery`` kind, one seed)."""
        params = {"simulator": self.simulator, "population": dict(self.population),
                  "n_vehicles": self.n_vehicles or 0,
                  "control_noise": -1.0 if self.control_noise is None else float(self.control_noise),
                  **({"scenario": dict(self.scenario)} if self.scenario else {})}
        noise = "" if self.control_noise is None else f" noise {self.control_noise:g}"
        return {"scenario": "recovery", "label": f"{self.simulator} seed {self.seed}{noise}", "params": params,
                "seeds": [self.seed],
                "learners": [{"name": LEARNER, "params": {"min_steps": self.min_steps, "stride": self.stride}}]}


LEARNER = "receding-irl"  #: the kind's one learner: per-track receding-horizon IRL and TIRL per style


class RecedingRecovery(BaseEstimator):
    """The recovery kind's learner (:func:`recovery_report`): a track is usable with at least ``min_steps``
    usable steps; every ``stride``-th of them is scored."""

    name = LEARNER
    scenarios = ("recovery",)

    def __init__(self, min_steps: int = 10, stride: int = 1, model=None, window=None, windows="first"):
        self.min_steps, self.stride = min_steps, stride
        self.model, self.window, self.windows = model, window, windows  # the engine's learner keys, unused here

    def _check_common(self) -> None:
        from pirl_sim.validation import is_positive_int

        for name in ("min_steps", "stride"):
            if not is_positive_int(getattr(self, name)):
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")


#: the learners of this kind, by name (the engine's config reads them through the registry)
LEARNERS = {LEARNER: RecedingRecovery}

RECOVERY_PARAMS = {
    "simulator": Param("choice", "sumo", "the simulator of the run", choices=SIMULATORS),
    "population": Param("table", {}, "the population (a population TOML's table); empty: the embedded default"),
    "n_vehicles": Param("int", 0, "vehicles in the run; 0: the population's own"),
    "control_noise": Param("float", -1.0, "[m/s^3] noise on every applied jerk; < 0: the population's own"),
    "scenario": Param("table", {}, "a scenario's keys and tables besides its population (a scenario TOML's of the "
                      "simulator, e.g. lanelet_map, route_weights, drivers); empty: the default ring"),
}


def _population(params: dict):
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, population_from_dict

    pop = population_from_dict(params["population"], source="scenario 'recovery' population") \
        if params["population"] else DEFAULT_POPULATION
    changes = {}
    if params["n_vehicles"]:
        changes["n_vehicles"] = int(params["n_vehicles"])
    if params["control_noise"] >= 0:
        changes["control_noise"] = float(params["control_noise"])  # type: ignore[assignment]
    return dataclasses.replace(pop, **changes) if changes else pop  # type: ignore[arg-type]


def _check(params: dict) -> dict:
    """The population validated and written out in full, its own size and noise filled in: cells of the same
    run have the same parameters (a noise level equal to the population's own is the main run)."""
    if params["n_vehicles"] < 0:
        raise ValueError(f"n_vehicles must be >= 0 (0: the population's own), got {params['n_vehicles']}")
    if not math.isfinite(params["control_noise"]):
        raise ValueError(f"control_noise must be finite, got {params['control_noise']!r}")
    pop = _population(params)
    out = {"simulator": params["simulator"], "population": json.loads(json.dumps(pop.to_dict())),
           "n_vehicles": int(pop.n_vehicles), "control_noise": float(pop.control_noise)}
    if params["scenario"]:  # written out in full (routes included); absent when empty, as before it existed
        if "population" in params["scenario"]:
            raise ValueError("scenario: give its population as the 'population' parameter, not inside 'scenario'")
        config = _scenario_config(params, pop)
        out["scenario"] = json.loads(json.dumps({k: v for k, v in config.to_dict().items() if k != "population"}))
    return out


def _scenario_config(params: dict, population):
    """The simulator's scenario configuration of the cell's scenario table (none: its default scenario) with
    ``population``."""
    from pirl_sim.scenarios.simulators import simulator_scenarios

    sim = simulator_scenarios(params["simulator"])
    if not params.get("scenario"):
        return sim.config(population=population)
    return sim.from_dict(params["scenario"], source="scenario 'recovery' scenario", population=population)


def _simulate(params: dict, seed: int, out_dir: Path) -> None:
    from pirl_sim.scenarios.simulators import simulator_scenarios

    simulator_scenarios(params["simulator"]).run(_scenario_config(params, _population(params)), seed,
                                                 out_dir=out_dir)


def _paper_only(params: dict, protocol: dict) -> None:
    if protocol.get("kind") != "paper":
        raise ValueError("recovery scores the weights of whole runs: it takes no protocol")


def to_record(report: RunRecovery) -> dict:
    """A `RunRecovery` as plain JSON data (a cell's result); `from_record` reads it back."""
    def frame(df: pd.DataFrame) -> dict:
        return json.loads(df.to_json(orient="split", double_precision=15))

    return {"simulator": report.simulator, "seed": report.seed, "control_noise": report.control_noise,
            "n_pirl_tracks": report.n_pirl_tracks, "fit_time_s": report.fit_time_s,
            "tirl_time_s": report.tirl_time_s, "tracks": frame(report.tracks), "styles": frame(report.styles),
            "selection": frame(report.selection), "summary": json.loads(pd.Series(report.summary()).to_json())}


def from_record(record: dict) -> RunRecovery:
    """The `RunRecovery` of a cell's result (`to_record`)."""
    def frame(d: dict) -> pd.DataFrame:
        return pd.DataFrame(d["data"], index=d["index"], columns=d["columns"])

    tracks, styles, selection = frame(record["tracks"]), frame(record["styles"]), frame(record["selection"])
    tracks.index = pd.RangeIndex(len(tracks))
    styles.index = pd.RangeIndex(len(styles))
    return RunRecovery(record["simulator"], int(record["seed"]), float(record["control_noise"]),
                       int(record["n_pirl_tracks"]), tracks, styles, selection, float(record["fit_time_s"]),
                       float(record["tirl_time_s"]))


def run_recovery_cells(specs: list[dict], simulation_dir: Path) -> list[tuple[dict, dict]]:
    """The cells of one recorded run (`pirl_sim.experiments.spec.ScenarioSpec.run_cells` of a simulated
    kind): :func:`recovery_report` with each cell's learner parameters."""
    from pirl_sim.scenarios.highway.scenario import load_highway_run
    from pirl_sim.scenarios.sumo.scenario import load_sumo_run

    out = []
    for spec in specs:
        load = load_sumo_run if spec["scenario_params"]["simulator"] == "sumo" else load_highway_run
        lp = spec["learner_params"]
        t0 = time.perf_counter()
        report = recovery_report(load(simulation_dir), min_steps=lp["min_steps"], stride=lp["stride"])
        out.append((to_record(report), {"fit_s": report.fit_time_s + report.tirl_time_s,
                                        "evaluate_s": time.perf_counter() - t0}))
    return out


SPEC = ScenarioSpec(
    "recovery", "weight recovery of the receding-horizon IRL on a simulated SUMO or highway-env run whose "
    "drivers' weights are known (module pirl_sim.experiments.recovery)",
    RECOVERY_PARAMS, _check, None, lambda params: TrainShape(0, (), exact=False),
    simulation=lambda params: dict(params), simulate=_simulate, run_cells=run_recovery_cells,
    check_protocol=_paper_only, learners=(LEARNER,),
    code=("pirl_sim.experiments.recovery", "pirl_sim.evaluation.tables"),
)


@dataclass(frozen=True, eq=False)
class RecoveryResult:
    """Reports of every job of :func:`run_recovery`, in job order."""

    jobs: tuple[RecoveryJob, ...]
    reports: tuple[RunRecovery, ...]
    simulated: tuple[bool, ...]
    sim_time_s: tuple[float, ...]
    stride: int
    min_steps: int
    workers: int
    blas_threads: str

    def _rows(self, noise_study: bool) -> pd.DataFrame:
        """Summary rows of the jobs with (``noise_study``) or without an explicit control noise: per
        simulator and noise level, one row per seed and, with several seeds, a pooled one."""
        groups: dict[tuple[str, float], list[RunRecovery]] = {}
        for r, j in zip(self.reports, self.jobs):
            if (j.control_noise is not None) == noise_study:
                groups.setdefault((r.simulator, r.control_noise), []).append(r)
        rows = []
        for (sim, noise), reps in sorted(groups.items(), key=lambda kv: (SIMULATORS.index(kv[0][0]), kv[0][1])):
            for r in sorted(reps, key=lambda r: r.seed):
                rows.append({"simulator": sim, "control_noise": noise, "seed": str(r.seed), **r.summary()})
            if len(reps) > 1:
                tracks = pd.concat([r.tracks for r in reps], ignore_index=True)
                styles = pd.concat([r.styles for r in reps], ignore_index=True)
                rows.append({"simulator": sim, "control_noise": noise, "seed": "pooled",
                             **summary_row(tracks, styles, sum(r.n_pirl_tracks for r in reps))})
        return pd.DataFrame(rows)

    def table(self) -> pd.DataFrame:
        """The recovery table: one row per simulator and seed, and pooled, at the population's own noise
        (the jobs with ``control_noise=None``)."""
        return self._rows(noise_study=False)

    def noise_table(self) -> pd.DataFrame:
        """Rows per simulator, control-noise level and seed (and pooled over seeds) of the noise study (the
        jobs with an explicit ``control_noise``); empty without them."""
        return self._rows(noise_study=True)

    def _unique(self) -> dict[int, tuple[RunRecovery, bool, float]]:
        """Each report once, with its first job's ``simulated`` and ``sim_time_s`` (a noise level equal to the
        population's own shares the main job's report)."""
        out = {}  # type: ignore[var-annotated]
        for r, s, t in zip(self.reports, self.simulated, self.sim_time_s):
            out.setdefault(id(r), (r, s, t))
        return out

    def _per_run(self, frame, first: tuple = ()) -> pd.DataFrame:
        """``frame(report)`` of every report, concatenated, with simulator, control_noise, seed and ``first``
        as the first columns."""
        out = pd.concat([frame(r).assign(simulator=r.simulator, control_noise=r.control_noise, seed=r.seed)
                         for r, _, _ in self._unique().values()], ignore_index=True)
        first = ["simulator", "control_noise", "seed", *first]  # type: ignore[assignment]
        return out[first + [c for c in out.columns if c not in first]]  # type: ignore[operator]

    def styles(self) -> pd.DataFrame:
        """Per-style TIRL rows of every job (simulator, control_noise, seed first)."""
        return self._per_run(lambda r: r.styles)

    def tracks(self) -> pd.DataFrame:
        """Per-track rows of every job (simulator, control_noise, seed first)."""
        return self._per_run(lambda r: r.tracks)

    def selection(self) -> pd.DataFrame:
        """Step-selection counts per rule and style of every job."""
        return self._per_run(lambda r: r.selection.reset_index().rename(columns={"index": "style_name"}),
                             ("style_name",))

    def times(self) -> pd.DataFrame:
        """Wall times per job (not deterministic: kept apart from the other tables)."""
        return pd.DataFrame([{"simulator": r.simulator, "control_noise": r.control_noise, "seed": r.seed,
                              "fitted_steps": int(r.tracks["fitted_steps"].sum()), "fit_time_s": r.fit_time_s,
                              "tirl_time_s": r.tirl_time_s, "simulated": s, "sim_time_s": t}
                             for r, s, t in self._unique().values()])


def recovery_jobs(simulators, seeds, *, population: dict | None = None, n_vehicles: int | None = None,
                  control_noise=(), noise_seeds=None, min_steps: int = 10, stride: int = 1,
                  scenario: dict | None = None) -> list[RecoveryJob]:
    """The study's runs: every (simulator, seed) at the population's own noise and, for the noise study, every
    (simulator, noise level, noise seed), on ``scenario``'s road (SUMO; default the ring); ValueError for an unknown
    simulator or no seed."""
    unknown = [s for s in simulators if s not in SIMULATORS]
    if unknown or not simulators:
        raise ValueError(f"simulators must be some of {SIMULATORS}, got {list(simulators)}")
    if not seeds:
        raise ValueError("at least one seed is needed")
    RecedingRecovery(min_steps, stride)._check_common()
    noise_seeds = list(seeds) if noise_seeds is None else list(noise_seeds)
    pop = dict(population or {})
    jobs = []
    for sim in simulators:
        jobs += [RecoveryJob(sim, int(s), None, pop, n_vehicles, min_steps, stride, dict(scenario or {}))
                 for s in seeds]
        jobs += [RecoveryJob(sim, int(s), float(noise), pop, n_vehicles, min_steps, stride, dict(scenario or {}))
                 for noise in control_noise for s in noise_seeds]
    return jobs


def recovery_result(jobs, records, *, simulated, sim_time_s, workers: int) -> RecoveryResult:
    """The study's result from each job's cell result (`to_record`), whether its run was simulated now and the
    simulation's wall time [s]; jobs of the same run share one report."""
    runs = {id(rec): rec for rec in records}
    reports = {run: from_record(rec) for run, rec in runs.items()}  # one per run, shared by its jobs
    first = jobs[0] if jobs else RecoveryJob("sumo", 0, None)
    return RecoveryResult(tuple(jobs), tuple(reports[id(rec)] for rec in records), tuple(simulated),
                          tuple(sim_time_s), first.stride, first.min_steps, workers,
                          os.environ.get("OPENBLAS_NUM_THREADS", "default"))


# ---------------------------------------------------------------------------------------------- output
def _csv(df: pd.DataFrame) -> str:
    return df.to_csv(index=False, float_format=_FLOAT, lineterminator="\n")


_SHORT = {"median_abs_log_err_speed_dev": "med sd", "median_abs_log_err_acc_sq": "med acc",
          "p90_abs_log_err_speed_dev": "p90 sd", "p90_abs_log_err_acc_sq": "p90 acc",
          "spearman_speed_dev": "rho sd", "spearman_acc_sq": "rho acc",
          "tirl_max_abs_log_err_speed_dev": "TIRL sd", "tirl_max_abs_log_err_acc_sq": "TIRL acc"}


def compact_table(table: pd.DataFrame) -> pd.DataFrame:
    """The columns of the Markdown tables (full precision and the rest in the CSV)."""
    if not len(table):
        return table
    out = table[["simulator", "control_noise", "seed"]].copy()
    out["tracks usable/PIRL"] = [f"{u}/{p}" for u, p in zip(table["usable_tracks"], table["pirl_tracks"])]
    out["steps"] = table["usable_steps"]
    for col, short in _SHORT.items():
        out[short] = table[col]
    for f, short in (("headway", "hw"), ("yielding", "yld")):  # drivers who interact: all tracks, and identified
        if f"{f}_tracks" in table:
            out[f"med {short}"] = table[f"median_abs_log_err_{f}"]
            out[f"{short} id"] = table[f"{f}_tracks"]
            out[f"med {short} id"] = table[f"median_abs_log_err_{f}_identified"]
            out[f"p90 {short} id"] = table[f"p90_abs_log_err_{f}_identified"]
            out[f"rho {short} id"] = table[f"spearman_{f}_identified"]
    out["conv"] = [f"{c}/{g}" for c, g in zip(table["converged"], table["groups"])]
    out["at bound"] = table["at_bound"]
    out["TIRL conv"] = [f"{c}/{g}" for c, g in zip(table["tirl_converged"], table["tirl_groups"])]
    out["sigma"] = table["sigma_median"]
    return out


def _targets_text(table: pd.DataFrame) -> str:
    lines = []
    for sim in table["simulator"].unique():
        sub = table[table["simulator"] == sim]
        pooled = sub[sub["seed"] == "pooled"]
        rows = pooled if len(pooled) else sub
        for _, row in rows.iterrows():
            lines.append(f"{sim}, seed {row['seed']}:")
            for col, op, limit, value, met in check_targets(row.to_dict(), sim):
                lines.append(f"- {'met' if met else '**NOT met**'}: {col} = {value:.3g} (target {op} {limit:g})")
        failing = [(r["seed"], col, value) for _, r in sub[sub["seed"] != "pooled"].iterrows()
                   for col, _, _, value, met in check_targets(r.to_dict(), sim) if not met]
        if failing:
            lines.append("- single seeds missing a target: "
                         + "; ".join(f"seed {s} {c} = {v:.3g}" for s, c, v in failing))
        lines.append("")
    return "\n".join(lines)


def write_recovery(result: RecoveryResult, out, command: str) -> dict[str, Path]:
    """Write the study's files into ``out`` (atomically, each), return them by name."""
    out = Path(out)
    table = result.table()
    noise = result.noise_table()
    styles, sel = result.styles(), result.selection()
    tracks = result.tracks()
    fitted = [f for f in FREE_FEATURES + INTERACTION_FEATURES if f"se_log_{f}" in tracks]
    mixtures = (style_mixtures(tracks, fitted, identified_se=IDENTIFIED_SE, min_near_steps=MIN_NEAR_STEPS)
                if fitted and len(tracks) else pd.DataFrame())
    files = {
        "table.csv": _csv(table),
        "table.md": markdown(compact_table(table)),
        "styles.csv": _csv(styles),
        "tracks.csv": _csv(tracks),
        "style_mixtures.csv": _csv(mixtures),
        "selection.csv": _csv(sel),
        "times.csv": result.times().to_csv(index=False, float_format="%.3f", lineterminator="\n"),
    }
    if len(noise):
        files["noise.csv"] = _csv(noise)
        files["noise.md"] = markdown(compact_table(noise))
    sel_all = sel[sel["style_name"] == "all"].drop(columns=["style_name"])
    noise_part = ""
    if len(noise):
        nt = noise[noise["seed"] == "pooled"] if (noise["seed"] == "pooled").any() else noise
        cols = ["simulator", "control_noise", "seed", "usable_tracks", "sigma_median",
                "median_abs_log_err_speed_dev", "median_abs_log_err_acc_sq", "p90_abs_log_err_speed_dev",
                "p90_abs_log_err_acc_sq", "spearman_speed_dev", "tirl_max_abs_log_err_speed_dev",
                "tirl_max_abs_log_err_acc_sq"]
        noise_part = (
            "## Control noise\n\nGaussian noise of standard deviation `control_noise` [m/s^3] on every applied "
            "jerk (population key `control_noise`); `sigma_median` is the median fitted residual scale of the "
            "per-track fits. Per seed: `noise.csv` / `noise.md`.\n\n" + markdown(nt[cols]) + "\n")
    readme = (
        "# Weight recovery of the receding-horizon IRL on simulated roundabouts\n\n"
        f"Made by `{command}` (per-track fit stride {result.stride}, tracks with at least {result.min_steps} "
        "usable steps). Every file here but `times.csv` is the same for the same seeds.\n\n"
        "Per run: every PIRL track whose step mask keeps enough steps (`selection=\"steps\"`: the steps whose "
        "jerk is the driver's own) is fitted on its own (`pirl_sim.receding.fit_receding`, one weight vector "
        "per track); per style, TIRL (`likelihood=\"receding\"`) on the style's usable tracks. Errors are "
        "|log(theta_hat / theta)| of the normalised weights (jerk_sq = 1); TIRL is compared with the mean "
        "true weights of the style's usable tracks. `pooled`: medians, 90th percentiles and Spearman over "
        "the tracks of all seeds, TIRL the largest error over all seeds' styles.\n\n"
        "Columns of `table.md`: med / p90 = median / 90th percentile |log error| (sd = speed_dev, acc = "
        "acc_sq), rho = Spearman of true vs fitted weights, TIRL = largest per-style TIRL |log error|, conv "
        "= converged / fitted groups, at bound = tracks with a log weight at its bound, sigma = median fitted "
        "residual scale [m/s^3].\n\n"
        "## Targets\n\n" + _targets_text(table) + "\n"
        "## Recovery\n\n" + markdown(compact_table(table)) + "\n"
        "## Per-style TIRL\n\n" + markdown(styles.drop(columns=["fitted_steps"])) + "\n"
        "## Styles in weight space\n\nA deconvolved Gaussian mixture with one component per style fitted to the "
        "tracks' log weights, each with its fit's standard errors (a weight the track's data do not determine is "
        "integrated out; `pirl_sim.experiments.recovery_styles`): `ari` = adjusted Rand index of the tracks' "
        "components against their styles, `mean_err_<f>` = the largest |component mean - style's mean log "
        "weight| over styles.\n\n" + markdown(mixtures) + "\n"
        + noise_part +
        "## Step selection\n\nSteps per rule, all styles (per style: `selection.csv`; the rules overlap). "
        "`usable`: steps the mask keeps; `tracks_few_usable`: tracks with fewer than "
        f"{result.min_steps} usable steps (left out).\n\n" + markdown(sel_all) + "\n"
        "## Files\n\n`table.csv` (every column), `styles.csv` (per-style TIRL), `tracks.csv` (per-track "
        "weights), `style_mixtures.csv`, `selection.csv`, `noise.csv`, `times.csv` (wall times of this machine: "
        f"{result.workers} worker process(es), OPENBLAS_NUM_THREADS={result.blas_threads}). The simulated "
        "runs are kept under `simulations/` (not committed) so that a rerun does not simulate again.\n"
    )
    files["README.md"] = readme
    return {name: atomic_write_text(out / name, text) for name, text in files.items()}
