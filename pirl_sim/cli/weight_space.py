"""``pirl-sim weight-space``: mixtures in feature space against mixtures in weight space
(`pirl_sim.experiments.weight_space`)."""

from __future__ import annotations

from pathlib import Path

from pirl_sim.validation import seed_arg

from .common import add_study_options, finish, run_study, subcommand

__all__ = ["add_parser", "run", "EXPERIMENTS"]

#: `pirl_sim.experiments.weight_space.EXPERIMENTS`, named here so that the parser does not import the study
EXPERIMENTS = ("synthetic-spread", "synthetic", "lq-3-styles", "passage", "lq-receding")


@subcommand("weight-space", help="mixtures in feature space against mixtures in weight space (tables and a figure)",
            description="Feature-space against weight-space mixtures: style recovery, weight errors and multi-modal "
            "predictions on synthetic, LQ and roundabout-passage drivers of known styles. Finished cells are kept in "
            "OUT/cells: the same command resumes.")
def add_parser(p) -> None:
    """The options of ``weight-space``."""
    p.add_argument("--out", type=Path, default=Path("results") / "weight_space", help="output directory")
    p.add_argument("--seeds", type=seed_arg, nargs="+", default=[0], help="seeds of every draw (default 0)")
    p.add_argument("--experiments", nargs="+", choices=EXPERIMENTS, default=list(EXPERIMENTS), metavar="NAME",
                   help=f"the experiments to run, of {', '.join(EXPERIMENTS)} (default all)")
    add_study_options(p, "cells run")


def run(args) -> int:
    """``pirl-sim weight-space``: 0 on success, 1 when cells failed (the others are kept), 2 for a bad value or an
    unusable output directory, 130 when interrupted (finished cells are kept)."""
    from pirl_sim.evaluation.tables import markdown
    from pirl_sim.experiments.weight_space import study_config, write_study

    experiments = list(dict.fromkeys(args.experiments))
    command = " ".join(["pirl-sim weight-space", *(["--seeds", *map(str, args.seeds)] if args.seeds != [0] else []),
                        *(["--experiments", *experiments] if experiments != list(EXPERIMENTS) else [])])

    def report(result, _, names) -> int:
        table = write_study([result.records[k]["result"] for k in result.keys], names, args.out, command)  # any --out
        return finish(f"{args.out}/", markdown(table))

    return run_study("weight-space", lambda: study_config(experiments, args.seeds), report, args, command)
