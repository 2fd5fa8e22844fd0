"""The ``pirl-sim`` command line."""

from __future__ import annotations

import argparse
import logging
import sys
from contextlib import contextmanager
from pathlib import Path

from pirl_sim.harness import reproduce
from pirl_sim.harness.model_cli import add_model_parsers, run_fit_model_command, run_predict_command
from pirl_sim.harness.recovery import add_recover_parser, run_recover_command
from pirl_sim.harness.replay_cli import add_replay_parser, run_replay_command
from pirl_sim.scenarios.highway.cli import add_highway_parser, run_simulate_highway
from pirl_sim.scenarios.simulate_cli import add_simulate_parser
from pirl_sim.scenarios.sumo.cli import add_sumo_parser, run_simulate_sumo
from pirl_sim.sweep.cli import (_workers, add_sweep_parsers, command_line, interrupted, run_report_command,
                                run_sweep_command)
from pirl_sim.threads import add_blas_threads_option, resolve_blas_threads, thread_policy
from pirl_sim.validation import positive_int_arg, seed_arg

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
        description="Reproduce one of the paper's experiments; writes CSV/Markdown tables, figures and a summary. "
        "The experiment is an embedded sweep preset (pirl_sim/sweep/<experiment>.toml): its finished cells are kept "
        "in the output directory (cells/), so an interrupted run resumes where it stopped.",
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
        "--position-range", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
        help="synthetic only: start positions drawn uniformly from [LOW, HIGH] m (default 1 1: the single start)",
    )
    rep.add_argument(
        "--velocity-range", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
        help="synthetic only: start velocities drawn uniformly from [LOW, HIGH] m/s (default 0 0)",
    )
    rep.add_argument("--workers", type=_workers, default=0,
                     help="sweep worker processes (default 0: in this process)")
    rep.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    simulators = add_simulate_parser(sub)
    add_sumo_parser(simulators)
    add_highway_parser(simulators)
    add_sweep_parsers(sub)
    add_recover_parser(sub)
    add_replay_parser(sub)
    add_model_parsers(sub)
    add_blas_threads_option(parser)  # every command: see pirl_sim/threads.py
    return parser


def _reproduce(args) -> int:
    """``pirl-sim reproduce``: 0, 1 when cells failed, 2 for a bad option, 130 when interrupted (finished cells
    are kept)."""
    params = {k: v for k, v in (("n_trajectories", args.n_trajectories), ("n_train", args.n_train),
                                ("position_range", args.position_range), ("velocity_range", args.velocity_range))
              if v is not None}
    out = args.out if args.out is not None else Path("results") / args.experiment
    command = command_line("reproduce", [args.experiment, "--out", str(out)])
    try:
        ranges = [k for k in ("position_range", "velocity_range") if k in params]
        if args.experiment != "synthetic" and ranges:
            flags = " and ".join("--" + k.replace("_", "-") for k in ranges)
            raise ValueError(f"{flags} apply to the synthetic experiment only (the passage starts are its own)")
        table = reproduce.reproduce(args.experiment, out, seed=args.seed, params=params,
                                    history_steps=args.history_steps, workers=args.workers,
                                    progress=not args.quiet, command=command)
    except (TypeError, ValueError, RuntimeError) as exc:  # RuntimeError: cells failed (the others are kept)
        print(f"pirl-sim: error: {exc}", file=sys.stderr)
        return 1 if isinstance(exc, RuntimeError) else 2
    except KeyboardInterrupt:
        return interrupted(out)
    print(table.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    if args.experiment == "synthetic":
        for proto in table["protocol"].unique():
            verdict = "holds" if reproduce.ordering_holds(table, proto) else "does NOT hold"
            print(f"{proto}: MED(TIRL) > MED(PIRL-GMM) > MED(PIRL-kNN) {verdict}")
    print(f"wrote {out}/")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
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
        return run_recover_command(args)
    if args.command == "replay":
        return run_replay_command(args)
    if args.command in ("fit-model", "predict"):
        return run_fit_model_command(args) if args.command == "fit-model" else run_predict_command(args)
    if args.command in ("sweep", "report"):
        return run_sweep_command(args) if args.command == "sweep" else run_report_command(args)
    if args.command == "simulate" and args.simulator == "highway":
        return run_simulate_highway(args)
    if args.command == "simulate" and args.simulator == "sumo":
        return run_simulate_sumo(args)
    if args.command == "reproduce":
        return _reproduce(args)
    return 1  # pragma: no cover - argparse enforces a command


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
