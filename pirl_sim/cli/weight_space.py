"""``pirl-sim weight-space``: mixtures in feature space against mixtures in weight space
(`pirl_sim.experiments.weight_space`)."""

from __future__ import annotations

from pathlib import Path

from pirl_sim.validation import seed_arg

from .common import error

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> None:
    """Add ``weight-space`` to the command's subparsers."""
    p = subparsers.add_parser(
        "weight-space",
        help="mixtures in feature space against mixtures in weight space (tables and a figure)",
        description="Feature-space against weight-space mixtures: style recovery, weight errors and multi-modal "
                    "predictions on synthetic, LQ and roundabout-passage drivers of known styles.")
    p.add_argument("--out", type=Path, default=Path("results") / "weight_space", help="output directory")
    p.add_argument("--seed", type=seed_arg, default=0, help="seed of every draw (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def run(args) -> int:
    """``pirl-sim weight-space``: 0, or 2 for an unusable output directory."""
    from pirl_sim.evaluation.tables import markdown
    from pirl_sim.experiments.weight_space import run_study, write_study
    from pirl_sim.progress import reporter
    from pirl_sim.validation import check_output_dir

    try:
        out = check_output_dir(args.out)
    except ValueError as exc:
        return error(exc)
    figures: dict = {}
    table = run_study(args.seed, reporter(not args.quiet), figures)
    command = "pirl-sim weight-space" + (f" --seed {args.seed}" if args.seed else "")  # the same bytes in any --out
    write_study(table, figures, out, command)
    print(markdown(table))
    print(f"wrote {out}/")
    return 0
