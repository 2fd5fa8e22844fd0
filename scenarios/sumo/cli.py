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
import dataclasses
import math
from pathlib import Path

from pirl_sim.validation import positive_int_arg

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
    sumo.add_argument("--demand", type=_positive_float, default=None, metavar="VEH_PER_H",
                      help="traffic demand [vehicles per hour per arm]: sets the time between departures "
                           "(3600 / (demand * arms) s; overrides the population's depart_interval); with "
                           "--n-vehicles it sets how long the demand lasts")
    sumo.add_argument("--lanes", type=positive_int_arg, default=None, metavar="N",
                      help="lanes of the ring and of every arm (default: the scenario's, 1); 2 for a two-lane "
                           "roundabout")
    return sumo


def _positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def _with_options(config, args: argparse.Namespace):
    """``config`` with the command line's --demand and --lanes applied (ValueError for bad combinations)."""
    changes = {}
    if getattr(args, "lanes", None) is not None:
        changes["network"] = dataclasses.replace(config.network, lanes=args.lanes)
    if getattr(args, "demand", None) is not None:
        changes["demand_per_arm"] = args.demand
    return dataclasses.replace(config, **changes) if changes else config


def run_simulate_sumo(args: argparse.Namespace) -> int:
    """Run the command parsed by :func:`add_sumo_parser` (0 on success, 2 for a bad configuration)."""
    from .scenario import SumoScenarioConfig, load_scenario, run_sumo_scenario

    def run(config, seed, **kwargs):
        return run_sumo_scenario(config, seed, backend=args.backend, **kwargs)

    def default_config(**kwargs):
        return _with_options(SumoScenarioConfig(**kwargs), args)

    def scenario(path, **kwargs):
        return _with_options(load_scenario(path, **kwargs), args)

    return run_simulator(args, default_config=default_config, load_scenario=scenario, run=run)
