"""``pirl-sim simulate SIMULATOR``: record a driver population of known weights in INTERACTION format.

Every simulator has the common options (`add_simulator_parser`) and runs through `run` (configuration,
progress bar, errors, summary): ``sumo`` (a SUMO roundabout, libsumo or TraCI) and
``highway`` (highway-env's roundabout). Both run with no arguments (the embedded default population).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import sys
from pathlib import Path
from typing import Any

from pirl_sim.validation import check_output_dir, positive_float_arg, positive_int_arg

from .common import add_seed_option, error, finish, reworded, subcommand

__all__ = ["add_parser", "run", "add_simulator_parser", "ProgressBar", "SUMO_OUT", "HIGHWAY_OUT", "SUMO_BACKENDS"]

SUMO_OUT = Path("results") / "sumo_run"
HIGHWAY_OUT = Path("results") / "highway_run"
#: `pirl_sim.scenarios.sumo.runner.BACKENDS`, named here so that the parser does not import the simulator
SUMO_BACKENDS = ("libsumo", "traci")


@subcommand("simulate", help="simulate a driver population of known cost weights and record it in INTERACTION format",
            description="Simulate a mixed-style driver population whose cost weights are known and record it: "
            "INTERACTION tracks, a ground-truth table and a Lanelet2 map.")
def add_parser(sim) -> None:
    """The simulators of ``simulate``, each a command of its own (`add_simulator_parser`)."""
    simulators = sim.add_subparsers(dest="simulator", metavar="SIMULATOR", required=True)
    drivers = ("with PIRL drivers (the paper's roundabout model, each with its own sampled weights, re-planning every "
               "0.1 s) and")
    sumo = add_simulator_parser(
        simulators, "sumo", help="a SUMO roundabout (libsumo)", default_out=SUMO_OUT, seed_of="every draw and of SUMO",
        description=f"Run a SUMO roundabout {drivers} SUMO background traffic; write vehicle_tracks_000.csv, "
        "ground_truth.csv, map.osm, run.json and network/ to --out. Runs with no arguments (embedded default "
        "population and network).", scenario_help="scenario TOML with [network], [drivers] and route settings "
        "(default: the default 4-arm roundabout)")
    sumo.add_argument("--backend", choices=SUMO_BACKENDS, default="libsumo",
                      help="libsumo (default, in-process) or traci (a SUMO process over a socket, slower)")
    sumo.add_argument("--demand", type=reworded(positive_float_arg, "expected a number > 0, got {text!r}"),
                      metavar="VEH_PER_H", help="traffic demand [vehicles per hour per arm]: sets the "
                      "time between departures (3600 / (demand * arms) s; overrides the population's depart_interval); "
                      "with --n-vehicles it sets how long the demand lasts")
    sumo.add_argument("--lanes", type=positive_int_arg, metavar="N", help="lanes of the ring and of "
                      "every arm (default: the scenario's, 1); 2 for a two-lane roundabout")
    add_simulator_parser(
        simulators, "highway", help="highway-env's roundabout", default_out=HIGHWAY_OUT,
        description=f"Run highway-env's roundabout (roundabout-generic-v0, one ring lane) {drivers} highway-env IDM "
        "background traffic; write vehicle_tracks_000.csv, ground_truth.csv, map.osm and run.json to --out. Runs with "
        "no arguments.", scenario_help="scenario TOML with [geometry], [drivers], [rules] and route settings")


def add_simulator_parser(simulators, name: str, *, help: str, description: str, default_out: Path,
                         scenario_help: str, seed_of: str = "every draw") -> argparse.ArgumentParser:
    """Add the simulator ``name`` to ``simulate`` with the options every simulator has (``--seed``: the seed of
    ``seed_of``); returns its parser (for options of its own)."""
    p = simulators.add_parser(name, help=help, description=description)
    p.add_argument("--population", type=Path, metavar="CONFIG",
                   help="population TOML (default: the embedded one, see --print-default-population)")
    p.add_argument("--scenario", type=Path, metavar="CONFIG", help=scenario_help)
    add_seed_option(p, seed_of)
    p.add_argument("--out", type=Path, default=default_out,
                   help=f"output directory (default: {default_out.as_posix()})")
    p.add_argument("--n-vehicles", type=positive_int_arg, help="override the population's number of vehicles")
    p.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    p.add_argument("--print-default-population", action="store_true",
                   help="print the embedded default population as TOML and exit")
    return p


class ProgressBar:
    """The simulation's progress, ``progress(time_s, n_done, n_total)``, as a bar of vehicles done on a stream
    (stderr by default), drawn by tqdm through `pirl_sim.progress.bar` with the simulated time and an ETA: on a
    terminal redrawn in place; otherwise a line at most every ``every`` seconds."""

    def __init__(self, stream=None, every: float = 5.0):
        self.stream, self.every = sys.stderr if stream is None else stream, every
        self._bar: Any = None  # a tqdm bar (an untyped library) from the first call

    def __call__(self, time_s: float, n_done: int, n_total: int) -> None:
        if self._bar is None:
            from pirl_sim.progress import bar

            self._bar = bar(n_total, "vehicles done", unit="veh", stream=self.stream, every=self.every)
        self._bar.set_postfix_str(f"{time_s:.1f} s simulated", refresh=False)
        self._bar.update(n_done - self._bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def run(args: argparse.Namespace) -> int:
    """``pirl-sim simulate SIMULATOR``: 0 on success; 2 for a bad configuration (the reason on stderr, nothing
    written)."""
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, DEFAULT_POPULATION_TOML, load_population
    from pirl_sim.scenarios.simulators import simulator_scenarios

    if args.print_default_population:
        sys.stdout.write(DEFAULT_POPULATION_TOML)
        return 0
    sim = simulator_scenarios(args.simulator)
    Config, load_scenario, simulate = sim.config, sim.load, sim.run
    if args.simulator == "sumo":
        simulate = functools.partial(simulate, backend=args.backend)
    try:
        population = load_population(args.population) if args.population is not None else None
        config = (load_scenario(args.scenario, population=population) if args.scenario is not None
                  else Config(population=population or DEFAULT_POPULATION))
        changes: dict[str, Any] = {}  # the options that override the configuration (ValueError for bad combinations)
        if getattr(args, "lanes", None) is not None:  # sumo's
            changes["network"] = dataclasses.replace(config.network, lanes=args.lanes)
        if getattr(args, "demand", None) is not None:  # sumo's
            changes["demand_per_arm"] = args.demand
        if args.n_vehicles is not None:
            changes["population"] = dataclasses.replace(config.population, n_vehicles=args.n_vehicles)
        config = dataclasses.replace(config, **changes)
        check_output_dir(args.out)  # before the run, not after it
        with contextlib.closing(ProgressBar()) as bar:  # draws nothing until the simulation reports
            result = simulate(config, args.seed, out_dir=args.out, progress=None if args.quiet else bar)
    except (ValueError, FileNotFoundError) as exc:
        return error(exc)
    gt = result.recording.ground_truth
    pirl = gt[gt["is_pirl"]]
    clean, t = pirl[~pirl["interacted"].fillna(False).astype(bool)], result.timing
    print(f"{len(gt)} tracks ({len(pirl)} PIRL, {len(gt) - len(pirl)} background), "
          f"{t['sim_time_s']:.1f} s simulated in {t['wall_time_s']:.1f} s ({t['real_time_factor']:.0f}x real time)")
    if "mean_pirl" in t:
        print(f"  PIRL drivers in the network at once: mean {t['mean_pirl']:.1f}, max {t['max_pirl']}")
    for name in config.population.style_names:
        print(f"  {name}: {int((pirl['style_name'] == name).sum())} PIRL tracks, "
              f"{int((clean['style_name'] == name).sum())} without interaction")
    print(f"  collided: {int(gt['collided'].sum())}, removed early: {int(gt['removed_early'].sum())}")
    return finish(f"{args.out}/")
