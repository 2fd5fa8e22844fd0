"""``pirl-sim predict``: predict recorded drivers' futures with a model file written by ``pirl-sim fit-model``.

Each selected track's future is predicted from its first ``--history`` seconds; one CSV row per predicted step,
with the recorded position where the track has one and the weights used. A saved path model carries the
arc-length layout of the scene it was fitted on; the learner runs on the layout of the tracks read
(`rebind_model`), read with the saved model's feature set and desired speed, after checking that the model step,
the state, control and feature names and the reference feature agree: weights and styles do not depend on the
layout.

With ``--futures K`` the output is instead the INTERACTION prediction challenge's submission layout (INTERPRET,
single-agent regular track): one row per predicted 0.1 s frame of each case (one case per predicted track),
``case_id,frame_id,timestamp_ms,track_id,agent_role,agent_type`` then the K modes' ``x1,y1,...,xK,yK`` [m], and
the modes' probabilities beside it in ``<OUT stem>_proba.csv`` (`submission_tables`).
"""

from __future__ import annotations

import copy
import functools
import math
from pathlib import Path

from pirl_sim.validation import positive_float_arg, positive_int_arg

from .common import add_seed_option, add_track_options, error, finish, load_track_scene, seconds_to_steps, subcommand

__all__ = ["SUBMISSION_COLUMNS", "add_parser", "history_end_frames", "proba_path", "rebind_model", "run",
           "submission_tables"]

#: the first columns of an INTERACTION prediction challenge submission, in this order; the K modes' x, y follow
SUBMISSION_COLUMNS = ("case_id", "frame_id", "timestamp_ms", "track_id", "agent_role", "agent_type")
_FRAME_S = 0.1  # [s] an INTERACTION frame
_FRAME_MS = 100  # [ms] an INTERACTION frame
_XY_TOLERANCE = 1e-6  # [m] a recorded position matches a trajectory's within this
MAX_HORIZON_S = 600.0  #: [s] the longest --horizon predict takes
MAX_FUTURES = 100  #: the most modes --futures takes (the INTERACTION challenge scores 6)


@subcommand("predict", help="predict recorded drivers' futures with a saved model",
            description="Read a model file written by fit-model (or learner.save) and recorded tracks; predict every "
            "selected track's future from its first --history seconds; write one CSV row per predicted step, or with "
            "--futures K the INTERACTION prediction challenge's submission (K modes per 0.1 s frame) and "
            "<OUT stem>_proba.csv (the modes' probabilities).")
def add_parser(pr) -> None:
    """The options of ``predict``."""
    add_track_options(pr)
    pr.add_argument("--model", type=Path, required=True, help="model file written by fit-model")
    pr.add_argument("--history", type=positive_float_arg,
                    help="observed history [s] (default: the model's look-up window, else 2)")
    pr.add_argument("--horizon", type=positive_float_arg, default=3.0,
                    help=f"predicted horizon [s], at most {MAX_HORIZON_S:g} (default 3)")
    pr.add_argument("--out", type=Path, required=True, help="CSV file of the predictions")
    pr.add_argument("--futures", type=positive_int_arg, metavar="K", help="write the INTERACTION challenge's "
                    f"submission layout with K <= {MAX_FUTURES} predicted modes per case, and their probabilities in "
                    "<OUT stem>_proba.csv (default: one row per predicted step)")
    add_seed_option(pr, "the learners that draw their --futures")


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
    out: dict[str, str | float]
    out = {"features": ("following" if "speed_sq" in names else "interacting") if "headway" in names else
           "speed-level" if "speed_sq" in names else "paper"}
    for feature in model.features.features:
        profile = getattr(feature.residual, "profile", None)
        if feature.name == "speed_dev" and profile is not None:
            out.update(a_lat=float(profile.a_lat), v_max=float(profile.v_max))
    return out


