"""Experiments run as a sweep and written by a report template: the paper's presets (`preset_config`,
`run_preset`: ``pirl-sim reproduce``) and the agents study (`agents_config`, `run_agents`: ``pirl-sim agents``).
Finished cells stay in the output directory's store, so an interrupted run resumes."""

from __future__ import annotations

import time
import tomllib

import pandas as pd

from pirl_sim.experiments import agents_study, reproduce
from pirl_sim.experiments.registry import scenario_spec
from pirl_sim.validation import check_output_dir

from .config import SweepConfig, parse_config, preset_text
from .executors import InlineExecutor, LocalExecutor
from .run import run_sweep

__all__ = ["preset_config", "run_preset", "agents_config", "run_agents"]


def preset_config(name: str, *, seed: int = 0, params: dict | None = None,
                  history_steps: int | None = None) -> SweepConfig:
    """The embedded preset ``name`` as a validated `pirl_sim.engine.config.SweepConfig`.

    Parameters
    ----------
    name : {"synthetic", "passage"}
    seed : int                   the one seed of every cell (data and learners)
    params : dict or None        scenario parameters set in every experiment (e.g. ``n_train``,
                                 ``position_range``); PIRL-kNN grid values of k above ``n_train`` are dropped
    history_steps : int or None  [steps] history of every protocol that has one (None: the preset's)

    Raises
    ------
    ValueError
        An unknown preset, or a parameter the sweep config rejects (named there).
    """
    if name not in reproduce.PRESETS:
        raise ValueError(f"unknown experiment {name!r}; choose one of {', '.join(reproduce.PRESETS)}")
    text = preset_text(name)
    data = {**tomllib.loads(text), "seeds": [seed]}
    for exp in data["experiments"]:
        exp["params"] = {**exp.get("params", {}), **(params or {})}
        for proto in (p for p in exp["protocols"] if history_steps is not None and p["kind"] != "paper"):
            proto["history_steps"] = history_steps
        n_train = exp["params"].get("n_train", scenario_spec(exp["scenario"]).params["n_train"].default)
        for learner in exp["learners"]:
            grid = learner.get("grid", {}) if isinstance(learner, dict) else {}
            if isinstance(grid.get("n_neighbors"), list):
                grid["n_neighbors"] = [k for k in grid["n_neighbors"] if not isinstance(k, int) or k <= n_train]
    return parse_config(data, source=f"<{name}>", text=text)


def run_preset(name: str, out_dir, *, seed: int = 0, params: dict | None = None, history_steps: int | None = None,
               workers: int | None = 0, progress: bool = True, command: str | None = None) -> pd.DataFrame:
    """Run the preset ``name`` into ``out_dir``; write its files (`pirl_sim.experiments.reproduce.write_reproduction`).

    Parameters
    ----------
    name, seed, params, history_steps : see `preset_config`.
    out_dir : path               output directory; its finished cells are reused (resume)
    workers : int or None        sweep workers (0: in this process; None: the usable cores)
    progress : bool              progress bar and status lines on stderr
    command : str or None        recorded in ``sweep.json``

    Returns
    -------
    table : DataFrame            the main table (``table.csv``); ValueError for an unwritable ``out_dir`` or a bad
                                 parameter, RuntimeError when cells failed (``out_dir/errors/``; the call resumes)
    """
    out = check_output_dir(out_dir, "out_dir")  # before the work: a bad directory fails now, not at the end
    config = preset_config(name, seed=seed, params=params, history_steps=history_steps)
    run = run_sweep(config, out, workers=workers, progress=progress, command=command, tables=False)
    run.check_failed(f"the {name} cells")
    return reproduce.write_reproduction(name, config.cells, run.table, out, progress=progress)


def agents_config(cfg: agents_study.AgentsConfig) -> SweepConfig:
    """The agents study ``cfg`` as a validated sweep config (`pirl_sim.experiments.agents_study.sweep_data`)."""
    return parse_config(agents_study.sweep_data(cfg))


def run_agents(cfg: agents_study.AgentsConfig, out, *, workers: int = 1, progress: bool = False,
               command: str = agents_study.DEFAULT_COMMAND) -> agents_study.ExperimentResult:
    """Run (or resume) the agents study through the sweep engine into ``out`` (its ``cells/`` store and
    ``sweep.json``) on ``workers`` worker processes (1: in this process) and return every run's record
    (`pirl_sim.experiments.agents_study.collect_records`)."""
    config, t0 = agents_config(cfg), time.perf_counter()
    with (InlineExecutor() if workers == 1 else LocalExecutor(workers)) as executor:
        run = run_sweep(config, out, executor=executor, progress=progress, command=command, tables=False)
    run.check_failed("the experiment's runs")
    return agents_study.collect_records(config.cells, run.keys, run.records, run.computed, time.perf_counter() - t0)
