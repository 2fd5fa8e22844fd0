"""``pirl-sim agents``: PPO on ``pirl_sim/Roundabout-v0`` per observation mode against scripted egos
(`pirl_sim.experiments.agents_study`, run by `pirl_sim.engine.presets.run_agents`; resumable)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pirl_sim.validation import list_arg, positive_int_arg

from .common import command_line, error, finish, optional_arg, print_plan, subcommand

__all__ = ["add_parser", "run", "DEFAULT_OUT", "MODES", "ACTIONS", "BASELINES", "DEFAULT_SCALES", "DEFAULTS"]

DEFAULT_OUT = Path("results") / "agents"

# Named here so that building the parser imports neither the env nor the study (a test checks they agree):
MODES = ("none", "truth", "inferred")  #: `pirl_sim.experiments.agents.MODES`
ACTIONS = ("residual-idm", "shielded-residual-idm", "idm-speed", "direct")  #: `pirl_sim.experiments.agents.ACTIONS`
BASELINES = ("hold-speed", "idm", "mpc")  #: `pirl_sim.experiments.agents_study.BASELINE_POLICIES`
#: `pirl_sim.experiments.agents_study.DEFAULT_SCALES`
DEFAULT_SCALES = {"residual-idm": 1.0, "shielded-residual-idm": 1.0, "idm-speed": 0.3, "direct": 1.0}
#: `pirl_sim.experiments.agents_study.AgentsConfig`'s defaults of the options (``episodes``: its evaluation seeds,
#: ``eval_seed`` the first)
DEFAULTS = {"action": "idm-speed", "direct_modes": ("none",), "max_change": 0.05, "seeds": (0, 1, 2), "steps": 80_000,
            "episodes": 200, "eval_seed": 1000, "n_steps": 1024, "gamma": 0.99, "learning_rate": 3e-4,
            "log_std_init": -2.0, "observe_residual": True, "select_every": None, "select_episodes": 10}


@subcommand("agents", help="PPO agents in a crowd of known styles against scripted egos (resumable)",
            description="Agents in a crowd of known styles: PPO on ``pirl_sim/Roundabout-v0`` per observation mode, "
            "against scripted egos.")
def add_parser(ap) -> None:
    """The options of ``agents``."""
    d = DEFAULTS
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    ap.add_argument("--modes", type=list_arg(str, empty=True), default=MODES, help="observation modes, e.g. none,truth")
    ap.add_argument("--action", default=d["action"], help=f"PPO's action, one of {ACTIONS}")
    ap.add_argument("--direct-modes", type=list_arg(str, empty=True), default=d["direct_modes"],
                    help="modes in which PPO also learns the direct action (default none; '' for no such run)")
    ap.add_argument("--residual-scale", type=float, help="largest residual correction in action units, or with "
                    f"idm-speed the largest change of the desired-speed factor (default per action: {DEFAULT_SCALES})")
    ap.add_argument("--max-change", type=optional_arg(float, "a number"), default=d["max_change"],
                    help="largest change of the residual (or factor) per agent step, or 'none' (default %(default)s)")
    ap.add_argument("--seeds", type=list_arg(int, empty=True), default=d["seeds"], help="training seeds, e.g. 0,1,2")
    ap.add_argument("--steps", type=int, default=d["steps"], help="PPO steps per run")
    ap.add_argument("--episodes", type=int, default=d["episodes"],
                    help="evaluation episodes (env seeds --eval-seed, --eval-seed + 1, ...)")
    ap.add_argument("--baselines", type=list_arg(str, empty=True), default=BASELINES)
    ap.add_argument("--n-steps", type=int, default=d["n_steps"], help="PPO rollout length")
    ap.add_argument("--gamma", type=float, default=d["gamma"], help="PPO's discount (default %(default)s)")
    ap.add_argument("--learning-rate", type=float, default=d["learning_rate"],
                    help="PPO's learning rate (default %(default)s)")
    ap.add_argument("--log-std-init", type=float, default=d["log_std_init"],
                    help="initial log standard deviation of PPO's exploration noise (default %(default)s)")
    ap.add_argument("--observe-residual", action=argparse.BooleanOptionalAction, default=d["observe_residual"],
                    help="PPO (residual action) also observes the IDM ego's action, its correction and the cap; "
                         "(idm-speed) the factor in force and the desired speed (default %(default)s)")
    ap.add_argument("--eval-seed", type=int, default=d["eval_seed"],
                    help="env seed of the first evaluation episode (default %(default)s; design choices are better "
                         "made on other seeds than the committed evaluation's)")
    ap.add_argument("--select-every", type=optional_arg(int, "a whole number"), default=d["select_every"],
                    help="environment steps between checks of PPO's policy on validation episodes (the best "
                         "check's policy is evaluated), or 'none': the last policy (default %(default)s)")
    ap.add_argument("--select-episodes", type=int, default=d["select_episodes"],
                    help="validation episodes per check (env seeds 2000, 2001, ...; default %(default)s)")
    ap.add_argument("--workers", type=positive_int_arg, default=1,
                    help="worker processes (runs in parallel; default 1: in this process)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument("--dry-run", action="store_true",
                    help="say how many runs are finished in --out under the current code, and run nothing")


def run(args) -> int:
    """``pirl-sim agents``: 0, or 2 for a bad setting."""
    from pirl_sim.experiments.agents_study import AgentsConfig, markdown_table, write_results

    try:  # the options named as AgentsConfig fields, and the evaluation seeds
        given = {k: v for k, v in vars(args).items() if k in AgentsConfig.__dataclass_fields__}
        cfg = AgentsConfig(**given, eval_seeds=tuple(range(args.eval_seed, args.eval_seed + args.episodes)),
                           batch_size=min(AgentsConfig.batch_size, args.n_steps))
    except ValueError as exc:
        return error(exc)
    from pirl_sim.engine.presets import agents_config, run_agents

    if args.dry_run:
        print_plan(agents_config(cfg), args.out, "agents experiment", unit="runs")
        return 0
    import pandas as pd

    from pirl_sim.threads import blas_threads

    command = command_line("agents", ["--out", str(args.out)])
    with blas_threads(1):
        result = run_agents(cfg, args.out, workers=args.workers, progress=not args.quiet, command=command)
        files = write_results(cfg, result, args.out, command)
    return finish(f"{', '.join(str(p) for p in files.values())} ({result.wall_time_s:.0f} s)",
                  markdown_table(pd.read_csv(files["table"])))
