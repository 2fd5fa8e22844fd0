"""``pirl-sim policy-recovery``: train PPO on the env's theta reward and measure how close the weights
recovered from its driving come to the reward's weights (`pirl_sim.experiments.policy_recovery`, the engine kind
``policy-recovery``: resumable)."""

from __future__ import annotations

from pathlib import Path

from pirl_sim.validation import list_arg, positive_float_arg, positive_int_arg

from .common import add_study_options, command_line, finish, run_study, subcommand

__all__ = ["add_parser", "run", "DEFAULT_OUT", "DEFAULTS"]

DEFAULT_OUT = Path("results") / "policy_recovery"
#: `pirl_sim.experiments.policy_recovery.PpoRecoveryConfig`'s defaults of the options, named here so that building
#: the parser does not import the study (a test checks they agree)
DEFAULTS = {"steps": 30_000, "seeds": (0, 1, 2), "eval_seeds": tuple(range(1000, 1010)), "n_steps": 2048,
            "n_vehicles": 8, "initial_vehicles": 2, "speed_dev": 3.0, "acc_sq": 0.3}


@subcommand("policy-recovery",
            help="weights recovered from a PPO agent trained on the theta reward, against the reward's",
            description="Train PPO on the env's theta reward and measure how close the weights recovered from its "
            "driving come to the reward's weights.")
def add_parser(p) -> None:
    """The options of ``policy-recovery``."""
    d = DEFAULTS
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    p.add_argument("--steps", type=positive_int_arg, default=d["steps"],
                   help=f"PPO training steps per seed (default {d['steps']})")
    p.add_argument("--seeds", type=list_arg(int, low=0), default=d["seeds"], help="training seeds, comma-separated")
    p.add_argument("--eval-seeds", type=list_arg(int, low=0), default=d["eval_seeds"], help="evaluation env seeds")
    p.add_argument("--n-steps", type=positive_int_arg, default=d["n_steps"],
                   help=f"PPO rollout length (default {d['n_steps']})")
    p.add_argument("--n-vehicles", type=positive_int_arg, default=d["n_vehicles"],
                   help=f"vehicles of the traffic per episode (default {d['n_vehicles']})")
    p.add_argument("--initial-vehicles", type=int, default=d["initial_vehicles"],
                   help=f"of them on the road at reset (default {d['initial_vehicles']})")
    p.add_argument("--duration", type=positive_float_arg, default=40.0, help="[s] episode time limit (default 40)")
    p.add_argument("--no-normalize-reward", action="store_true", help="train on the unscaled theta reward")
    p.add_argument("--speed-dev", type=positive_float_arg, default=d["speed_dev"], help="reward weight of speed_dev")
    p.add_argument("--acc-sq", type=positive_float_arg, default=d["acc_sq"], help="reward weight of acc_sq")
    add_study_options(p, "cells (a training seed, or the MPC ego) run")


def run(args) -> int:
    """``pirl-sim policy-recovery``: 0, 1 when cells failed (the others are kept), 2 for a bad setting, 130 when
    interrupted (finished cells are kept)."""
    import time

    from pirl_sim.experiments.policy_recovery import PpoRecoveryConfig, collect_records, write_results

    t0, command = time.perf_counter(), command_line("policy-recovery", [])

    def config():
        given = {k: v for k, v in vars(args).items() if k in PpoRecoveryConfig.__dataclass_fields__}  # its fields
        cfg = PpoRecoveryConfig(**given, theta=(("speed_dev", args.speed_dev), ("acc_sq", args.acc_sq)),
                                batch_size=min(PpoRecoveryConfig.batch_size, args.n_steps),
                                normalize_reward=not args.no_normalize_reward)
        return cfg.sweep_data(), cfg

    def report(result, _, cfg) -> int:
        study = collect_records([result.records[k]["result"] for k in result.keys])
        wall = time.perf_counter() - t0
        write_results(study, cfg, args.out, command, wall)
        return finish(f"{args.out}/ in {wall:.0f} s", study["reports"]["ppo"].to_markdown())

    return run_study("policy-recovery", config, report, args, command)
