"""The ``pirl-sim`` command line."""

from __future__ import annotations

import argparse
import logging
import sys
from contextlib import contextmanager
from pathlib import Path

from pirl_sim.validation import check_output_dir, positive_int_arg, seed_arg

__all__ = ["main", "build_parser", "package_version", "cli_logging"]


def package_version() -> str:
    """The installed version of pirl_sim, from the package metadata (``pyproject.toml``'s ``version``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pirl_sim")
    except PackageNotFoundError:  # pragma: no cover - run from a source tree that was never installed
        return "unknown (not installed)"


@contextmanager
def cli_logging(verbose: bool = False):
    """Diagnostics of the ``pirl_sim`` loggers on stderr while a command runs: warnings always, progress and
    details (INFO) with ``--verbose``; the bare message, as the commands printed before. Removed on exit, so
    calling `main` again (tests, notebooks) adds no second handler."""
    logger = logging.getLogger("pirl_sim")
    handler = logging.StreamHandler(sys.stderr)
    handler.setLevel(logging.INFO if verbose else logging.WARNING)
    handler.setFormatter(logging.Formatter("%(message)s"))
    old_level = logger.level
    if verbose and logger.getEffectiveLevel() > logging.INFO:
        logger.setLevel(logging.INFO)
    logger.addHandler(handler)
    try:
        yield handler
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pirl-sim",
        description="Probabilistic IRL of diverse drivers: generate, learn, predict, score.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log progress and details (INFO) on stderr, not only warnings")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    rep = sub.add_parser(
        "reproduce",
        help="reproduce one of the paper's experiments and write tables and figures",
        description="Reproduce one of the paper's experiments; writes CSV/Markdown tables, figures and a summary.",
    )
    rep.add_argument(
        "experiment",
        choices=["synthetic", "passage"],
        help="synthetic (the paper's LQR point mass) or passage (roundabout drivers of three known styles)",
    )
    rep.add_argument("--out", type=Path, default=None, help="output directory (default: results/<experiment>)")
    rep.add_argument("--seed", type=seed_arg, default=0, help="seed of every random draw, in [0, 2**31) (default 0)")
    rep.add_argument(
        "--n-trajectories", type=positive_int_arg, default=None,
        help="trajectories in all (default: synthetic 2000, the paper's; passage 600)",
    )
    rep.add_argument(
        "--n-train", type=positive_int_arg, default=None, help="training trajectories (default: synthetic 1800; passage 500)"
    )
    rep.add_argument(
        "--history-steps", type=positive_int_arg, default=10, help="observed steps in the online protocol (default 10)"
    )
    rep.add_argument(
        "--position-range", type=float, nargs=2, default=(1.0, 1.0), metavar=("LOW", "HIGH"),
        help="start positions drawn uniformly from [LOW, HIGH] m (default 1 1: the single start)",
    )
    rep.add_argument(
        "--velocity-range", type=float, nargs=2, default=(0.0, 0.0), metavar=("LOW", "HIGH"),
        help="start velocities drawn uniformly from [LOW, HIGH] m/s (default 0 0)",
    )
    rep.add_argument("--quiet", action="store_true", help="no progress lines on stderr")

    from pirl_sim.scenarios.highway.cli import add_highway_parser
    from pirl_sim.scenarios.simulate_cli import add_simulate_parser
    from pirl_sim.scenarios.sumo.cli import add_sumo_parser
    from pirl_sim.sweep.cli import add_sweep_parsers

    simulators = add_simulate_parser(sub)
    add_sumo_parser(simulators)
    add_highway_parser(simulators)
    add_sweep_parsers(sub)
    from pirl_sim.harness.recovery import add_recover_parser

    add_recover_parser(sub)

    from pirl_sim.harness.replay_cli import add_replay_parser

    add_replay_parser(sub)
    from pirl_sim.harness.model_cli import add_model_parsers

    add_model_parsers(sub)
    from pirl_sim.threads import add_blas_threads_option

    add_blas_threads_option(parser)  # every command: see pirl_sim/threads.py
    return parser


def _replay(args) -> int:
    from pirl_sim.harness.replay_cli import run_replay_command

    return run_replay_command(args)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from pirl_sim.threads import resolve_blas_threads, thread_policy

    option = getattr(args, "blas_threads", None)
    try:
        resolve_blas_threads(option)  # a bad $PIRL_SIM_BLAS_THREADS stops the command before any work
    except ValueError as exc:
        print(f"pirl-sim: error: {exc}", file=sys.stderr)
        return 2
    with thread_policy(option), cli_logging(getattr(args, "verbose", False)):  # both restored on return
        return _run(args)


def _run(args) -> int:
    """Run the parsed command (inside the thread policy, see `main`)."""
    if args.command == "recover":
        from pirl_sim.harness.recovery import run_recover_command

        return run_recover_command(args)
    if args.command == "replay":
        return _replay(args)
    if args.command in ("fit-model", "predict"):
        from pirl_sim.harness.model_cli import run_fit_model_command, run_predict_command

        return run_fit_model_command(args) if args.command == "fit-model" else run_predict_command(args)
    if args.command in ("sweep", "report"):
        from pirl_sim.sweep.cli import run_report_command, run_sweep_command

        return run_sweep_command(args) if args.command == "sweep" else run_report_command(args)
    if args.command == "simulate" and args.simulator == "highway":
        from pirl_sim.scenarios.highway.cli import run_simulate_highway

        return run_simulate_highway(args)
    if args.command == "simulate" and args.simulator == "sumo":
        from pirl_sim.scenarios.sumo.cli import run_simulate_sumo

        return run_simulate_sumo(args)
    if args.command == "reproduce" and args.experiment == "passage":
        from pirl_sim.harness.reproduce import reproduce_passage
        from pirl_sim.scenarios.passage import PassageConfig

        try:
            sizes = {k: v for k, v in (("n_trajectories", args.n_trajectories), ("n_train", args.n_train)) if v}
            config = PassageConfig(seed=args.seed, **sizes)
        except (TypeError, ValueError) as exc:
            print(f"pirl-sim: error: {exc}", file=sys.stderr)
            return 2
        out = args.out if args.out is not None else Path("results") / "passage"
        try:
            check_output_dir(out)  # before the work, not after it
        except ValueError as exc:
            print(f"pirl-sim: error: {exc}", file=sys.stderr)
            return 2
        table = reproduce_passage(out, config, history_steps=args.history_steps, progress=not args.quiet)
        print(table.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
        print(f"wrote {out}/")
        return 0
    if args.command == "reproduce":
        from pirl_sim.harness.reproduce import reproduce_synthetic, ordering_holds
        from pirl_sim.scenarios.synthetic import SyntheticConfig

        try:
            config = SyntheticConfig(
                n_trajectories=args.n_trajectories or 2000,
                n_train=args.n_train or 1800,
                seed=args.seed,
                position_range=tuple(args.position_range),
                velocity_range=tuple(args.velocity_range),
            )
            if args.history_steps >= config.n_steps:
                raise ValueError(
                    f"--history-steps must be less than the {config.n_steps} steps of a trajectory, got {args.history_steps}"
                )
            out = check_output_dir(args.out if args.out is not None else Path("results") / args.experiment)
        except (TypeError, ValueError) as exc:
            print(f"pirl-sim: error: {exc}", file=sys.stderr)
            return 2
        table = reproduce_synthetic(out, config, history_steps=args.history_steps, progress=not args.quiet)
        print(table.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
        for proto in table["protocol"].unique():
            verdict = "holds" if ordering_holds(table, proto) else "does NOT hold"
            print(f"{proto}: MED(TIRL) > MED(PIRL-GMM) > MED(PIRL-kNN) {verdict}")
        print(f"wrote {out}/")
        return 0
    return 1  # pragma: no cover - argparse enforces a command


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
