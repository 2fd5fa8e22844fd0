"""The replay experiment: learners and baselines predicting recorded (or simulated) tracks, scored in metres.

For each split seed the selected tracks are split by track into train and test. Every test track is predicted
at every ``stride``-th step t with t >= history and t + horizon <= its length: learners infer weights from the
last ``history`` steps and the MPC predicts the next ``horizon`` steps from the estimated state at t; the
prediction is mapped to Cartesian metres on the track's own path at its last observed lateral offset and
compared with the recorded positions. Baselines use the same windows:

- ``CV (path)``: constant speed along the path, ``CA (path)``: constant acceleration along the path, both
  from the estimated state at t; CA is physical: a car braking stops at v = 0 and stays there, a car with
  v <= 0 and a <= 0 stays where it is, one with v <= 0 and a > 0 starts from standstill (the start-state rule
  of `PathDriverModel.predict_states`);
- ``CV (x, y)``: constant velocity in the plane from the last two recorded positions.

Rollouts (``ReplayProtocol.rollout``). ``"open"``: one MPC plan from the state at t under the inferred weights
over ``max(horizon, mpc_horizon)`` steps, its first ``horizon`` steps (the paper's prediction). ``"closed"``:
what a receding-horizon driver does: plan over ``mpc_horizon`` steps, apply the first control, re-plan from the
new state, ... for ``horizon`` steps (`pirl_sim.simulate.simulate_receding_horizon`). Learners fitted with the
receding-horizon likelihood predict closed-loop with the drivers' horizon by default (see the CLI).

Per-step masks. When trajectories carry a ``step_mask`` (pirl_sim recordings replayed with
``selection="steps"``), a test window is used only if every step of its history and horizon is the driver's
own: the methods are scored on free driving, not on steps where the simulator overrode the driver.

Scores per (seed, method): MED [m] (mean over windows of the mean distance over the horizon) and
displacement errors at fixed horizons. Lateral offsets of the path-based predictions come from
``ReplayProtocol.lateral`` (`pirl_sim.lateral`: the last one held, or the training tracks' mean path), the same
for baselines and learners; ``med_path`` places each prediction at the *recorded* future offsets, which leaves
the error along the path only (what the cost models), and ``lateral_floor`` is the MED of the recorded future
arc lengths under the protocol's lateral model: what a perfect prediction along the path would score. Counts
are of recorded tracks (``n_train``, ``n_test``) and of the pieces long tracks are cut into (``n_train_pieces``,
``n_test_pieces``).

PIRL-kNN learners that differ only in k share one fit per split: the per-demonstration IRL, the look-up
samples and their feature space do not depend on k, so the learner with the smallest k is fitted and the
others are copies of it with only their nearest-neighbour index rebuilt (`PIRLKNN.with_neighbors`; identical to
refitting). Warnings raised while fitting are not silenced: the IRL's own diagnostics
(`pirl_sim.irl.IRLConvergenceWarning`, `HessianRegularizationWarning`) are counted per fit, together with
the learner's converged IRL groups (``irl_result_.converged``), and reported in the rows and the summary;
any other warning is passed on. Differences between methods are paired by window, averaged per seed,
and reported with their standard error over the seeds: on ~60 real test tracks the gaps between methods
were as large as the split-to-split noise, so a single split proves nothing.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pirl_sim.irl import HessianRegularizationWarning, IRLConvergenceWarning
from pirl_sim.metrics import adjusted_rand_index, match_styles, weight_recovery_error
from pirl_sim.validation import is_positive_int

__all__ = ["ReplayProtocol", "run_replay", "paired_differences", "predict_path_states",
           "split_by_track", "usable_tracks", "SeedStore", "files_identity", "REPLAY_CODE",
           "BASELINES", "HINDSIGHT", "ROLLOUTS"]

BASELINES = ("CV (path)", "CA (path)", "CV (x, y)")
HINDSIGHT = "hindsight cost (oracle)"  #: not a predictor: each window's cost fitted on its own future
ROLLOUTS = ("open", "closed")


@dataclass(frozen=True)
class ReplayProtocol:
    """Windows of the replay experiment (all in model steps).

    Attributes
    ----------
    history : int             observed steps before each prediction
    horizon : int             predicted steps
    stride : int              steps between predictions along a track
    fde_steps : tuple of int  horizons at which displacement errors are reported
    test_fraction : float     share of tracks in the test set
    seeds : tuple of int      split seeds
    rollout : {"open", "closed"}  how learners' weights become a prediction (module doc)
    mpc_horizon : int or None     the MPC's planning horizon [steps]; required for ``rollout="closed"``
                                  (None with "open": plan over ``horizon``)
    lateral : {"hold", "mean-path", "plane", "neighbours"}  lateral offsets of every path-based prediction
                                  (`pirl_sim.lateral`): the last observed one held, or the training tracks' mean
                                  path per route, or their mean path pooled in the plane over routes, or that
                                  plus the change of deviation of the nearest training windows
    """

    history: int = 10
    horizon: int = 15
    stride: int = 5
    fde_steps: tuple[int, ...] = (5, 10, 15)
    test_fraction: float = 0.25
    seeds: tuple[int, ...] = (0, 1, 2)
    rollout: str = "open"
    mpc_horizon: int | None = None
    lateral: str = "hold"

    def __post_init__(self) -> None:
        from pirl_sim.lateral import LATERAL_MODELS

        if self.lateral not in LATERAL_MODELS:
            raise ValueError(f"lateral must be one of {LATERAL_MODELS}, got {self.lateral!r}")
        for name in ("history", "horizon", "stride"):
            v = getattr(self, name)
            if not is_positive_int(v):
                raise ValueError(f"{name} must be a positive number of steps, got {v!r}")
        if self.rollout not in ROLLOUTS:
            raise ValueError(f"rollout must be one of {ROLLOUTS}, got {self.rollout!r}")
        if self.mpc_horizon is not None and not is_positive_int(self.mpc_horizon):
            raise ValueError(f"mpc_horizon must be a positive number of steps or None, got {self.mpc_horizon!r}")
        if self.rollout == "closed" and self.mpc_horizon is None:
            raise ValueError("rollout='closed' needs mpc_horizon, the drivers' planning horizon [steps]")
        if any(not 1 <= k <= self.horizon for k in self.fde_steps):
            raise ValueError(f"fde_steps must lie in [1, horizon={self.horizon}], got {self.fde_steps}")
        if not 0 < self.test_fraction < 1:
            raise ValueError(f"test_fraction must be in (0, 1), got {self.test_fraction!r}")
        if not self.seeds:
            raise ValueError("need at least one split seed")


def _windows(test, proto: ReplayProtocol):
    """(test index, step) of every prediction; with a ``step_mask``, only windows whose history and horizon
    are all the driver's own steps (module doc)."""
    out = []
    for i, t in enumerate(test):
        mask = t.metadata.get("step_mask")
        for step in range(proto.history, t.n_steps - proto.horizon + 1, proto.stride):
            if mask is None or mask[step - proto.history : step + proto.horizon].all():
                out.append((i, step))
    return out


