"""``pirl-sim simulate highway``: run a population on highway-env's roundabout and record it.

Wiring into ``pirl_sim/cli.py`` (the ``simulate`` command comes from
:func:`pirl_sim.scenarios.simulate_cli.add_simulate_parser`)::

    from pirl_sim.scenarios.highway.cli import add_highway_parser, run_simulate_highway
    ...
    add_highway_parser(simulators)            # the subparsers action of ``simulate`` (dest="simulator")
    ...
    if args.command == "simulate" and args.simulator == "highway":
        return run_simulate_highway(args)

``pirl-sim simulate highway`` runs with no arguments: the embedded default population (the SUMO
scenario's: the paper's three styles, 20 % background, 80 vehicles) on highway-env's roundabout (radius
20 m), seed 0, written to ``results/highway_run``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..simulate_cli import add_simulator_parser, run_simulator

__all__ = ["add_highway_parser", "run_simulate_highway", "DEFAULT_OUT"]

DEFAULT_OUT = Path("results") / "highway_run"


def add_highway_parser(simulators) -> argparse.ArgumentParser:
    """Add ``highway`` to the ``simulate`` command's simulators (a ``parser.add_subparsers()`` action)."""
    return add_simulator_parser(
        simulators, "highway",
        help="highway-env's roundabout",
        description="Run highway-env's roundabout (roundabout-generic-v0, one ring lane) with PIRL drivers (the "
                    "paper's roundabout model, each with its own sampled weights, re-planning every 0.1 s) and "
                    "highway-env IDM background traffic; write vehicle_tracks_000.csv, ground_truth.csv, "
                    "map.osm and run.json to --out. Runs with no arguments.",
        default_out=DEFAULT_OUT,
        scenario_help="scenario TOML with [geometry], [drivers], [rules] and route settings",
    )


def run_simulate_highway(args: argparse.Namespace) -> int:
    """Run the command parsed by :func:`add_highway_parser` (0 on success, 2 for a bad configuration)."""
    from .scenario import HighwayScenarioConfig, load_scenario, run_highway_scenario

    return run_simulator(args, default_config=HighwayScenarioConfig, load_scenario=load_scenario,
                         run=run_highway_scenario)
