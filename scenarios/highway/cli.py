"""``pirl-sim simulate highway``: run a population on highway-env's roundabout and record it.

Wiring into ``pirl_sim/cli.py`` (the ``simulate`` command and its ``simulators`` subparsers come from
:func:`pirl_sim.scenarios.sumo.cli.add_simulate_parser`)::

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
import sys
from pathlib import Path

from ..sumo.cli import ProgressBar, _positive_int, _seed

__all__ = ["add_highway_parser", "run_simulate_highway", "DEFAULT_OUT"]

DEFAULT_OUT = Path("results") / "highway_run"


def add_highway_parser(simulators) -> argparse.ArgumentParser:
    """Add ``highway`` to the ``simulate`` command's simulators (a ``parser.add_subparsers()`` action)."""
    hw = simulators.add_parser(
        "highway",
        help="highway-env's roundabout",
        description="Run highway-env's roundabout (roundabout-generic-v0, one ring lane) with PIRL drivers (the "
                    "paper's roundabout model, each with its own sampled weights, re-planning every 0.1 s) and "
                    "highway-env IDM background traffic; write vehicle_tracks_000.csv, ground_truth.csv, "
                    "map.osm and run.json to --out. Runs with no arguments.",
    )
    hw.add_argument("--population", type=Path, default=None, metavar="CONFIG",
                    help="population TOML (default: the embedded one, see --print-default-population)")
    hw.add_argument("--scenario", type=Path, default=None, metavar="CONFIG",
                    help="scenario TOML with [geometry], [drivers], [rules] and route settings")
    hw.add_argument("--seed", type=_seed, default=0, help="seed of every draw (default 0)")
    hw.add_argument("--out", type=Path, default=DEFAULT_OUT,
                    help=f"output directory (default: {DEFAULT_OUT.as_posix()})")
    hw.add_argument("--n-vehicles", type=_positive_int, default=None,
                    help="override the population's number of vehicles")
    hw.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    hw.add_argument("--print-default-population", action="store_true",
                    help="print the embedded default population as TOML and exit")
    return hw


def run_simulate_highway(args: argparse.Namespace) -> int:
    """Run the command parsed by :func:`add_highway_parser`.

    Returns
    -------
    int
        0 on success; 2 for a bad configuration (the reason on stderr, nothing written).
    """
    import dataclasses

    from ..population_config import DEFAULT_POPULATION, DEFAULT_POPULATION_TOML, load_population
    from .scenario import HighwayScenarioConfig, load_scenario, run_highway_scenario

    if args.print_default_population:
        sys.stdout.write(DEFAULT_POPULATION_TOML)
        return 0
    try:
        population = load_population(args.population) if args.population is not None else None
        if args.scenario is not None:
            config = load_scenario(args.scenario, population=population)
        else:
            config = HighwayScenarioConfig(population=population or DEFAULT_POPULATION)
        if args.n_vehicles is not None:
            config = dataclasses.replace(
                config, population=dataclasses.replace(config.population, n_vehicles=args.n_vehicles))
        bar = None if args.quiet else ProgressBar()
        try:
            result = run_highway_scenario(config, args.seed, out_dir=args.out, progress=bar)
        finally:
            if bar is not None:
                bar.close()
    except (ValueError, FileNotFoundError) as exc:
        print(f"pirl-sim: error: {exc}", file=sys.stderr)
        return 2
    gt = result.recording.ground_truth
    pirl = gt[gt["is_pirl"]]
    clean = pirl[~pirl["interacted"].fillna(False).astype(bool)]
    t = result.timing
    print(f"{len(gt)} tracks ({len(pirl)} PIRL, {len(gt) - len(pirl)} background), "
          f"{t['sim_time_s']:.1f} s simulated in {t['wall_time_s']:.1f} s ({t['real_time_factor']:.0f}x real time)")
    for name in config.population.style_names:
        n_style = int((pirl["style_name"] == name).sum())
        n_clean = int((clean["style_name"] == name).sum())
        print(f"  {name}: {n_style} PIRL tracks, {n_clean} without interaction")
    print(f"  collided: {int(gt['collided'].sum())}, removed early: {int(gt['removed_early'].sum())}")
    print(f"wrote {args.out}/")
    return 0