def _track_keys(tracks) -> tuple[list, list]:
    keys = [(t.metadata.get("file"), t.metadata.get("track_id", i)) for i, t in enumerate(tracks)]
    return keys, sorted(set(keys), key=str)


def usable_tracks(scene, proto: ReplayProtocol) -> list:
    """The scene's selected pieces long enough for one window of ``proto`` (with ``selection="free"``: for one
    training window of ``history`` steps; test windows come from the runs long enough for history and
    horizon); raises ValueError with fewer than 4 tracks."""
    min_steps = proto.history if getattr(scene, "selection", "tracks") == "free" else proto.history + proto.horizon
    tracks = [t for t in scene.selected if t.n_steps >= min_steps]
    n = len(_track_keys(tracks)[1])
    if n < 4:
        raise ValueError(f"only {n} selected tracks have {proto.history + proto.horizon} steps; need at least 4")
    return tracks


def split_by_track(tracks, seed: int, test_fraction: float) -> tuple[list, list, dict]:
    """(train, test, counts) for one split seed: by recorded track, so that pieces of one long track never sit
    on both sides; counts ``n_train``, ``n_test`` (tracks), ``n_train_pieces``, ``n_test_pieces``."""
    keys, unique = _track_keys(tracks)
    order = np.random.default_rng(seed).permutation(len(unique))
    n_test = max(1, int(round(test_fraction * len(unique))))
    test_keys = {unique[i] for i in order[:n_test]}
    test = [t for t, k in zip(tracks, keys) if k in test_keys]
    train = [t for t, k in zip(tracks, keys) if k not in test_keys]
    counts = {"n_train": len(unique) - n_test, "n_test": n_test, "n_train_pieces": len(train),
              "n_test_pieces": len(test)}
    return train, test, counts


def _open_plan(horizon: int, mpc_horizon: int | None) -> int:
    """Steps of an open-loop plan whose first ``horizon`` steps are the prediction (module doc)."""
    return horizon if mpc_horizon is None else max(horizon, int(mpc_horizon))


def predict_path_states(model, x0: np.ndarray, theta: np.ndarray, horizon: int, *, rollout: str = "open",
                        mpc_horizon: int | None = None) -> np.ndarray:
    """Predicted states (M, horizon + 1, n_x) from starts x0 (M, n_x) under normalised weights theta (M, K).

    ``rollout="open"``: the MPC's plan over ``max(horizon, mpc_horizon)`` steps, cut to ``horizon``.
    ``"closed"``: a receding-horizon rollout with the MPC over ``mpc_horizon`` steps (module doc). Starts
    with v <= 0 are made physical as in `pirl_sim.driving.PathDriverModel.predict_states`.
    """
    if rollout not in ROLLOUTS:
        raise ValueError(f"rollout must be one of {ROLLOUTS}, got {rollout!r}")
    if rollout == "open":
        return model.predict_states(x0, theta, _open_plan(horizon, mpc_horizon))[:, : horizon + 1]
    if not is_positive_int(mpc_horizon):
        raise ValueError(f"rollout='closed' needs mpc_horizon, a positive number of steps, got {mpc_horizon!r}")
    from pirl_sim.simulate import simulate_receding_horizon

    x0 = np.array(np.atleast_2d(x0), dtype=float)
    stopped = x0[:, 1] <= 0.0
    x0[stopped, 1] = 0.0
    x0[stopped, 2] = np.maximum(x0[stopped, 2], 0.0)
    trajs = simulate_receding_horizon(model, x0, theta, horizon, int(mpc_horizon))
    return np.stack([t.states for t in trajs])


def _positions(model, test, windows, s_pred, proto, lateral: str | None = None, profile=None) -> np.ndarray:
    """Predicted arc lengths (W, horizon) mapped to x, y (W, horizon, 2) [m] on the track's own route of a
    `CompositePath` (even where a prediction runs beyond that route's ends).

    ``lateral``: the offsets the predicted arc lengths are placed at: the protocol's model (None:
    ``proto.lateral``, with the fitted `pirl_sim.lateral.MeanOffsetProfile` ``profile`` for "mean-path" and
    "plane"), or ``"recorded"``: the recorded future offsets, which leaves the error along the path only."""
    from pirl_sim.driving import CompositePath
    from pirl_sim.lateral import predict_offsets

    lateral = proto.lateral if lateral is None else lateral
    out = np.empty((len(windows), proto.horizon, 2))
    composite = isinstance(model.path, CompositePath)
    neighbours = profile.predict(test, windows, s_pred) if lateral == "neighbours" else None
    for w, (i, step) in enumerate(windows):
        t = test[i]
        seg = int(t.metadata.get("segment", 0))
        on = {"segment": seg} if composite and "segment" in t.metadata else {}
        if lateral == "recorded":
            d = t.metadata["d"][step + 1 : step + 1 + proto.horizon]
        elif neighbours is not None:
            d = neighbours[w]
        else:
            d = predict_offsets(lateral, t.metadata["d"][step], seg, t.states[step, 0], s_pred[w], profile)
        out[w] = model.path.to_cartesian(s_pred[w], d, **on)
    return out


