"""``pirl-sim simulate SIMULATOR``: what every simulator's command shares (simulator-neutral).

``pirl_sim/cli.py`` adds the ``simulate`` command with :func:`add_simulate_parser`, then each simulator its
subcommand (``pirl_sim.scenarios.sumo.cli``, ``pirl_sim.scenarios.highway.cli``) through
:func:`add_simulator_parser`, which gives it the common options (``--population``, ``--scenario``,
``--seed``, ``--out``, ``--n-vehicles``, ``--quiet``, ``--print-default-population``);
:func:`run_simulator` runs it (configuration, progress bar, errors, summary) and :class:`ProgressBar` draws
the progress.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pirl_sim.validation import check_output_dir, positive_int_arg, seed_arg

__all__ = ["add_simulate_parser", "add_simulator_parser", "run_simulator", "ProgressBar"]

def add_simulate_parser(subparsers) -> argparse._SubParsersAction:
    """Add the ``simulate`` command to a ``parser.add_subparsers()`` object.

    Returns
    -------
    argparse._SubParsersAction
        The command's own subparsers (``dest="simulator"``): pass it to :func:`add_simulator_parser`.
    """
    sim = subparsers.add_parser(
        "simulate",
        help="simulate a driver population of known cost weights and record it in INTERACTION format",
        description="Simulate a mixed-style driver population whose cost weights are known and record it: "
                    "INTERACTION tracks, a ground-truth table and a Lanelet2 map.",
    )
    simulators = sim.add_subparsers(dest="simulator", metavar="SIMULATOR")
    simulators.required = True
    return simulators


def add_simulator_parser(simulators, name: str, *, help: str, description: str, default_out: Path,
                         scenario_help: str, seed_help: str = "seed of every draw (default 0)"
                         ) -> argparse.ArgumentParser:
    """Add the simulator ``name`` to ``simulate`` with the options every simulator has; returns its parser
    (for options of its own)."""
    p = simulators.add_parser(name, help=help, description=description)
    p.add_argument("--population", type=Path, default=None, metavar="CONFIG",
                   help="population TOML (default: the embedded one, see --print-default-population)")
    p.add_argument("--scenario", type=Path, default=None, metavar="CONFIG", help=scenario_help)
    p.add_argument("--seed", type=seed_arg, default=0, help=seed_help)
    p.add_argument("--out", type=Path, default=default_out,
                   help=f"output directory (default: {default_out.as_posix()})")
    p.add_argument("--n-vehicles", type=positive_int_arg, default=None,
                   help="override the population's number of vehicles")
    p.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    p.add_argument("--print-default-population", action="store_true",
                   help="print the embedded default population as TOML and exit")
    return p


class ProgressBar:
    """The simulation's progress, ``progress(time_s, n_done, n_total)``, as a bar of vehicles done on a stream
    (stderr by default), drawn by tqdm through `pirl_sim.progress.bar` with the simulated time and an ETA: on a
    terminal redrawn in place; otherwise a line at most every ``every`` seconds."""

    def __init__(self, stream=None, every: float = 5.0):
        self.stream = sys.stderr if stream is None else stream
        self.every = every
        self._bar = None

    def __call__(self, time_s: float, n_done: int, n_total: int) -> None:
        if self._bar is None:
            from pirl_sim.progress import bar

            self._bar = bar(n_total, "vehicles done", unit="veh", stream=self.stream, every=self.every)
        self._bar.set_postfix_str(f"{time_s:.1f} s simulated", refresh=False)
        self._bar.update(n_done - self._bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def run_simulator(args: argparse.Namespace, *, default_config: Callable[..., Any],
                  load_scenario: Callable[..., Any], run: Callable[..., Any]) -> int:
    """Run a simulator's command parsed by :func:`add_simulator_parser`.

    Parameters
    ----------
    args : argparse.Namespace
    default_config : callable
        ``default_config(population=...)``: the simulator's scenario configuration without ``--scenario``.
    load_scenario : callable
        ``load_scenario(path, population=...)``: the configuration from ``--scenario``.
    run : callable
        ``run(config, seed, out_dir=..., progress=...)``: runs and records; returns a result with
        ``recording`` and ``timing``.

    Returns
    -------
    int
        0 on success; 2 for a bad configuration (the reason on stderr, nothing written).
    """
    from .population_config import DEFAULT_POPULATION, DEFAULT_POPULATION_TOML, load_population

    if args.print_default_population:
        sys.stdout.write(DEFAULT_POPULATION_TOML)
        return 0
    try:
        population = load_population(args.population) if args.population is not None else None
        if args.scenario is not None:
            config = load_scenario(args.scenario, population=population)
        else:
            config = default_config(population=population or DEFAULT_POPULATION)
        if args.n_vehicles is not None:
            config = dataclasses.replace(
                config, population=dataclasses.replace(config.population, n_vehicles=args.n_vehicles))
        check_output_dir(args.out)  # before the run, not after it
        bar = None if args.quiet else ProgressBar()
        try:
            result = run(config, args.seed, out_dir=args.out, progress=bar)
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
    if "mean_pirl" in t:
        print(f"  PIRL drivers in the network at once: mean {t['mean_pirl']:.1f}, max {t['max_pirl']}")
    for name in config.population.style_names:
        n_style = int((pirl["style_name"] == name).sum())
        n_clean = int((clean["style_name"] == name).sum())
        print(f"  {name}: {n_style} PIRL tracks, {n_clean} without interaction")
    print(f"  collided: {int(gt['collided'].sum())}, removed early: {int(gt['removed_early'].sum())}")
    print(f"wrote {args.out}/")
    return 0
