"""Scenario sweeps: config grids, local processes or Dask, a resumable result store, reports.

A sweep config (TOML, `pirl_sim.engine.config`) is a grid over scenarios (the registry
`pirl_sim.experiments.registry.SCENARIOS`) and their parameters, protocols, learners and their parameters, and
seeds. `run_sweep` sends the cells that the results directory does not hold yet to worker processes
(`pirl_sim.engine.executors`: local, Dask, or in-process), stores each result atomically as it finishes
(`pirl_sim.engine.store`, keyed by the cell's config and the code version) and assembles the tidy table;
`write_report` draws the figures and a Markdown summary. The command line: ``pirl-sim sweep`` and
``pirl-sim report`` (`pirl_sim.cli.sweep`, `pirl_sim.cli.report`).

Sweeps, with an example from Python, are explained in the documentation's "Sweeps" page.
"""

from .config import Cell, SweepConfig, default_config, load_config, parse_config
from .report import write_report
from .run import TIMING_COLUMNS, SweepRun, assemble_table, read_table, run_sweep
from pirl_sim.experiments.registry import SCENARIOS, register_scenario
from pirl_sim.experiments.spec import Param, ScenarioData, ScenarioSpec, TrainShape
from .store import ResultStore, code_version

__all__ = ["Cell", "SweepConfig", "load_config", "parse_config", "default_config", "run_sweep", "SweepRun",
           "assemble_table", "read_table", "TIMING_COLUMNS", "write_report", "SCENARIOS", "ScenarioSpec",
           "ScenarioData", "TrainShape", "Param", "register_scenario", "ResultStore", "code_version"]
