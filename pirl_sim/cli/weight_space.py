"""``pirl-sim weight-space``: mixtures in feature space against mixtures in weight space
(`pirl_sim.experiments.weight_space`)."""

from __future__ import annotations

from pathlib import Path

from pirl_sim.validation import seed_arg

from .common import run_study, workers_arg

__all__ = ["add_parser", "run", "EXPERIMENTS"]

#: `pirl_sim.experiments.weight_space.EXPERIMENTS`, named here so that the parser does not import the study
EXPERIMENTS = ("synthetic-spread", "synthetic", "lq-3-styles", "passage", "lq-receding")


def add_parser(subparsers) -> None:
    """Add ``weight-space`` to the command's subparsers."""
    p = subparsers.add_parser(
        "weight-space",
        help="mixtures in feature space against mixtures in weight space (tables and a figure)",
        description="Feature-space against weight-space mixtures: style recovery, weight errors and multi-modal "
                    "predictions on synthetic, LQ and roundabout-passage drivers of known styles. Finished cells "
                    "are kept in OUT/cells: the same command resumes.")
    p.add_argument("--out", type=Path, default=Path("results") / "weight_space", help="output directory")
    p.add_argument("--seeds", type=seed_arg, nargs="+", default=[0], help="seeds of every draw (default 0)")
    p.add_argument("--experiments", nargs="+", choices=EXPERIMENTS, default=list(EXPERIMENTS), metavar="NAME",
                   help=f"the experiments to run, of {', '.join(EXPERIMENTS)} (default all)")
    p.add_argument("--workers", type=workers_arg, default=1,
                   help="cells run at once, each in its own process (default 1; 0: in this process)")
    p.add_argument("--dry-run", action="store_true", help="check the options and count the cells still to run")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def run(args) -> int:
    """``pirl-sim weight-space``: 0 on success, 1 when cells failed (the others are kept), 2 for a bad value or an
    unusable output directory, 130 when interrupted (finished cells are kept)."""
    from pirl_sim.engine.config import parse_config
    from pirl_sim.evaluation.tables import markdown
    from pirl_sim.experiments.weight_space import study_config, write_study

    experiments = list(dict.fromkeys(args.experiments))
    command = " ".join(["pirl-sim weight-space", *(["--seeds", *map(str, args.seeds)] if args.seeds != [0] else []),
                        *(["--experiments", *experiments] if experiments != list(EXPERIMENTS) else [])])

    def config():
        data, names = study_config(experiments, args.seeds)
        return parse_config(data, source="pirl-sim weight-space"), names

    result, _, names, status = run_study("weight-space", config, args, command)
    if status is not None:
        return status
    out = args.out
    table = write_study([result.records[k]["result"] for k in result.keys], names, out, command)  # in any --out
    print(markdown(table))
    print(f"wrote {out}/")
    return 0