def _check_out(args, futures: int | None) -> None:
    """ValueError when ``--out`` (and with ``futures`` its probabilities' file, `proba_path`) is a directory, or one
    of the inputs (the model file, the map, a track file, a file in the tracks directory or a sidecar beside the
    track file), which writing it would overwrite."""
    from pirl_sim.scenarios.recording import DRIVER_STEPS_FILE, GROUND_TRUTH_FILE, INFO_FILE, MAP_FILE

    sidecars = (GROUND_TRUTH_FILE, INFO_FILE, DRIVER_STEPS_FILE, MAP_FILE)  # what a recording's reader reads beside
    inputs = [args.model, args.map, args.tracks] + (sorted(args.tracks.iterdir()) if args.tracks.is_dir() else
                                                    [args.tracks.parent / name for name in sidecars])
    outputs = [("--out", args.out)]
    if futures is not None:
        outputs.append((f"the probabilities of --out {str(args.out)!r},", proba_path(args.out)))
    for label, out in outputs:
        if out.is_dir():
            raise ValueError(f"{label} {str(out)!r} is a directory; give the CSV file of the predictions")
        if any(out.resolve() == p.resolve() for p in inputs):
            raise ValueError(f"{label} {str(out)!r} is one of the inputs; writing the predictions would overwrite it")


def proba_path(out: Path) -> Path:
    """Where ``--futures`` writes the modes' probabilities beside the submission ``out``: ``<stem>_proba.csv``."""
    return out.with_name(f"{out.stem}_proba.csv")


def _read_track_file(path: Path):
    """The rows of a track file (`read_tracks`; when it fails validation, the valid tracks that
    `load_replay` kept, `read_tracks_lenient`)."""
    from pirl_sim.io.interaction import read_tracks, read_tracks_lenient

    try:
        return read_tracks(path)
    except ValueError:
        df, _ = read_tracks_lenient(path)
        if df is None:
            raise
        return df


def history_end_frames(trajectories, history: int, stride: int) -> list[tuple[int, int]]:
    """``(frame_id, timestamp_ms)`` of the last recorded frame of each trajectory's first ``history`` steps.

    A trajectory read by `load_replay` carries its track file (``metadata["file"]``), ``track_id`` and recorded
    positions ``xy`` at the model step (``stride`` frames of 0.1 s), from the first frame it uses, but no frame
    ids: its first frame is the frame of that track from which every ``stride``-th recorded x, y equals the
    history's ``xy[: history + 1]`` (within 1e-6 m; the earliest such frame). Raises ValueError naming the file and
    the track when no frame matches."""
    import numpy as np

    read, out = functools.cache(_read_track_file), []  # each file once
    for t in trajectories:
        meta = t.metadata
        if not all(k in meta for k in ("file", "track_id", "xy")):
            raise ValueError("--futures needs tracks read from INTERACTION track files (a trajectory has no file, "
                             "track_id or recorded xy)")
        file, track_id = Path(meta["file"]), meta["track_id"]
        target = np.asarray(meta["xy"], dtype=float)[: history + 1]
        df = read(file)
        rows = df[df["track_id"] == track_id].sort_values("frame_id", kind="stable")
        xy, frames = rows[["x", "y"]].to_numpy(dtype=float), rows["frame_id"].to_numpy(dtype=np.int64)
        span = (len(target) - 1) * stride
        n, found = len(xy) - span, None  # n: first frames that leave room for the whole history
        if len(target) == history + 1 and n > 0:
            ok = np.ones(n, dtype=bool)
            for j, point in enumerate(target):
                part = slice(j * stride, j * stride + n)
                ok &= np.all(np.abs(xy[part] - point) <= _XY_TOLERANCE, axis=1)
                ok &= frames[part] == frames[:n] + j * stride  # no gap in the frames
            hits = np.flatnonzero(ok)
            found = int(hits[0]) + span if len(hits) else None
        if found is None:
            x0, y0 = target[0] if len(target) else (float("nan"), float("nan"))
            raise ValueError(f"{file}: no frames of track {track_id} at the positions of its history (first "
                             f"x={x0:.6f}, y={y0:.6f} m, every {stride} frames); was the file changed after it "
                             "was read?")
        out.append((int(frames[found]), int(rows["timestamp_ms"].to_numpy()[found])))
    return out


