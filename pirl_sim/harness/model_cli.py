"""``pirl-sim fit-model`` and ``pirl-sim predict``: learn a cost model from recordings and keep it in a file, then
predict recorded drivers' futures with the saved model.

``fit-model`` reads INTERACTION-format tracks on their Lanelet2 map (`pirl_sim.scenarios.replay.load_replay`,
with a pirl_sim recording's own driver-model settings from its ``run.json`` when there is one), fits one learner
on the selected tracks and writes it with `pirl_sim.learners.model_io` (a versioned ``.npz`` that needs no
pickle). ``predict`` reads a saved learner and tracks (the same map, or another one with the same model step and
features), predicts each selected track's future from its first ``--history`` seconds and writes one CSV row per
predicted step, with the recorded position where the track has one and the weights used.

A saved path model carries the arc-length layout of the scene it was fitted on; ``predict`` runs the learner on
the layout of the tracks it reads (their own `CompositePath`), after checking that the model step, the state,
control and feature names and the reference feature agree: weights and styles do not depend on the layout.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
from pathlib import Path

import numpy as np

from pirl_sim.harness.replay_cli import seconds_to_steps
from pirl_sim.progress import reporter
from pirl_sim.validation import positive_float_arg, positive_int_arg, seed_arg

__all__ = ["add_model_parsers", "run_fit_model_command", "run_predict_command", "rebind_model", "LEARNER_KEYS"]

LEARNER_KEYS = ("tirl", "pirl-gmm", "pirl-dpgmm", "pirl-knn")


def _add_data_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tracks", type=Path, required=True, help="a vehicle_tracks_*.csv file or a directory of them")
    p.add_argument("--map", type=Path, required=True, help="the Lanelet2 OSM map of the recording")
    p.add_argument("--files", type=positive_int_arg, default=None,
                   help="use only the first N track files (sorted by name) (default all)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def add_model_parsers(sub) -> None:
    """The ``fit-model`` and ``predict`` subcommands on an argparse subparsers object."""
    fm = sub.add_parser(
        "fit-model",
        help="fit a learner on recorded tracks and write the model to a file",
        description="Fit TIRL, PIRL-GMM, PIRL-DPGMM or PIRL-kNN on recorded tracks (INTERACTION format, Lanelet2 "
        "map) and write it as a versioned .npz model file (pirl_sim.learners.model_io; no pickle).",
    )
    _add_data_options(fm)
    fm.add_argument("--learner", choices=LEARNER_KEYS, default="pirl-gmm", help="the learner (default pirl-gmm)")
    fm.add_argument("--k", type=positive_int_arg, default=3,
                    help="clusters of PIRL-GMM, neighbours of PIRL-kNN (default 3)")
    fm.add_argument("--space", choices=["features", "weights"], default="features",
                    help="pirl-gmm / pirl-dpgmm: cluster in feature space (the paper's) or the per-demonstration "
                         "weight posteriors (issue 14; default features)")
    fm.add_argument("--window", type=positive_float_arg, default=2.0,
                    help="look-up window [s]: histories are described by their last WINDOW seconds (default 2)")
    fm.add_argument("--dt", type=positive_float_arg, default=None,
                    help="model step [s], a multiple of 0.1 s (default 0.2; with --likelihood receding on a pirl_sim "
                         "recording its drivers' re-planning step)")
    fm.add_argument("--likelihood", choices=["trajectory", "receding"], default="trajectory",
                    help="the IRL's model of a demonstration (default trajectory, the paper's)")
    fm.add_argument("--mpc-horizon", type=positive_int_arg, default=None, metavar="H",
                    help="the drivers' MPC horizon [steps of --dt] for --likelihood receding (default: a pirl_sim "
                         "recording's drivers.horizon; required for real data)")
    fm.add_argument("--seed", type=seed_arg, default=0, help="seed of the mixture's EM initialisation (default 0)")
    fm.add_argument("--out", type=Path, required=True, help="model file to write (.npz appended if missing)")

    pr = sub.add_parser(
        "predict",
        help="predict recorded drivers' futures with a saved model",
        description="Read a model file written by fit-model (or BaseLearner.save) and recorded tracks; predict every "
        "selected track's future from its first --history seconds; write one CSV row per predicted step.",
    )
    _add_data_options(pr)
    pr.add_argument("--model", type=Path, required=True, help="model file written by fit-model")
    pr.add_argument("--history", type=positive_float_arg, default=None,
                    help="observed history [s] (default: the model's look-up window, else 2)")
    pr.add_argument("--horizon", type=positive_float_arg, default=3.0, help="predicted horizon [s] (default 3)")
    pr.add_argument("--out", type=Path, required=True, help="CSV file of the predictions")


def _load_scene(args, dt: float, say, receding: bool = False):
    """The selected tracks: whole tracks without interaction, or, with the receding likelihood on a recording
    with per-step driver flags, every PIRL track with its step mask (as ``pirl-sim replay``)."""
    from pirl_sim.io.interaction import find_track_files
    from pirl_sim.scenarios.replay import (DRIVER_STEPS_FILE, SIMULATED_NOISE, is_recording, load_replay,
                                           recording_settings)

    files = find_track_files(args.tracks) if args.tracks.is_dir() else [args.tracks]
    if args.files is not None:
        files = sorted(files, key=lambda f: Path(f).name)[: args.files]
    load = {"dt": dt}
    rec = recording_settings(args.tracks)
    if is_recording(args.tracks):
        load.update(arc_length="observed", noise=SIMULATED_NOISE)
    if receding:
        load["estimate"] = "speeds"
        if ((args.tracks if args.tracks.is_dir() else args.tracks.parent) / DRIVER_STEPS_FILE).is_file():
            load["selection"] = "steps"
    if rec is not None:
        load.update(smoothing=rec.smoothing, speed_smoothing=rec.speed_smoothing, a_lat=rec.a_lat, v_max=rec.v_max)
    say(f"reading {len(files)} track files and {args.map} (dt {dt:g} s)")
    scene = load_replay(files, args.map, **load)
    say(f"{scene.n_converted} tracks converted, {scene.n_selected_tracks} selected; skipped {scene.skipped}")
    if not scene.selected:
        raise ValueError(f"no usable track in {args.tracks} (skipped: {scene.skipped})")
    return scene


def _say(args):
    return reporter(not args.quiet)


def run_fit_model_command(args) -> int:
    """Run ``pirl-sim fit-model``; returns the exit status."""
    import warnings

    from pirl_sim.learners import make_learner

    say = _say(args)
    try:
        from pirl_sim.scenarios.replay import recording_settings

        receding = args.likelihood == "receding"
        rec = recording_settings(args.tracks)
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
        scene = _load_scene(args, dt, say, receding)
        params = {"model": scene.model, "window": seconds_to_steps(args.window, dt, "--window"), "windows": "sliding"}
        if receding:
            params.update(likelihood="receding", horizon=horizon)
        if args.learner == "pirl-gmm":
            params.update(n_components=args.k, random_state=args.seed)
        elif args.learner == "pirl-dpgmm":
            params.update(random_state=args.seed)
        elif args.learner == "pirl-knn":
            params.update(n_neighbors=args.k)
        if args.space == "weights":
            params["space"] = "weights"
        learner = make_learner(args.learner, **params)
        say(f"fitting {type(learner).__name__} on {len(scene.selected)} trajectories")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            learner.fit(scene.selected)
        for w in caught:
            say(f"warning: {w.message}")
        path = learner.save(args.out)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"pirl-sim: error: {exc}", file=sys.stderr)
        return 2
    names = scene.model.features.names
    theta = np.atleast_2d(getattr(learner, "theta_", getattr(learner, "demo_theta_", None)))
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
    print(f"wrote {path}")
    return 0


def rebind_model(learner, model):
    """A copy of a fitted ``learner`` that evaluates features and predicts with ``model`` instead of its own.

    Raises ValueError naming what differs when ``model`` does not describe the same driver: model step [s],
    state, control and feature names, or reference feature (a path model's layout may differ)."""
    own = learner.model_
    checks = (("model step dt [s]", own.dynamics.dt, model.dynamics.dt),
              ("state names", own.dynamics.state_names, model.dynamics.state_names),
              ("control names", own.dynamics.control_names, model.dynamics.control_names),
              ("feature names", own.features.names, model.features.names),
              ("reference feature", own.features.reference, model.features.reference))
    for what, a, b in checks:
        if (not math.isclose(a, b, rel_tol=1e-9)) if isinstance(a, float) else a != b:
            raise ValueError(f"the saved model's {what} {a!r} differs from the data's {b!r}")
    out = copy.copy(learner)
    out.model_ = model
    return out


def run_predict_command(args) -> int:
    """Run ``pirl-sim predict``; returns the exit status."""
    import pandas as pd

    from pirl_sim.learners import BaseLearner

    say = _say(args)
    try:
        learner = BaseLearner.load(args.model)
        dt = learner.model_.dynamics.dt
        scene = _load_scene(args, dt, say)
        learner = rebind_model(learner, scene.model)
        window = getattr(learner, "window", None)
        history = (seconds_to_steps(args.history, dt, "--history") if args.history is not None
                   else (window or seconds_to_steps(2.0, dt, "--history")))
        if window is not None and history < window:
            raise ValueError(f"--history {history * dt:g} s is shorter than the model's look-up window "
                             f"{window * dt:g} s")
        horizon = seconds_to_steps(args.horizon, dt, "--horizon")
        usable = [t for t in scene.selected if t.n_steps >= history + 1]
        if not usable:
            raise ValueError(f"no selected track has more than {history} steps (--history {history * dt:g} s)")
        histories = [t.window(0, history) for t in usable]
        theta = learner.infer_weights(histories)
        states = learner.predict_states(histories, horizon)
        styles = learner.predict_style(histories) if hasattr(learner, "predict_style") else None
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"pirl-sim: error: {exc}", file=sys.stderr)
        return 2
    names = scene.model.features.names
    rows = []
    for i, (t, h) in enumerate(zip(usable, histories)):
        xy = scene.model.positions(states[i, 1:])
        rec = t.metadata.get("xy")
        for k in range(horizon):
            j = history + k + 1  # index of the recorded state this step predicts
            row = {"file": t.metadata.get("file"), "track_id": t.metadata.get("track_id"),
                   "piece": t.metadata.get("piece", 0), "step": k + 1, "t_s": (k + 1) * dt,
                   "s_m": states[i, k + 1, 0], "x_m": xy[k, 0], "y_m": xy[k, 1]}
            if rec is not None and j < len(rec):
                row.update(x_rec_m=rec[j, 0], y_rec_m=rec[j, 1], error_m=float(np.hypot(*(xy[k] - rec[j]))))
            if styles is not None:
                row["style"] = int(styles[i])
            row.update({f"theta_{n}": float(w) for n, w in zip(names, theta[i])})
            rows.append(row)
    table = pd.DataFrame(rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out, index=False, float_format="%.6g")
    if "error_m" in table:
        print(f"{len(usable)} tracks, history {history * dt:g} s, horizon {horizon * dt:g} s: mean displacement "
              f"error {table['error_m'].mean():.3g} m over {int(table['error_m'].notna().sum())} recorded steps")
    print(f"wrote {args.out}")
    return 0
