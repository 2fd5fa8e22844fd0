"""``pirl-sim predict``: predict recorded drivers' futures with a model file written by ``pirl-sim fit-model``.

Each selected track's future is predicted from its first ``--history`` seconds; one CSV row per predicted step,
with the recorded position where the track has one and the weights used. A saved path model carries the
arc-length layout of the scene it was fitted on; the learner runs on the layout of the tracks read
(`rebind_model`), read with the saved model's feature set and desired speed, after checking that the model step,
the state, control and feature names and the reference feature agree: weights and styles do not depend on the
layout.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

from pirl_sim.validation import positive_float_arg

from .common import add_track_options, error, load_track_scene, seconds_to_steps

__all__ = ["add_parser", "run", "rebind_model"]


def add_parser(subparsers) -> None:
    """Add ``predict`` to the command's subparsers."""
    pr = subparsers.add_parser(
        "predict",
        help="predict recorded drivers' futures with a saved model",
        description="Read a model file written by fit-model (or learner.save) and recorded tracks; predict every "
        "selected track's future from its first --history seconds; write one CSV row per predicted step.",
    )
    add_track_options(pr)
    pr.add_argument("--model", type=Path, required=True, help="model file written by fit-model")
    pr.add_argument("--history", type=positive_float_arg, default=None,
                    help="observed history [s] (default: the model's look-up window, else 2)")
    pr.add_argument("--horizon", type=positive_float_arg, default=3.0, help="predicted horizon [s] (default 3)")
    pr.add_argument("--out", type=Path, required=True, help="CSV file of the predictions")


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


def _model_settings(model) -> dict:
    """How to read tracks for a saved model: its feature set and its desired speed's a_lat [m/s^2] and v_max
    [m/s] (`load_track_scene`'s keywords)."""
    names = model.features.names
    out = {"features": "following" if "headway" in names else "speed-level" if "speed_sq" in names else "paper"}
    for feature in model.features.features:
        profile = getattr(feature.residual, "profile", None)
        if feature.name == "speed_dev" and profile is not None:
            out.update(a_lat=float(profile.a_lat), v_max=float(profile.v_max))
    return out


def _check_out(out: Path, model: Path, map_path: Path, tracks: Path) -> None:
    """ValueError when the predictions' CSV ``out`` is a directory, or one of the inputs (the model file, the map,
    a track file or a file in the tracks directory), which writing it would overwrite."""
    if out.is_dir():
        raise ValueError(f"--out {str(out)!r} is a directory; give the CSV file of the predictions")
    inputs = [model, map_path, tracks] + (sorted(tracks.iterdir()) if tracks.is_dir() else [])
    if any(out.resolve() == p.resolve() for p in inputs):
        raise ValueError(f"--out {str(out)!r} is one of the inputs; writing the predictions would overwrite it")


def run(args) -> int:
    """``pirl-sim predict``: 0, or 2 for a bad option, an unreadable model or unusable data."""
    import numpy as np
    import pandas as pd

    from pirl_sim.learners import load_learner
    from pirl_sim.progress import reporter

    say = reporter(not args.quiet)
    try:
        _check_out(args.out, args.model, args.map, args.tracks)
        learner = load_learner(args.model)
        dt = learner.model_.dynamics.dt
        scene = load_track_scene(args, dt, say, **_model_settings(learner.model_))
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
        return error(exc)
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