def _recorded_xy(test, windows, horizon: int) -> np.ndarray:
    """The recorded positions (W, horizon, 2) [m] after each window's start."""
    return np.stack([np.asarray(test[i].metadata["xy"])[step + 1 : step + 1 + horizon] for i, step in windows])


def _errors(model, test, windows, s_pred, proto, lateral: str | None = None, profile=None) -> np.ndarray:
    """Distances (W, horizon) [m] between predicted arc lengths mapped to x, y (`_positions`) and the recorded
    positions."""
    xy = _positions(model, test, windows, s_pred, proto, lateral, profile)
    return np.linalg.norm(xy - _recorded_xy(test, windows, proto.horizon), axis=-1)


def _future_scores(model, test, windows, s_futures, proba, proto, profile, dt: float, K: int) -> dict:
    """minADE_K, minFDE_K, the INTERACTION miss rate and the mixture NLL per step (sigma 1 m) of the futures
    along the path (W, K', horizon) with probabilities (W, K'), placed by the protocol's lateral model; named
    by the K asked for (a learner may give fewer, K' <= K)."""
    from pirl_sim.metrics import interaction_miss, min_ade, min_fde, mixture_nll

    xy = np.stack([_positions(model, test, windows, s_futures[:, k], proto, profile=profile)
                   for k in range(s_futures.shape[1])],
                  axis=1)
    truth = _recorded_xy(test, windows, proto.horizon)
    end = np.stack([np.asarray(test[i].metadata["xy"])[step + proto.horizon - 1 : step + proto.horizon + 1]
                    for i, step in windows])  # the last two recorded positions: true speed and heading at T
    move = end[:, 1] - end[:, 0]
    speed = np.linalg.norm(move, axis=1) / dt
    heading = np.arctan2(move[:, 1], move[:, 0])
    return {f"min_ade@{K}": float(min_ade(xy, truth).mean()), f"min_fde@{K}": float(min_fde(xy, truth).mean()),
            f"miss_rate@{K}": float(interaction_miss(xy, truth, speed, heading).mean()),
            f"nll_per_step@{K}": float(mixture_nll(xy, proba, truth, 1.0).mean() / proto.horizon)}


def fit_lateral_profile(train, kind: str = "mean-path", path=None, horizon: int | None = None):
    """`pirl_sim.lateral.MeanOffsetProfile` fitted on training pieces: per route from (route, arc length,
    recorded offset) for ``kind="mean-path"``, that backed by the profile pooled in the plane from their
    positions on ``path`` (the model's reference path) for ``"plane"``; for ``"neighbours"`` a
    `pirl_sim.lateral.NeighbourOffsets` on the ``"plane"`` profile for predictions of ``horizon`` steps; None for
    ``"hold"``."""
    from pirl_sim.lateral import MeanOffsetProfile, NeighbourOffsets

    if kind == "hold":
        return None
    if kind == "neighbours":
        if horizon is None:
            raise ValueError("the 'neighbours' lateral model needs the prediction horizon [steps]")
        return NeighbourOffsets().fit(fit_lateral_profile(train, "plane", path), train, horizon)
    if kind == "plane":
        pooled = MeanOffsetProfile().fit_plane(path, [np.asarray(t.metadata["xy"], dtype=float) for t in train])
        return fit_lateral_profile(train, "mean-path").backed_by(pooled)
    segment = np.concatenate([np.full(t.n_steps + 1, int(t.metadata.get("segment", 0))) for t in train])
    s = np.concatenate([t.states[:, 0] for t in train])
    d = np.concatenate([np.asarray(t.metadata["d"], dtype=float) for t in train])
    return MeanOffsetProfile().fit(segment, s, d)


def _baseline_s(kind: str, x0: np.ndarray, horizon: int, dt: float) -> np.ndarray:
    tt = dt * np.arange(1, horizon + 1)
    s0, v0, a0 = x0[:, :1], x0[:, 1:2], x0[:, 2:3]
    if kind == "CV (path)":
        return s0 + v0 * tt
    # constant acceleration from a non-negative speed, stopping at v = 0 rather than reversing
    v0 = np.maximum(v0, 0.0)
    braking = a0 < 0
    t_stop = np.full(a0.shape, np.inf)
    t_stop[braking] = v0[braking] / -a0[braking]  # 0 for a car that is already stopped
    tc = np.minimum(tt, t_stop)
    return s0 + v0 * tc + 0.5 * a0 * tc**2


_IRL_WARNINGS = {IRLConvergenceWarning: "irl_convergence_warnings",
                 HessianRegularizationWarning: "hessian_regularization_warnings"}


