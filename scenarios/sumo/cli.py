"""``pirl-sim simulate sumo``: run a SUMO roundabout population and record it.

Wiring into ``pirl_sim/cli.py``::

    from pirl_sim.scenarios.sumo.cli import add_simulate_parser, run_simulate
    ...
    add_simulate_parser(sub)                 # in build_parser, ``sub`` = parser.add_subparsers(...)
    ...
    if args.command == "simulate":           # in main
        return run_simulate(args)

``pirl-sim simulate sumo`` runs with no arguments: the embedded default population (the paper's three
styles, 20 % background, 80 vehicles) on the default 4-arm roundabout, seed 0, written to
``results/sumo_run``. ``--print-default-population`` prints the embedded population as TOML to start a
config from.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

__all__ = ["add_simulate_parser", "run_simulate", "DEFAULT_OUT", "ProgressBar"]

DEFAULT_OUT = Path("results") / "sumo_run"
_BAR_WIDTH = 30


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= value < 2**31:
        raise argparse.ArgumentTypeError(f"the seed must be in [0, 2**31), got {value}")
    return value


def add_simulate_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``simulate`` (with the simulator ``sumo``) to a ``parser.add_subparsers()`` object.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The top-level command's subparsers.

    Returns
    -------
    argparse.ArgumentParser
        The ``simulate`` parser; its own subparsers (``dest="simulator"``) hold ``sumo``.
    """
    from .runner import BACKENDS

    sim = subparsers.add_parser(
        "simulate",
        help="simulate a driver population of known cost weights and record it in INTERACTION format",
        description="Simulate a mixed-style driver population whose cost weights are known and record it: "
                    "INTERACTION tracks, a ground-truth table and a Lanelet2 map.",
    )
    simulators = sim.add_subparsers(dest="simulator", metavar="SIMULATOR")
    simulators.required = True
    sumo = simulators.add_parser(
        "sumo",
        help="a SUMO roundabout (libsumo)",
        description="Run a SUMO roundabout with PIRL drivers (the paper's roundabout model, each with its own "
                    "sampled weights, re-planning every 0.1 s) and SUMO background traffic; write "
                    "vehicle_tracks_000.csv, ground_truth.csv, map.osm, run.json and network/ to --out. "
                    "Runs with no arguments (embedded default population and network).",
    )
    sumo.add_argument("--population", type=Path, default=None, metavar="CONFIG",
                      help="population TOML (default: the embedded one, see --print-default-population)")
    sumo.add_argument("--scenario", type=Path, default=None, metavar="CONFIG",
                      help="scenario TOML with [network], [drivers] and route settings (default: the default "
                           "4-arm roundabout)")
    sumo.add_argument("--seed", type=_seed, default=0, help="seed of every draw and of SUMO (default 0)")
    sumo.add_argument("--out", type=Path, default=DEFAULT_OUT,
                      help=f"output directory (default: {DEFAULT_OUT.as_posix()})")
    sumo.add_argument("--n-vehicles", type=_positive_int, default=None,
                      help="override the population's number of vehicles")
    sumo.add_argument("--backend", choices=BACKENDS, default="libsumo",
                      help="libsumo (default, in-process) or traci (a SUMO process over a socket, slower)")
    sumo.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    sumo.add_argument("--print-default-population", action="store_true",
                      help="print the embedded default population as TOML and exit")
    return sim


class ProgressBar:
    """A one-line progress bar on a stream (stderr by default): ``[#####.....]  50% | 120.0 s | 40/80 done``.

    On a terminal the line is redrawn in place; otherwise a line is printed each time another tenth of the
    vehicles is done.
    """

    def __init__(self, stream=None):
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_tenth = -1

    def __call__(self, time_s: float, n_done: int, n_total: int) -> None:
        frac = n_done / n_total if n_total else 1.0
        filled = int(round(_BAR_WIDTH * frac))
        line = (f"[{'#' * filled}{'.' * (_BAR_WIDTH - filled)}] {100 * frac:3.0f}% | {time_s:7.1f} s simulated | "
                f"{n_done}/{n_total} vehicles done")
        if self.tty:
            self.stream.write("\r" + line)
            self.stream.flush()
        elif math.floor(10 * frac) > self._last_tenth:
            self._last_tenth = math.floor(10 * frac)
            self.stream.write(line + "\n")
            self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def run_simulate(args: argparse.Namespace) -> int:
    """Run the command parsed by :func:`add_simulate_parser`.

    Returns
    -------
    int
        0 on success; 2 for a bad configuration (the reason on stderr, nothing written).
    """
    if getattr(args, "simulator", None) != "sumo":  # pragma: no cover - argparse enforces the choice
        print(f"pirl-sim: error: unknown simulator {getattr(args, 'simulator', None)!r}", file=sys.stderr)
        return 2
    import dataclasses

    from ..population_config import DEFAULT_POPULATION, DEFAULT_POPULATION_TOML, load_population
    from .scenario import SumoScenarioConfig, load_scenario, run_sumo_scenario

    if args.print_default_population:
        sys.stdout.write(DEFAULT_POPULATION_TOML)
        return 0
    try:
        population = load_population(args.population) if args.population is not None else None
        if args.scenario is not None:
            config = load_scenario(args.scenario, population=population)
        else:
            config = SumoScenarioConfig(population=population or DEFAULT_POPULATION)
        if args.n_vehicles is not None:
            config = dataclasses.replace(
                config, population=dataclasses.replace(config.population, n_vehicles=args.n_vehicles))
        bar = None if args.quiet else ProgressBar()
        try:
            result = run_sumo_scenario(config, args.seed, out_dir=args.out, backend=args.backend, progress=bar)
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
