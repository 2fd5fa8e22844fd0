"""``pirl-sim sweep``: run a sweep config's cells that the results directory does not hold yet."""

from __future__ import annotations

import logging
from pathlib import Path

from .common import command_line, error, interrupted, subcommand, workers_arg

__all__ = ["add_parser", "run", "DEFAULT_OUT"]

DEFAULT_OUT = Path("results") / "sweep"

log = logging.getLogger(__name__)


@subcommand("sweep",
            help="run a grid of scenario x learner x protocol x seed cells; resumable, local processes or Dask",
            description="Run every cell of a sweep config (TOML) that the results directory does not hold yet: local "
            "worker processes by default, a Dask cluster with --scheduler or --scheduler-file. Each finished cell is "
            "stored at once (keyed by its config and the code version): run the same command again after an "
            "interruption and only the missing cells run. Writes table.parquet / table.csv (one row per cell).")
def add_parser(sw) -> None:
    """The options of ``sweep``."""
    sw.add_argument("config", nargs="?", default="default",
                    help="sweep config (TOML); 'default' or nothing: the embedded default (the paper's experiments)")
    sw.add_argument("--workers", type=workers_arg,
                    help="local worker processes (default: the usable cores; 0: run in this process)")
    sw.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                    help="Dask scheduler to run the cells on (workers: same pirl_sim version, --nthreads 1)")
    sw.add_argument("--scheduler-file", type=Path, metavar="PATH",
                    help="instead of --scheduler: the file 'dask scheduler --scheduler-file PATH' wrote")
    sw.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"results directory (default {DEFAULT_OUT})")
    sw.add_argument("--report", action="store_true", help="draw the figures and README.md afterwards (as report)")
    sw.add_argument("--dry-run", action="store_true",
                    help="validate the config and count the cells (and those already stored); run nothing")
    sw.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    """``pirl-sim sweep``: 0 when every cell finished, 1 when some failed, 2 for a bad config or option,
    130 when interrupted (finished cells are kept)."""
    from pirl_sim.engine import ResultStore, load_config, run as engine_run, write_report
    from pirl_sim.engine.executors import check_one_place

    try:
        check_one_place(args.workers, args.scheduler, args.scheduler_file)
        config = load_config(args.config)
    except ValueError as exc:
        return error(exc)
    if args.dry_run:
        store = ResultStore(args.out)
        # a damaged cell file is not stored: it runs again
        version, _, unique, stored, todo = engine_run.plan_cells(config, store)
        sims, _ = engine_run._simulations(unique, todo, store, version)
        sim_part = f" and {len(sims)} simulation{'s' if len(sims) != 1 else ''}" if sims else ""
        print(f"sweep {config.name!r} ({config.source}): {len(config.cells)} cells ({len(unique)} distinct), "
              f"{len(stored)} already in {args.out}/, {len(todo)} to run{sim_part} (code {version})")
        return 0
    try:
        result = engine_run.run_sweep(config, args.out, workers=args.workers, scheduler=args.scheduler,
                                      scheduler_file=args.scheduler_file, progress=not args.quiet,
                                      command=command_line("sweep", [str(args.config), "--out", str(args.out)]))
    except KeyboardInterrupt:
        return interrupted(args.out)
    except (ValueError, OSError) as exc:  # e.g. a bad scheduler address or file, no scheduler there, other versions
        return error(exc)
    print(f"{len(result.table)} cells in {args.out}/table.parquet ({len(result.computed)} run now, "
          f"{len(result.cached)} from the store) in {result.wall_s:.1f} s")
    for key, err in result.failed.items():
        log.warning("cell %s failed: %s", key, err)
    if result.failed:
        log.warning("%d cells failed (details in %s/errors/); they run again next time", len(result.failed), args.out)
    if args.report and not result.table.empty:
        try:
            write_report(args.out)
        except ValueError as exc:  # e.g. a sweep of agents only: its cells are kept, the report says why not
            return error(exc)
        print(f"wrote the report to {args.out}/README.md")
    return 1 if result.failed else 0
