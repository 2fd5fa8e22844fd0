"""``pirl-sim fit-model``: fit one learner on recorded tracks and write it to a versioned ``.npz`` model file.

The tracks are INTERACTION-format files on their Lanelet2 map (`pirl_sim.scenarios.replay.load_replay`, with a
pirl_sim recording's own driver-model settings from its ``run.json``); the model's features, desired speed and
selection of tracks default to ``pirl-sim replay``'s (``--preset``). The file is written by
`pirl_sim.learners.model_io` (no pickle); ``pirl-sim predict`` reads it and builds the same model on its tracks.
"""

from __future__ import annotations

from pathlib import Path

from pirl_sim.validation import positive_float_arg, positive_int_arg

from .common import add_seed_option, add_track_options, error, finish, load_track_scene, seconds_to_steps, subcommand

__all__ = ["add_parser", "run", "LEARNER_KEYS"]

LEARNER_KEYS = ("tirl", "pirl-gmm", "pirl-dpgmm", "pirl-knn")


@subcommand("fit-model", help="fit a learner on recorded tracks and write the model to a file",
            description="Fit TIRL, PIRL-GMM, PIRL-DPGMM or PIRL-kNN on recorded tracks (INTERACTION format, "
            "Lanelet2 map) and write it as a versioned .npz model file (pirl_sim.learners.model_io; no pickle).")
def add_parser(fm) -> None:
    """The options of ``fit-model``."""
    add_track_options(fm)
    fm.add_argument("--preset", choices=("best", "paper"), default="best",
                    help="the model's settings not given: 'best' (as pirl-sim replay's default: --features "
                         "speed-level, --desired-speed fit, free-flow runs of every track) or 'paper' (features "
                         "paper, the fixed desired speed, whole tracks without a leader); drivers whose model is "
                         "known (a pirl_sim recording, a ground_truth.csv) keep their own (default best)")
    fm.add_argument("--features", choices=("paper", "speed-level"),
                    help="the cost's features (pirl_sim.driving.roundabout_features) (default: --preset's)")
    fm.add_argument("--desired-speed", choices=("fit", "fixed"),
                    help="the desired speed's a_lat and v_max fitted on the tracks (pirl_sim.speed_fit) or fixed "
                         "(1.8 m/s^2, 13.9 m/s; a pirl_sim recording's drivers' values) (default: --preset's)")
    fm.add_argument("--learner", choices=LEARNER_KEYS, default="pirl-gmm", help="the learner (default pirl-gmm)")
    fm.add_argument("--k", type=positive_int_arg, default=3,
                    help="clusters of PIRL-GMM, neighbours of PIRL-kNN (default 3)")
    fm.add_argument("--space", choices=["features", "weights"], default="features",
                    help="pirl-gmm / pirl-dpgmm: cluster in feature space (the paper's) or the per-demonstration "
                         "weight posteriors (default features)")
    fm.add_argument("--window", type=positive_float_arg, default=2.0,
                    help="look-up window [s]: histories are described by their last WINDOW seconds (default 2)")
    fm.add_argument("--dt", type=positive_float_arg, help="model step [s], a multiple of 0.1 s (default "
                    "0.2; with --likelihood receding on a pirl_sim recording its drivers' re-planning step)")
    fm.add_argument("--likelihood", choices=["trajectory", "receding"], default="trajectory",
                    help="the IRL's model of a demonstration (default trajectory, the paper's)")
    fm.add_argument("--mpc-horizon", type=positive_int_arg, metavar="H",
                    help="the drivers' MPC horizon [steps of --dt] for --likelihood receding (default: a pirl_sim "
                         "recording's drivers.horizon; required for real data)")
    add_seed_option(fm, "the mixture's EM initialisation")
    fm.add_argument("--out", type=Path, required=True, help="model file to write (.npz appended if missing)")


def run(args) -> int:
    """``pirl-sim fit-model``: 0, or 2 for a bad option or unusable data."""
    import warnings

    import numpy as np

    from pirl_sim.learners import make_learner
    from pirl_sim.progress import reporter

    say = reporter(not args.quiet)
    try:
        from pirl_sim.scenarios.replay import recording_settings

        receding, rec = args.likelihood == "receding", recording_settings(args.tracks)
        dt = args.dt if args.dt is not None else (rec.dt if receding and rec is not None else 0.2)
        horizon = args.mpc_horizon
        if receding and horizon is None:
            if rec is None or abs(rec.dt - dt) > 1e-9:
                raise ValueError("--likelihood receding needs --mpc-horizon H, the drivers' MPC horizon in steps of "
                                 f"--dt ({dt:g} s)" + ("" if rec is None else f"; the recording's drivers re-plan "
                                                       f"every {rec.dt:g} s over {rec.horizon} steps"))
            horizon = rec.horizon
        if args.space == "weights" and args.learner not in ("pirl-gmm", "pirl-dpgmm"):
            raise ValueError(f"--space weights is an option of pirl-gmm and pirl-dpgmm, not {args.learner}")
        from pirl_sim.experiments.recorded import desired_speed_model

        from .replay import data_preset

        preset = data_preset(args.tracks, args.preset)
        scene = load_track_scene(args, dt, say, receding, features=args.features or preset["features"],
                                 selection=None if receding else preset["selection"])
        model = scene.model
        if (args.desired_speed or preset["desired_speed"]) == "fit":
            model, speed, _ = desired_speed_model(scene, "fit", scene.selected)
            say(f"desired speed fitted on the tracks: a_lat {speed['a_lat']:.3g} m/s^2, v_max {speed['v_max']:.3g} m/s")
        params = {"model": model, "window": seconds_to_steps(args.window, dt, "--window"), "windows": "sliding"}
        if receding:
            params.update(likelihood="receding", horizon=horizon)
        params.update({"pirl-gmm": {"n_components": args.k, "random_state": args.seed, "space": args.space},
                       "pirl-dpgmm": {"random_state": args.seed, "space": args.space},
                       "pirl-knn": {"n_neighbors": args.k}}.get(args.learner, {}))
        learner = make_learner(args.learner, **params)
        say(f"fitting {type(learner).__name__} on {len(scene.selected)} trajectories")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            learner.fit(scene.selected)
        for w in caught:
            say(f"warning: {w.message}")
        path = learner.save(args.out)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        return error(exc)
    names = model.features.names
    theta = np.atleast_2d(getattr(learner, "theta_", getattr(learner, "demo_theta_", None)))  # type: ignore[arg-type]
    label = "style" if theta.shape[0] > 1 and hasattr(learner, "n_styles_") else "demo" if theta.shape[0] > 1 else ""
    print(f"{type(learner).__name__}: {theta.shape[0]} weight vector(s) over {list(names)}")
    for i, row in enumerate(theta[:10]):
        print(f"  {label} {i}: " + ", ".join(f"{n}={w:.4g}" for n, w in zip(names, row)))
    if theta.shape[0] > 10:
        print(f"  ... {theta.shape[0] - 10} more")
    styles = [t.metadata.get("style") for t in scene.selected]
    if hasattr(learner, "labels_") and all(x is not None for x in styles):  # ground truth known (a recording)
        from pirl_sim.metrics import adjusted_rand_index

        print(f"ARI of the styles against the recording's ground truth: "
              f"{adjusted_rand_index(np.asarray(styles, dtype=int), learner.labels_):.3f} ({len(styles)} trajectories)")
    return finish(path)