def _fit_with_diagnostics(fit) -> dict:
    """Run ``fit()`` (returns the fitted learner); count the IRL's warnings, pass every other warning on.

    Returns {"learner", "irl_converged", "irl_groups", "irl_convergence_warnings",
    "hessian_regularization_warnings"}.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        learner = fit()
    out = {"learner": learner, **{name: 0 for name in _IRL_WARNINGS.values()}}
    for w in caught:
        name = next((n for c, n in _IRL_WARNINGS.items() if issubclass(w.category, c)), None)
        if name is not None:
            out[name] += 1
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
    res = getattr(learner, "irl_result_", None)
    converged = np.asarray(res.converged, dtype=bool) if res is not None else np.zeros(0, dtype=bool)
    out["irl_converged"], out["irl_groups"] = int(converged.sum()), int(converged.size)
    return out


def _shared_knn_fits(learner_specs) -> dict[int, int]:
    """{spec index: index of the spec whose fit it reuses} for PIRL-kNN specs that differ only in k (each
    group reuses the fit of its smallest k, the one whose fit succeeds whenever any does)."""
    groups: dict[str, list[int]] = {}
    for i, (_, key, params) in enumerate(learner_specs):
        if key == "pirl-knn":
            rest = {k: v for k, v in params.items() if k != "n_neighbors"}
            groups.setdefault(repr(sorted(rest.items())), []).append(i)
    out = {}
    for members in groups.values():
        base = min(members, key=lambda i: learner_specs[i][2].get("n_neighbors", 1))
        out.update({i: base for i in members if i != base})
    return out


def fit_scene_speed(scene, tracks, **kwargs):
    """`pirl_sim.speed_fit.fit_desired_speed` on the (curvature, speed) of every state of ``tracks`` (pieces of
    ``scene``)."""
    from pirl_sim.speed_fit import fit_desired_speed

    states = np.concatenate([t.states for t in tracks])
    return fit_desired_speed(scene.curvature(states[:, 0]), states[:, 1], **kwargs)


def desired_speed_model(scene, desired_speed=None, train=None):
    """The scene's model under a desired speed: None (the scene's own), ``"fit"`` (a_lat, v_max fitted on the
    training pieces ``train`` by `fit_scene_speed`) or (a_lat, v_max) [m/s^2, m/s].

    Returns (model, {"a_lat", "v_max"}, the `pirl_sim.speed_fit.DesiredSpeedFit` or None)."""
    if desired_speed is None:
        return scene.model, {"a_lat": getattr(scene, "a_lat", np.nan), "v_max": getattr(scene, "v_max", np.nan)}, None
    fit = None
    if desired_speed == "fit":
        fit = fit_scene_speed(scene, train)
        a_lat, v_max = fit.a_lat, fit.v_max
    else:
        a_lat, v_max = (float(x) for x in desired_speed)
    return scene.with_desired_speed(a_lat, v_max), {"a_lat": a_lat, "v_max": v_max}, fit


def run_replay(scene, learner_specs, proto: ReplayProtocol = ReplayProtocol(), *, progress=None,
               desired_speed=None, hindsight: bool = False, n_futures: int = 0, jobs: int = 1,
               partial_dir=None, data_identity: str = "") -> dict:
    """Run the experiment on a `pirl_sim.scenarios.replay.ReplayScene`.

    Parameters
    ----------
    scene : ReplayScene
    learner_specs : list of (name, learner key, params)  (see `pirl_sim.learners.make_learner`)
    proto : ReplayProtocol
    progress : callable(str) or None

    Returns
    -------
    dict with ``rows`` (tidy DataFrame: seed, method, med, fde@k, n_windows, fit_s, predict_s, and for
    scenes with ground truth ari / weight_error), ``paired`` (DataFrame of paired differences against TIRL),
    ``errors`` {(seed, method): per-window MED (W,)}, ``selected`` (number of tracks used) and
    ``selected_pieces`` (number of pieces of them). Rows of learners carry their fit diagnostics:
    ``irl_converged`` / ``irl_groups`` (IRL groups that converged / all), ``irl_convergence_warnings``,
    ``hessian_regularization_warnings`` (warnings raised during the fit) and ``irl_from`` (the method whose
    fit a PIRL-kNN learner reused, else empty); with ground truth also ``irl_weight_error`` (median over the
    training trajectories of the weights the fit gives each, see `_training_weights`). ``paired_ca``: paired
    differences against ``CA (path)``.

    ``desired_speed``: None (the scene's model), ``"fit"`` (a_lat, v_max fitted per split seed on the training
    tracks by `fit_scene_speed`) or (a_lat, v_max) [m/s^2, m/s] fixed. Every row carries the ``a_lat`` and
    ``v_max`` its learners used.

    ``n_futures=K`` (> 0) scores every learner's K predicted futures (`predict_futures` with ``n_futures=K``,
    drawn with the split seed; a learner with one cost per history has one, PIRL-GMM one per style at most):
    ``min_ade@K``, ``min_fde@K``,
    ``miss_rate@K`` (INTERACTION's rule, `pirl_sim.metrics.interaction_miss`) and ``nll_per_step@K`` (the
    mixture NLL with sigma = 1 m, nats per step); the baselines' rows leave them empty.

    ``hindsight=True`` adds the row ``HINDSIGHT``: every test window predicted from its start under the cost
    the IRL fits on the window's own recorded future (one cost per window). It sees what it predicts, so it is
    no predictor; it is what the model class (dynamics, features, MPC) could reach with a perfect online
    inference of the weights, and separates that limit from the learners' inference.

    ``jobs`` (>= 1): split seeds run in this many forked processes at once (each seed is independent, so the
    results do not depend on it); 1 runs them here, one after another.

    ``partial_dir`` (a directory, or None): each split seed's results are written there as soon as the seed
    finishes (`SeedStore`), and seeds found there are not run again, so an interrupted replay resumes with the
    same results. ``data_identity`` must identify the scene (e.g. `files_identity` of the files it was read
    from and the loading settings): together with the other arguments and the code it keys the stored seeds.
    """
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise ValueError(f"jobs must be a whole number of processes >= 1, got {jobs!r}")
    say = progress or (lambda msg: None)
    averaging = [name for name, _, params in learner_specs if params.get("aggregate") == "futures"]
    if proto.rollout != "open" and (n_futures or averaging):  # before any work
        what = f"n_futures={n_futures!r}" if n_futures else f"{averaging[0]} (it averages its neighbours' futures)"
        raise ValueError(f"{what} predicts open-loop plans; rollout {proto.rollout!r} is not available for it")
    plan = _open_plan(proto.horizon, proto.mpc_horizon)  # the futures' open-loop plans [steps]
    tracks = usable_tracks(scene, proto)
    unique = _track_keys(tracks)[1]
    model, speed, _ = desired_speed_model(scene, None if desired_speed == "fit" else desired_speed)
    dt = model.dynamics.dt
    job = {"scene": scene, "tracks": tracks, "learner_specs": learner_specs, "proto": proto,
           "desired_speed": desired_speed, "hindsight": hindsight, "n_futures": n_futures, "say": say,
           "model": model, "speed": speed, "dt": dt, "plan": plan, "reuse": _shared_knn_fits(learner_specs),
           "has_truth": any("theta" in t.metadata for t in tracks)}
    store = None if partial_dir is None else SeedStore(partial_dir, [data_identity, learner_specs, proto,
                                                                     desired_speed, hindsight, n_futures])
    done = {} if store is None else {seed: r for seed in proto.seeds if (r := store.load(seed)) is not None}
    for seed in done:
        say(f"seed {seed}: read from {store.path(seed)}")
    todo = [seed for seed in proto.seeds if seed not in done]

    def finished(seed, result):
        done[seed] = result
        if store is not None:
            store.save(seed, result)

    if jobs == 1 or len(todo) <= 1:
        for seed in todo:
            finished(seed, _replay_seed(seed, job))
    else:  # seeds in forked processes that inherit the scene (nothing large is pickled)
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        _JOB.update(job)
        try:
            with ProcessPoolExecutor(min(jobs, len(todo)), mp_context=multiprocessing.get_context("fork")) as pool:
                futures = {pool.submit(_replay_seed_in_worker, seed): seed for seed in todo}
                for fut in as_completed(futures):
                    finished(futures[fut], fut.result())
        finally:
            _JOB.clear()
    rows, errors, examples = [], {}, {}
    for seed_rows, seed_errors, seed_examples in (done[seed] for seed in proto.seeds):
        rows += seed_rows
        errors.update(seed_errors)
        examples = examples or seed_examples
    rows = pd.DataFrame(rows)
    return {"rows": rows, "paired": paired_differences(errors, "TIRL"),
            "paired_ca": paired_differences(errors, "CA (path)"), "errors": errors, "selected": len(unique),
            "selected_pieces": len(tracks), "examples": examples, "history": proto.history,
            "horizon": proto.horizon, "gmm_k": _gmm_k(learner_specs)}


def _replay_seed(seed: int, job: dict) -> tuple[list, dict, dict]:
    """One split seed of `run_replay`: its rows, per-window errors {(seed, method): (W,)} and, for the first
    seed, the S-T figure's windows. ``job`` holds run_replay's shared inputs."""
    from pirl_sim.learners import make_learner

    scene, tracks, learner_specs, proto = job["scene"], job["tracks"], job["learner_specs"], job["proto"]
    desired_speed, hindsight, n_futures, say = job["desired_speed"], job["hindsight"], job["n_futures"], job["say"]
    model, speed, dt, plan, reuse = job["model"], job["speed"], job["dt"], job["plan"], job["reuse"]
    has_truth, with_examples = job["has_truth"], seed == proto.seeds[0]
    rows, errors, examples = [], {}, {}
    train, test, counts = split_by_track(tracks, seed, proto.test_fraction)
    if desired_speed == "fit":
        model, speed, fit = desired_speed_model(scene, "fit", train)
        say(f"seed {seed}: desired speed fitted on the training tracks: a_lat {fit.a_lat:.2f} m/s^2, "
            f"v_max {fit.v_max:.2f} m/s{' (at a bound)' if fit.at_bound else ''}")
    counts = {**counts, **speed}
    windows = _windows(test, proto)
    if not windows:
        raise ValueError("no test window: tracks are too short for the protocol")
    profile = fit_lateral_profile(train, proto.lateral, model.path, proto.horizon)
    recorded_s = np.stack([test[i].states[step + 1 : step + 1 + proto.horizon, 0] for i, step in windows])
    counts["lateral_floor"] = float(_errors(model, test, windows, recorded_s, proto, profile=profile).mean())
    x0 = np.stack([test[i].states[step] for i, step in windows])
    histories = [test[i].window(step - proto.history, step) for i, step in windows]
    methods = {}
    for kind in BASELINES[:2]:
        methods[kind] = (_baseline_s(kind, x0, proto.horizon, dt), 0.0, 0.0, {})
    fitted = {}  # spec index -> (learner, fit diagnostics), for reuse by PIRL-kNN with another k
    order = sorted(range(len(learner_specs)), key=lambda i: i in reuse)  # shared fits first
    for i in order:
        name, key, params = learner_specs[i]
        t0 = time.perf_counter()
        if i in reuse:
            base, diag = fitted[reuse[i]]
            learner = base.with_neighbors(params.get("n_neighbors", 1))
            diag = dict(diag, irl_from=learner_specs[reuse[i]][0])
        else:
            learner = make_learner(key, model=model, window=proto.history, windows="sliding", **params)
            diag = _fit_with_diagnostics(lambda: learner.fit(train))
            del diag["learner"]
            diag["irl_from"] = ""
        fitted[i] = (learner, diag)
        fit_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        theta = learner.infer_weights(histories)
        if getattr(learner, "aggregate", "weights") == "futures":  # the mean of several futures
            s_pred = learner.predict_states(histories, plan)[:, 1 : proto.horizon + 1, 0]
        else:
            s_pred = predict_path_states(model, x0, theta, proto.horizon, rollout=proto.rollout,
                                         mpc_horizon=proto.mpc_horizon)[:, 1:, 0]
        extra = {**_truth_scores(learner, train, test, windows, theta, model, has_truth), **diag}
        if n_futures:
            fut, proba = learner.predict_futures(histories, plan, n_futures=int(n_futures), random_state=seed)
            extra.update(_future_scores(model, test, windows, fut[:, :, 1 : proto.horizon + 1, 0], proba, proto,
                                        profile, dt, int(n_futures)))
        methods[name] = (s_pred, fit_s, time.perf_counter() - t0, extra)
        how = f"from the fit of {diag['irl_from']}" if diag["irl_from"] else "fitted"
        say(f"seed {seed}: {name} {how} in {fit_s:.1f} s; IRL converged for {diag['irl_converged']} of "
            f"{diag['irl_groups']} groups")
    if hindsight:
        t0 = time.perf_counter()
        futures = [test[i].window(step, step + proto.horizon) for i, step in windows]
        oracle = make_learner("pirl-knn", model=model, n_neighbors=1, irl_max_iter=400)
        diag = _fit_with_diagnostics(lambda: oracle.fit(futures))
        del diag["learner"]
        fit_s = time.perf_counter() - t0
        s_pred = predict_path_states(model, x0, oracle.demo_theta_, proto.horizon)[:, 1:, 0]
        methods[HINDSIGHT] = (s_pred, fit_s, 0.0, {**diag, "irl_from": ""})
        say(f"seed {seed}: {HINDSIGHT} fitted on {len(futures)} test futures in {fit_s:.1f} s; IRL converged "
            f"for {diag['irl_converged']} of {diag['irl_groups']}")
    order = [*BASELINES[:2], *(sp[0] for sp in learner_specs), *([HINDSIGHT] if hindsight else [])]
    methods = {name: methods[name] for name in order}
    if with_examples:  # a few windows for the S-T figure
        shown = np.linspace(0, len(windows) - 1, min(4, len(windows))).astype(int)
        examples = {
            "t": dt * np.arange(-proto.history, proto.horizon + 1),
            "truth": np.stack([test[windows[w][0]].states[windows[w][1] - proto.history:
                                                         windows[w][1] + proto.horizon + 1, 0] for w in shown]),
            "predictions": {name: m[0][shown] for name, m in methods.items()},
        }
    for name, (s_pred, fit_s, pred_s, extra) in methods.items():
        err = _errors(model, test, windows, s_pred, proto, profile=profile)
        errors[(seed, name)] = err.mean(axis=1)
        med_path = float(_errors(model, test, windows, s_pred, proto, "recorded").mean())
        row = {"seed": seed, "method": name, "med": float(err.mean()), "med_path": med_path,
               "n_windows": len(windows), **counts, "fit_s": fit_s, "predict_s": pred_s, **extra}
        for k in proto.fde_steps:
            row[f"de@{k * dt:.1f}s"] = float(err[:, k - 1].mean())
        rows.append(row)
    # CV in the plane, from the last two recorded positions
    err = np.empty((len(windows), proto.horizon))
    for w, (i, step) in enumerate(windows):
        xy = test[i].metadata["xy"]
        vel = (xy[step] - xy[step - 1]) / dt
        pred = xy[step] + vel[None] * (dt * np.arange(1, proto.horizon + 1))[:, None]
        err[w] = np.linalg.norm(pred - xy[step + 1 : step + 1 + proto.horizon], axis=1)
    errors[(seed, "CV (x, y)")] = err.mean(axis=1)
    row = {"seed": seed, "method": "CV (x, y)", "med": float(err.mean()), "n_windows": len(windows),
           **counts, "fit_s": 0.0, "predict_s": 0.0}
    for k in proto.fde_steps:
        row[f"de@{k * dt:.1f}s"] = float(err[:, k - 1].mean())
    rows.append(row)
    return rows, errors, examples


_JOB: dict = {}  #: run_replay's shared inputs, inherited by forked workers

#: modules whose code a split seed runs besides the sweep's cell code (`pirl_sim.sweep.store.CELL_CODE`)
REPLAY_CODE = ("pirl_sim.harness.replay", "pirl_sim.lateral", "pirl_sim.simulate", "pirl_sim.speed_fit")


def files_identity(paths, **settings) -> str:
    """sha256 (hex) of the names and bytes of ``paths`` (files, or directories: every file directly in them,
    sorted) and of ``settings`` (by ``repr``): what `run_replay`'s ``data_identity`` needs of a scene read from
    files."""
    import hashlib
    from pathlib import Path

    h = hashlib.sha256(repr(sorted(settings.items())).encode())
    for path in map(Path, paths):
        for f in sorted(path.iterdir()) if path.is_dir() else [path]:
            if f.is_file():
                h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


class SeedStore:
    """The finished split seeds of one `run_replay` call in ``root/seeds/<seed>-<key>.pkl``, written atomically.

    The key hashes ``identity`` (by ``repr``: the scene's identity and run_replay's arguments) and the code
    (`pirl_sim.sweep.store.code_version` and the source files of `REPLAY_CODE`), so other data, settings or
    code never reuse a stored seed. A file that cannot be read is ignored (the seed runs again). The files are
    pickles written by this class: read only output directories you made.
    """

    def __init__(self, root, identity) -> None:
        import hashlib
        import importlib.util
        from pathlib import Path

        from pirl_sim.sweep.store import code_version

        h = hashlib.sha256(repr(identity).encode() + code_version().encode())
        for name in REPLAY_CODE:
            h.update(Path(importlib.util.find_spec(name).origin).read_bytes())
        self.dir, self.key = Path(root) / "seeds", h.hexdigest()[:20]

    def path(self, seed: int):
        return self.dir / f"{seed}-{self.key}.pkl"

    def load(self, seed: int):
        """The stored (rows, errors, examples) of ``seed``, or None."""
        import pickle

        try:
            return pickle.loads(self.path(seed).read_bytes())
        except FileNotFoundError:
            return None
        except Exception as exc:  # noqa: BLE001 - a damaged file: the seed runs again
            warnings.warn(f"ignoring unreadable {self.path(seed)} ({type(exc).__name__}); seed {seed} runs again",
                          stacklevel=2)
            return None

    def save(self, seed: int, result) -> None:
        import pickle

        from pirl_sim.io.atomic import atomic_write_bytes

        atomic_write_bytes(self.path(seed), pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))


def _replay_seed_in_worker(seed: int) -> tuple[list, dict, dict]:
    return _replay_seed(seed, _JOB)  # the fork inherited _JOB and the parent's BLAS thread limits


def _gmm_k(learner_specs) -> int:
    """Clusters of the cluster figure: the first PIRL-GMM learner's ``n_components`` (3 without one)."""
    return next((int(p.get("n_components", 3)) for _, key, p in learner_specs if key == "pirl-gmm"), 3)


