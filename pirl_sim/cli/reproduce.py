"""``pirl-sim reproduce``: one of the paper's experiments, an embedded sweep preset and its report template
(`pirl_sim.engine.presets.run_preset`)."""

from __future__ import annotations

from pathlib import Path

from pirl_sim.validation import positive_int_arg

from .common import add_seed_option, command_line, error, finish, interrupted, subcommand, table_text, workers_arg

__all__ = ["add_parser", "run"]


@subcommand("reproduce", help="reproduce one of the paper's experiments and write tables and figures",
            description="Reproduce one of the paper's experiments; writes CSV/Markdown tables, figures and a summary. "
            "The experiment is an embedded sweep preset (pirl_sim/experiments/configs/<experiment>.toml): its finished "
            "cells are kept in the output directory (cells/), so an interrupted run resumes where it stopped.")
def add_parser(rep) -> None:
    """The options of ``reproduce``."""
    rep.add_argument("experiment", choices=["synthetic", "passage"], help="synthetic (the paper's LQR point mass) or "
                     "passage (roundabout drivers of three known styles)")
    rep.add_argument("--out", type=Path, help="output directory (default: results/<experiment>)")
    add_seed_option(rep, "every random draw, in [0, 2**31)")
    rep.add_argument("--n-trajectories", type=positive_int_arg,
                     help="trajectories in all (default: synthetic 2000, the paper's; passage 600)")
    rep.add_argument("--n-train", type=positive_int_arg,
                     help="training trajectories (default: synthetic 1800; passage 500)")
    rep.add_argument("--history-steps", type=positive_int_arg, default=10,
                     help="observed steps in the online protocol (default 10)")
    rep.add_argument("--position-range", type=float, nargs=2, metavar=("LOW", "HIGH"), help="synthetic "
                     "only: start positions drawn uniformly from [LOW, HIGH] m (default 1 1: the single start)")
    rep.add_argument("--velocity-range", type=float, nargs=2, metavar=("LOW", "HIGH"),
                     help="synthetic only: start velocities drawn uniformly from [LOW, HIGH] m/s (default 0 0)")
    rep.add_argument("--workers", type=workers_arg, default=0,
                     help="sweep worker processes (default 0: in this process)")
    rep.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def run(args) -> int:
    """``pirl-sim reproduce``: 0, 1 when cells failed, 2 for a bad option, 130 when interrupted (finished cells
    are kept)."""
    from pirl_sim.engine.presets import run_preset
    from pirl_sim.experiments.reproduce import ordering_holds

    params = {k: getattr(args, k) for k in ("n_trajectories", "n_train", "position_range", "velocity_range")
              if getattr(args, k) is not None}
    out = args.out if args.out is not None else Path("results") / args.experiment
    command = command_line("reproduce", [args.experiment, "--out", str(out)])
    try:
        ranges = [k for k in ("position_range", "velocity_range") if k in params]
        if args.experiment != "synthetic" and ranges:
            flags = " and ".join("--" + k.replace("_", "-") for k in ranges)
            raise ValueError(f"{flags} apply to the synthetic experiment only (the passage starts are its own)")
        table = run_preset(args.experiment, out, seed=args.seed, params=params, history_steps=args.history_steps,
                           workers=args.workers, progress=not args.quiet, command=command)
    except (TypeError, ValueError, RuntimeError) as exc:  # RuntimeError: cells failed (the others are kept)
        return error(exc, 1 if isinstance(exc, RuntimeError) else 2)
    except KeyboardInterrupt:
        return interrupted(out)
    orderings = [f"{proto}: MED(TIRL) > MED(PIRL-GMM) > MED(PIRL-kNN) "
                 f"{'holds' if ordering_holds(table, proto) else 'does NOT hold'}"
                 for proto in (table["protocol"].unique() if args.experiment == "synthetic" else ())]
    return finish(f"{out}/", table_text(table), *orderings)
