"""``pirl-sim simulate sumo``: run a SUMO roundabout population and record it.

Wiring into ``pirl_sim/cli.py`` (the ``simulate`` command comes from
:func:`pirl_sim.scenarios.simulate_cli.add_simulate_parser`)::

    from pirl_sim.scenarios.sumo.cli import add_sumo_parser, run_simulate_sumo
    ...
    add_sumo_parser(simulators)              # the subparsers action of ``simulate`` (dest="simulator")
    ...
    if args.command == "simulate" and args.simulator == "sumo":
        return run_simulate_sumo(args)

``pirl-sim simulate sumo`` runs with no arguments: the embedded default population (the paper's three
styles, 20 % background, 80 vehicles) on the default 4-arm roundabout, seed 0, written to
``results/sumo_run``. ``--print-default-population`` prints the embedded population as TOML to start a
config from.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..simulate_cli import add_simulator_parser, run_simulator

__all__ = ["add_sumo_parser", "run_simulate_sumo", "DEFAULT_OUT"]

DEFAULT_OUT = Path("results") / "sumo_run"


def add_sumo_parser(simulators) -> argparse.ArgumentParser:
    """Add ``sumo`` to the ``simulate`` command's simulators (a ``parser.add_subparsers()`` action)."""
    from .runner import BACKENDS

    sumo = add_simulator_parser(
        simulators, "sumo",
        help="a SUMO roundabout (libsumo)",
        description="Run a SUMO roundabout with PIRL drivers (the paper's roundabout model, each with its own "
                    "sampled weights, re-planning every 0.1 s) and SUMO background traffic; write "
                    "vehicle_tracks_000.csv, ground_truth.csv, map.osm, run.json and network/ to --out. "
                    "Runs with no arguments (embedded default population and network).",
        default_out=DEFAULT_OUT,
        scenario_help="scenario TOML with [network], [drivers] and route settings (default: the default 4-arm "
                      "roundabout)",
        seed_help="seed of every draw and of SUMO (default 0)",
    )
    sumo.add_argument("--backend", choices=BACKENDS, default="libsumo",
                      help="libsumo (default, in-process) or traci (a SUMO process over a socket, slower)")
    return sumo


def run_simulate_sumo(args: argparse.Namespace) -> int:
    """Run the command parsed by :func:`add_sumo_parser` (0 on success, 2 for a bad configuration)."""
    from .scenario import SumoScenarioConfig, load_scenario, run_sumo_scenario

    def run(config, seed, **kwargs):
        return run_sumo_scenario(config, seed, backend=args.backend, **kwargs)

    return run_simulator(args, default_config=SumoScenarioConfig, load_scenario=load_scenario, run=run)