def _truth_scores(learner, train, test, windows, theta, model, has_truth: bool = False) -> dict:
    """Scores against ground truth, on the tracks that have it: ``ari`` and ``matched_styles`` over the
    training tracks with a style >= 0 (PIRL drivers; background traffic has style -1), ``weight_error`` over
    the test windows with weights and ``irl_weight_error`` over the training tracks with weights. With
    ``has_truth`` (the scene has weights for some tracks) both weight errors are reported, NaN when this split
    has none: background tracks never make the columns disappear."""
    out = {}
    styled = [j for j, t in enumerate(train) if t.metadata.get("style", -1) >= 0]
    labels = getattr(learner, "labels_", None)
    if len(styled) >= 2 and labels is not None and len(labels) == len(train):
        truth = np.array([train[j].metadata["style"] for j in styled])
        got = np.asarray(labels)[styled]
        out["ari"] = adjusted_rand_index(truth, got)
        out["matched_styles"] = len(match_styles(truth, got))
    ref = model.features.reference_index
    known = [w for w, (i, _) in enumerate(windows) if "theta" in test[i].metadata]
    if known:
        true = np.stack([test[windows[w][0]].metadata["theta"] for w in known])
        out["weight_error"] = float(np.median(weight_recovery_error(np.asarray(theta)[known], true, ref)))
    elif has_truth:
        out["weight_error"] = np.nan
    known = [j for j, t in enumerate(train) if "theta" in t.metadata]
    fitted = _training_weights(learner, len(train)) if known else None
    if fitted is not None:  # the IRL's own recovery on the training tracks
        true = np.stack([train[j].metadata["theta"] for j in known])
        out["irl_weight_error"] = float(np.median(weight_recovery_error(np.asarray(fitted)[known], true, ref)))
    elif has_truth:
        out["irl_weight_error"] = np.nan
    return out


