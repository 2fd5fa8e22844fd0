"""The ``pirl-sim sweep`` and ``pirl-sim report`` commands (wired into `pirl_sim.cli` by `add_sweep_parsers`)."""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
from pathlib import Path

from .config import load_config
from .report import write_report
from .run import plan_cells, _simulations, run_sweep
from .store import ResultStore

__all__ = ["add_sweep_parsers", "run_sweep_command", "run_report_command", "interrupted", "command_line"]

DEFAULT_OUT = Path("results") / "sweep"

log = logging.getLogger(__name__)


def _workers(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of workers >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number of workers >= 0, got {value}")
    return value


def add_sweep_parsers(subparsers) -> None:
    """Add ``sweep`` and ``report`` to an ``argparse`` sub-parser collection."""
    sw = subparsers.add_parser(
        "sweep",
        help="run a grid of scenario x learner x protocol x seed cells; resumable, local processes or Dask",
        description="Run every cell of a sweep config (TOML) that the results directory does not hold yet: local "
        "worker processes by default, a Dask cluster with --scheduler. Each finished cell is stored at once "
        "(keyed by its config and the code version): run the same command again after an interruption and only "
        "the missing cells run. Writes table.parquet / table.csv (one row per cell).",
    )
    sw.add_argument("config", nargs="?", default="default",
                    help="sweep config (TOML); 'default' or nothing: the embedded default (the paper's experiments)")
    sw.add_argument("--workers", type=_workers, default=None,
                    help="local worker processes (default: the usable cores; 0: run in this process)")
    sw.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                    help="Dask scheduler to run the cells on (workers: same pirl_sim version, --nthreads 1)")
    sw.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"results directory (default {DEFAULT_OUT})")
    sw.add_argument("--report", action="store_true", help="draw the figures and README.md afterwards (as report)")
    sw.add_argument("--dry-run", action="store_true",
                    help="validate the config and count the cells (and those already stored); run nothing")
    sw.add_argument("--quiet", action="store_true", help="no progress bar")

    rp = subparsers.add_parser(
        "report",
        help="figures and a Markdown summary of a sweep's results",
        description="Draw MED vs k, the learners side by side and weight recovery from a sweep's table, and "
        "write README.md with the tables, orderings and the command that made them.",
    )
    rp.add_argument("results", type=Path, help="results directory of pirl-sim sweep (or its table.parquet)")
    rp.add_argument("--out", type=Path, default=None, help="where to write (default: the results directory)")


def command_line(name: str, fallback: list[str]) -> str:
    """The command ``name`` as typed (its arguments shell-quoted), or ``pirl-sim NAME FALLBACK...`` when it was
    called from Python: what ``sweep.json`` and the READMEs record."""
    argv = sys.argv[1:]
    return "pirl-sim " + shlex.join(argv[argv.index(name):] if name in argv else [name, *fallback])


def interrupted(out) -> int:
    """Say that an interrupted run keeps its finished cells in ``out`` (sweep, reproduce, replay); exit status 130."""
    print(f"\ninterrupted: finished cells are kept in {out}/cells/; run the same command to resume", file=sys.stderr)
    return 130


def run_sweep_command(args) -> int:
    """``pirl-sim sweep``: 0 when every cell finished, 1 when some failed, 2 for a bad config or option,
    130 when interrupted (finished cells are kept)."""
    try:
        if args.workers is not None and args.scheduler is not None:
            raise ValueError("give --workers or --scheduler, not both: with a scheduler the Dask workers run the cells")
        config = load_config(args.config)
    except ValueError as exc:
        print(f"pirl-sim: error: {exc}", file=sys.stderr)
        return 2
    if args.dry_run:
        store = ResultStore(args.out)
        version, _, unique, stored, todo = plan_cells(config, store)  # a damaged cell file is not stored: it runs again
        sims, _ = _simulations(unique, todo, store, version)
        sim_part = f" and {len(sims)} simulation{'s' if len(sims) != 1 else ''}" if sims else ""
        print(f"sweep {config.name!r} ({config.source}): {len(config.cells)} cells ({len(unique)} distinct), "
              f"{len(stored)} already in {args.out}/, {len(todo)} to run{sim_part} (code {version})")
        return 0
    try:
        run = run_sweep(config, args.out, workers=args.workers, scheduler=args.scheduler, progress=not args.quiet,
                        command=command_line("sweep", [str(args.config), "--out", str(args.out)]))
    except KeyboardInterrupt:
        return interrupted(args.out)
    except (ValueError, OSError) as exc:  # e.g. a bad scheduler address, no scheduler at that address
        print(f"pirl-sim: error: {exc}", file=sys.stderr)
        return 2
    print(f"{len(run.table)} cells in {args.out}/table.parquet ({len(run.computed)} run now, {len(run.cached)} "
          f"from the store) in {run.wall_s:.1f} s")
    for key, err in run.failed.items():
        log.warning("cell %s failed: %s", key, err)
    if run.failed:
        log.warning("%d cells failed (details in %s/errors/); they run again next time", len(run.failed), args.out)
    if args.report and not run.table.empty:
        try:
            write_report(args.out)
        except ValueError as exc:  # e.g. a sweep of agents only: its cells are kept, the report says why not
            print(f"pirl-sim: error: {exc}", file=sys.stderr)
            return 2
        print(f"wrote the report to {args.out}/README.md")
    return 1 if run.failed else 0


def run_report_command(args) -> int:
    """``pirl-sim report``: 0, or 2 when the results cannot be read."""
    try:
        written = write_report(args.results, args.out)
    except ValueError as exc:
        print(f"pirl-sim: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {', '.join(sorted(written))} to {Path(written['README.md']).parent}/")
    return 0
