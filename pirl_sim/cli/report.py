"""``pirl-sim report``: figures and a Markdown summary of a sweep's results (`pirl_sim.engine.report`)."""

from __future__ import annotations

from pathlib import Path

from .common import error, finish, subcommand

__all__ = ["add_parser", "run"]


@subcommand("report", help="figures and a Markdown summary of a sweep's results",
            description="Draw MED vs k, the learners side by side and weight recovery from a sweep's table, and "
            "write README.md with the tables, orderings and the command that made them.")
def add_parser(rp) -> None:
    """The options of ``report``."""
    rp.add_argument("results", type=Path, help="results directory of pirl-sim sweep (or its table.parquet)")
    rp.add_argument("--out", type=Path, help="where to write (default: the results directory)")


def run(args) -> int:
    """``pirl-sim report``: 0, or 2 when the results cannot be read."""
    from pirl_sim.engine.report import write_report

    try:
        written = write_report(args.results, args.out)
    except ValueError as exc:
        return error(exc)
    return finish(f"{', '.join(sorted(written))} to {Path(written['README.md']).parent}/")