def _training_weights(learner, n_train: int) -> np.ndarray | None:
    """The weights a fitted learner gives each training trajectory (n_train, K): per demonstration (kNN),
    its cluster's (GMM, DPGMM) or the one shared (TIRL); None when it has none of these."""
    demo = getattr(learner, "demo_theta_", None)
    if demo is not None and len(demo) == n_train:
        return np.asarray(demo)
    theta = getattr(learner, "theta_", None)
    if theta is None:
        return None
    theta = np.asarray(theta)
    labels = getattr(learner, "labels_", None)
    if theta.ndim == 1:
        return np.broadcast_to(theta, (n_train, theta.size))
    if labels is not None and len(labels) == n_train:
        return theta[np.asarray(labels)]
    return None


def paired_differences(errors: dict, reference: str) -> pd.DataFrame:
    """MED(method) - MED(reference) paired by window, mean per seed, then mean and standard error over seeds."""
    seeds = sorted({s for s, _ in errors})
    methods = sorted({m for _, m in errors if m != reference})
    rows = []
    for m in methods:
        if any((s, reference) not in errors for s in seeds):
            continue
        per_seed = np.array([np.mean(errors[(s, m)] - errors[(s, reference)]) for s in seeds])
        se = per_seed.std(ddof=1) / np.sqrt(len(seeds)) if len(seeds) > 1 else np.nan
        rows.append({"method": m, "reference": reference, "mean_difference": float(per_seed.mean()),
                     "standard_error": float(se), "n_seeds": len(seeds),
                     "better_in_every_seed": bool(np.all(per_seed < 0))})
    return pd.DataFrame(rows)