def submission_tables(trajectories, states, proba, n_futures: int, ends, positions, history: int, stride: int):
    """The INTERACTION challenge submission and its probabilities as two DataFrames.

    ``states`` (M, K', horizon + 1, n_x) and ``proba`` (M, K') are `predict_futures`' (K' <= ``n_futures``);
    each case's modes are sorted by probability (most probable first) and padded to ``n_futures`` by repeating the
    most probable at probability 0. ``positions(states, offset)`` gives x, y [m] (the scene model's); the predicted
    steps are placed at the history's last lateral offset ``metadata["d"]`` and interpolated linearly in time,
    from the history's last recorded x, y, at every 0.1 s frame (``stride`` frames a step) after ``ends``'
    (frame_id, timestamp_ms) of each history (`history_end_frames`)."""
    import numpy as np
    import pandas as pd

    K, horizon = int(n_futures), states.shape[2] - 1
    j = np.arange(1, horizon * stride + 1)  # frames after the history's last
    steps, blocks, probas = np.arange(horizon + 1) * stride, [], []
    for i, (t, (frame, stamp)) in enumerate(zip(trajectories, ends)):
        p = np.asarray(proba[i], dtype=float)
        order = np.argsort(-p, kind="stable")[:K]
        p, pad = p[order] / p[order].sum(), K - len(order)
        order, p = np.concatenate([order, np.full(pad, order[0])]), np.pad(p, (0, pad))
        d = t.metadata.get("d")
        offset = float(d[history]) if d is not None and len(d) > history else 0.0
        anchor = np.asarray(t.metadata["xy"], dtype=float)[history]
        xy = positions(states[i, order, 1:], offset)  # (K, horizon, 2)
        firsts = (i + 1, frame + j, stamp + _FRAME_MS * j, t.metadata["track_id"], "agent", "car")
        modes = {f"{c}{k + 1}": np.interp(j, steps, np.r_[anchor[n], xy[k, :, n]])  # from the history's last x, y
                 for k in range(K) for n, c in enumerate("xy")}
        blocks.append(pd.DataFrame({**dict(zip(SUBMISSION_COLUMNS, firsts)), **modes}))
        probas.append([i + 1, *p])
    table = pd.DataFrame(probas, columns=["case_id", *(f"p{k}" for k in range(1, K + 1))])
    table["case_id"] = table["case_id"].astype(int)
    return pd.concat(blocks, ignore_index=True), table


def run(args) -> int:
    """``pirl-sim predict``: 0, or 2 for a bad option, an unreadable model or unusable data."""
    import numpy as np
    import pandas as pd

    from pirl_sim.learners import load_learner
    from pirl_sim.progress import reporter

    say, futures = reporter(not args.quiet), getattr(args, "futures", None)
    try:
        if args.horizon > MAX_HORIZON_S:
            raise ValueError(f"--horizon {args.horizon:g} s is longer than {MAX_HORIZON_S:g} s: a prediction of a "
                             "roundabout passage is seconds long, and this one would not fit in memory")
        if futures is not None and futures > MAX_FUTURES:
            raise ValueError(f"--futures {futures}: at most {MAX_FUTURES} modes per case (the INTERACTION challenge "
                             "scores 6)")
        _check_out(args, futures)
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
        if futures is not None:
            stride = round(dt / _FRAME_S)
            ends = history_end_frames(usable, history, stride)  # before the predictions: a missing frame fails fast
            states, proba = learner.predict_futures(histories, horizon, n_futures=futures, random_state=args.seed)
            submission, table = submission_tables(usable, states, proba, futures, ends, scene.model.positions,
                                                  history, stride)
        else:
            theta, states = learner.infer_weights(histories), learner.predict_states(histories, horizon)
            styles = learner.predict_style(histories) if hasattr(learner, "predict_style") else None
    except (ValueError, TypeError, FileNotFoundError) as exc:
        return error(exc)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if futures is not None:
        submission.to_csv(args.out, index=False, float_format="%.3f")
        table.to_csv(proba_path(args.out), index=False)
        return finish(f"{args.out} and {proba_path(args.out)}", f"{len(usable)} cases, {futures} futures, "
                      f"{horizon * stride} frames of 0.1 s each (history {history * dt:g} s, horizon "
                      f"{horizon * dt:g} s)")
    names, rows = scene.model.features.names, []
    for i, t in enumerate(usable):
        xy, rec = scene.model.positions(states[i, 1:]), t.metadata.get("xy")
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
    table.to_csv(args.out, index=False, float_format="%.6g")
    if "error_m" in table:
        print(f"{len(usable)} tracks, history {history * dt:g} s, horizon {horizon * dt:g} s: mean displacement "
              f"error {table['error_m'].mean():.3g} m over {int(table['error_m'].notna().sum())} recorded steps")
    return finish(args.out)
