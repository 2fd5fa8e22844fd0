"""`write_report`: a sweep's results directory (or table file) through the report template
`pirl_sim.experiments.sweep_report`."""

from __future__ import annotations

from pathlib import Path

from pirl_sim.experiments.sweep_report import write_sweep_report

from .run import read_table, template_run

__all__ = ["write_report"]


def write_report(results, out_dir=None) -> dict:
    """Draw the figures and write ``README.md`` for a sweep's results.

    Parameters
    ----------
    results : path       a results directory of `pirl-sim sweep` (or its table.parquet / table.csv), or a report
                         template's results directory (``pirl-sim replay``, ``reproduce``: its stored cells)
    out_dir : path       where to write (default: the results directory; a report template's ``report/``,
                         beside its own README.md)

    Returns
    -------
    dict {name: path} of the files written.
    """
    results = Path(results)
    table, template = read_table(results), results.is_dir() and template_run(results)
    if out_dir is None:
        res_dir = results if results.is_dir() else results.parent
        out_dir = res_dir / "report" if template else res_dir
    return write_sweep_report(table, results, out_dir, template=template)