def summarize(result: dict) -> pd.DataFrame:
    """Mean and standard deviation over seeds of every score, one row per method (sorted by MED); for
    learners also ``irl_converged`` ("converged groups / groups", summed over seeds) and the numbers of IRL
    warnings raised while fitting (summed over seeds)."""
    rows = result["rows"]
    scores = [c for c in rows.columns
              if c in ("med", "med_path") or c.startswith(("de@", "min_ade@", "min_fde@", "miss_rate@", "nll_per_step@"))
              or c in ("ari", "weight_error", "irl_weight_error")]
    agg = rows.groupby("method")[scores].agg(["mean", "std"])
    agg.columns = [f"{a}_{b}" for a, b in agg.columns]
    out = agg.sort_values("med_mean").reset_index()
    if "irl_groups" in rows:
        fits = rows[rows["irl_groups"].notna()].groupby("method")
        totals = fits[["irl_converged", "irl_groups", *_IRL_WARNINGS.values()]].sum().astype(int)
        conv = {m: f"{r.irl_converged} / {r.irl_groups}" for m, r in totals.iterrows()}
        out["irl_converged"] = out["method"].map(conv).fillna("")
        for col in _IRL_WARNINGS.values():
            out[col] = out["method"].map(totals[col]).astype(float)  # NaN (empty) for baselines
    return out


def write_replay_results(result: dict, scene, out_dir, command: str) -> None:
    """rows.csv, summary.csv/.md, paired.csv and README.md (with the selection counts) in ``out_dir``."""
    from pathlib import Path

    from pirl_sim.harness.tables import markdown
    from pirl_sim.io.atomic import atomic_write_text

    out = Path(out_dir)
    summary = summarize(result)
    atomic_write_text(out / "rows.csv", result["rows"].to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "summary.csv", summary.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "summary.md", f"# Replay scores\n\nMade by `{command}`. Mean and standard deviation "
                      f"over split seeds; MED and de@ in metres.\n\n{markdown(summary)}\n")
    atomic_write_text(out / "paired.csv", result["paired"].to_csv(index=False, float_format="%.6g"))
    if "paired_ca" in result:
        atomic_write_text(out / "paired_ca.csv", result["paired_ca"].to_csv(index=False, float_format="%.6g"))
    _write_figures(result, scene, out)
    from pirl_sim.scenarios.replay import track_key

    n_inter = len({track_key(t) for t in scene.trajectories if t.metadata["interacted"]})
    selection = getattr(scene, "selection", "tracks")
    if selection == "free":
        used = (f"kept as free-flow runs (selection='free', steps with a leader left out, interacting tracks "
                f"included): {result['selected']} (in {result['selected_pieces']} runs); steps: "
                f"{getattr(scene, 'steps', {})}")
    elif selection == "all":
        used = (f"every matched track whole, leaders included (selection='all'): {result['selected']} (in "
                f"{result['selected_pieces']} pieces)")
    elif selection == "steps":
        used = (f"kept with per-step masks (selection='steps', interacting tracks included): {result['selected']} "
                f"(in {result['selected_pieces']} pieces); steps: {getattr(scene, 'steps', {})}")
    else:
        used = f"used (not interacting, long enough): {result['selected']} (in {result['selected_pieces']} pieces)"
    lines = [
        "# Replay experiment",
        "",
        f"Made by `{command}`.",
        "",
        f"Tracks read: {scene.n_tracks}; converted: {scene.n_converted} (in {len(scene.trajectories)} pieces); "
        f"flagged as interacting: {n_inter}; {used}. Skipped: {scene.skipped or 'none'}. "
        f"Route-matching repairs: {getattr(scene, 'repairs', None) or 'none'}.",
        "",
        "Counts of train and test tracks per split are in rows.csv (n_train, n_test; their pieces in "
        "n_train_pieces, n_test_pieces). irl_converged: IRL groups whose Newton iteration converged / all groups, "
        "summed over the split seeds (PIRL-kNN learners that differ only in k share one fit per split).",
        "",
        *_speed_lines(result),
        *_selection_lines(scene, result),
        "## Scores (mean and std over split seeds)",
        "",
        markdown(summary),
        "",
        "## Paired differences against TIRL (MED, per window; mean and standard error over seeds)",
        "",
        markdown(result["paired"]),
        "",
        *(["## Paired differences against CA (path)", "", markdown(result["paired_ca"]), ""]
          if "paired_ca" in result else []),
        "![clusters](clusters.png) ![S-T](s_t.png)" + (" ![MED vs k](knn_k.png)" if (out / "knn_k.png").exists() else ""),
    ]
    atomic_write_text(out / "README.md", "\n".join(lines) + "\n")


def _speed_lines(result: dict) -> list[str]:
    rows = result["rows"]
    if "a_lat" not in rows or rows["a_lat"].isna().all():
        return []
    per_seed = rows.groupby("seed")[["a_lat", "v_max"]].first()
    seeds = "; ".join(f"seed {s}: {r.a_lat:.2f}, {r.v_max:.2f}" for s, r in per_seed.iterrows())
    return [f"Desired speed (a_lat [m/s^2], v_max [m/s]) per split seed: {seeds}.", ""]


def _selection_lines(scene, result: dict) -> list[str]:
    from pirl_sim.harness.tables import markdown
    from pirl_sim.scenarios.replay import selection_counts

    if getattr(scene, "track_table", None) is None:
        return []
    h = result["history"]
    hz = result.get("horizon")
    tables = [selection_counts(scene, h).assign(min_steps=h)]
    if hz:
        tables.append(selection_counts(scene, h + hz).assign(min_steps=h + hz))
    table = pd.concat(tables, ignore_index=True)
    return ["## Matched car tracks usable per selection rule", "",
            "usable: tracks with at least one piece the rule keeps of >= min_steps steps (history: a training "
            "window; history + horizon: a test window).", "", markdown(table), ""]


def _write_figures(result: dict, scene, out) -> None:
    """clusters.png (PIRL-GMM with the replay's k, ``result["gmm_k"]``, default 3; the selected pieces; marker:
    true style where a sidecar gives one, background traffic as its own marker), s_t.png (a few predicted
    windows), knn_k.png (when several kNN learners ran)."""
    import re

    from pirl_sim.harness import figures
    from pirl_sim.io.atomic import atomic_write_bytes
    from pirl_sim.learners import PIRLGMM

    tracks = scene.selected
    model = scene.model
    labels = PIRLGMM(model, n_components=min(int(result.get("gmm_k", 3)), len(tracks)),
                     random_state=0).cluster_labels(tracks)  # the clusters alone: no IRL for an illustration
    styles = np.array([int(t.metadata.get("style", -1)) for t in tracks])
    names = None
    if np.any(styles >= 0):  # a sidecar gives styles: tracks without one (background traffic) get a marker too
        names = {int(s): (f"style {s}" if s >= 0 else "background (no style)") for s in np.unique(styles)}
    atomic_write_bytes(out / "clusters.png", figures.feature_clusters(
        model.feature_values(tracks), model.features.names, labels, styles if names else None, names))
    ex = result["examples"]
    if ex:
        h = result["history"]
        preds = {k: np.concatenate([np.repeat(ex["truth"][:, h : h + 1], 1, axis=1), v], axis=1)
                 for k, v in ex["predictions"].items()}
        atomic_write_bytes(out / "s_t.png", figures.s_t_predictions(ex["t"], ex["truth"], preds, h))
    rows = result["rows"]
    knn = rows[rows["method"].str.startswith("PIRL-kNN (k=")]
    if knn["method"].nunique() > 1:
        per_seed = knn.groupby("method")["med"].agg(["mean", "std"]).reset_index()
        per_seed["k"] = [int(re.search(r"k=(\d+)", m).group(1)) for m in per_seed["method"]]
        table = pd.DataFrame({"protocol": "replay (std over seeds)", "k": per_seed["k"],
                              "med": per_seed["mean"], "med_std": per_seed["std"].fillna(0.0)}).sort_values("k")
        atomic_write_bytes(out / "knn_k.png", figures.knn_vs_k(table, "PIRL-kNN on replayed tracks: MED vs k"))
