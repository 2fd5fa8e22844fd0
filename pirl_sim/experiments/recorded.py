"""The ``recorded`` sweep scenario: recorded (or simulated) roundabout tracks replayed, scored in metres.

``pirl-sim replay`` runs it through the sweep engine (`pirl_sim.cli.replay`: a config built from its options):
one cell per (split seed, method), the methods of one split seed one task (`run_recorded_cells`: the split, the
desired-speed fit, the lateral model and the windows are made once, and PIRL-kNN learners that differ only in k
share one fit). Parameters: `RECORDED_PARAMS`; the protocol: `ReplayProtocol` (rolling windows, rollout, lateral
model). Besides the learners, the pseudo-learners `METHODS` (``cv``, ``ca``, ``cv-xy``, `HINDSIGHT`, ``direct``)
are scored on the same windows; a cell's key includes the data files' identity (`recorded_fingerprint`).

Windows, baselines, rollouts, per-step masks and scores are explained in the documentation's "Replay of
recorded driving" page.
"""
from __future__ import annotations

import hashlib
import json
import time
import warnings
from dataclasses import dataclass, fields, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from pirl_sim.driving import CompositePath, physical_starts
from pirl_sim.io.interaction import find_track_files, read_tracks, read_tracks_lenient
from pirl_sim.irl import HessianRegularizationWarning, IRLConvergenceWarning
from pirl_sim.lateral import LATERAL_MODELS, MeanOffsetProfile, NeighbourOffsets, observed_s, predict_offsets
from pirl_sim.metrics import (adjusted_rand_index, interaction_miss, match_styles, min_ade, min_fde, mixture_nll,
                              weight_recovery_error)
from pirl_sim.scenarios.replay import EstimateNoise, load_replay
from pirl_sim.simulate import simulate_receding_horizon
from pirl_sim.speed_fit import fit_desired_speed
from pirl_sim.validation import check_keys, is_positive_int

from pirl_sim.evaluation.baselines import KinematicModel
from pirl_sim.evaluation.direct import DirectRegression
from .spec import Param, ScenarioSpec, TrainShape, split_indices

__all__ = ["ReplayProtocol", "replay_seed", "run_recorded_cells", "recorded_files", "recorded_fingerprint",
           "load_scene", "method_id", "decode_method", "predict_path_states", "split_by_track", "usable_tracks",
           "fit_lateral_profile", "desired_speed_model", "fit_scene_speed", "start_histories", "entry_windows",
           "history_lags",
           "METHODS", "HINDSIGHT", "ROLLOUTS", "RECORDED_PARAMS"]

#: pseudo-learners of this scenario (module doc); every other method is a learner of `pirl_sim.learners.LEARNERS`
METHODS = ("cv", "ca", "cv-xy", "hindsight", "direct")
HINDSIGHT = "hindsight cost (oracle)"  #: not a predictor: each window's cost fitted on its own future
ROLLOUTS = ("open", "closed")
STARTS = ("history", "track")  #: start states of a prediction (`ReplayProtocol.start`)
#: how far back [s] PIRL-kNN next's look-up and the direct regression read speed and acceleration
LAG_SECONDS = (0.0, 0.5, 1.0)


def history_lags(dt: float, history: int) -> list[int]:
    """`LAG_SECONDS` in steps of ``dt`` [s] (rounded, at most ``history`` steps back, repeats merged)."""
    return sorted({min(int(round(back / dt)), history) for back in LAG_SECONDS})


@dataclass(frozen=True)
class ReplayProtocol:
    """Windows of the replay experiment (all in model steps).

    Attributes
    ----------
    history, horizon : int        observed steps before each prediction, and predicted steps
    stride : int                  steps between predictions along a track
    fde_steps : tuple of int      horizons at which displacement errors are reported
    test_fraction : float         share of tracks in the test set
    seeds : tuple of int          split seeds
    rollout : {"open", "closed"}  how learners' weights become a prediction (module doc)
    mpc_horizon : int or None     the MPC's planning horizon [steps]; required with "closed" (None: ``horizon``)
    lateral : {"hold", "mean-path", "plane", "neighbours"}   lateral offsets of predictions (`pirl_sim.lateral`)
    start : {"history", "track"}  predictions start from the history's own estimate (`ReplayScene.history_window`),
                                  or the whole piece's; with "history" read the scene with ``estimate="speeds"``
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
    start: str = "history"

    def __post_init__(self) -> None:
        for name, choices in (("start", STARTS), ("lateral", LATERAL_MODELS), ("rollout", ROLLOUTS)):
            if getattr(self, name) not in choices:
                raise ValueError(f"{name} must be one of {choices}, got {getattr(self, name)!r}")
        for name in ("history", "horizon", "stride"):
            v = getattr(self, name)
            if not is_positive_int(v):
                raise ValueError(f"{name} must be a positive number of steps, got {v!r}")
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


def entry_windows(test, windows, proto: ReplayProtocol) -> np.ndarray | None:
    """(W,) bool: the windows (i, step) whose car has a conflict point to yield at (metadata ``yields``,
    `pirl_sim.scenarios.replay.load_replay`) at some step of its history or horizon, the *entry windows*; None
    when the pieces carry no such flags (scenes not read from track files)."""
    flags = [test[i].metadata.get("yields") for i, _ in windows]
    if any(f is None for f in flags):
        return None
    return np.array([bool(np.asarray(f)[step - proto.history : step + proto.horizon + 1].any())
                     for f, (_, step) in zip(flags, windows)], dtype=bool)


def start_histories(scene, test, windows, proto: ReplayProtocol) -> list:
    """The history of every window (i, step) of the test pieces ``test``, the last state of each the start of
    its prediction: estimated from the history alone or cut from the whole piece's estimate
    (``proto.start``)."""
    if proto.start == "history":
        return [scene.history_window(test[i], step - proto.history, step) for i, step in windows]
    return [test[i].window(step - proto.history, step) for i, step in windows]


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
    test_keys = {unique[i] for i in split_indices(len(unique), test_fraction, seed)[1]}  # as the simulated scenarios
    test = [t for t, k in zip(tracks, keys) if k in test_keys]
    train = [t for t, k in zip(tracks, keys) if k not in test_keys]
    counts = {"n_train": len(unique) - len(test_keys), "n_test": len(test_keys), "n_train_pieces": len(train),
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
    trajs = simulate_receding_horizon(model, physical_starts(x0), theta, horizon,
                                      int(mpc_horizon))  # type: ignore[arg-type]
    return np.stack([t.states for t in trajs])


def _positions(model, test, windows, s_pred, proto, lateral: str | None = None, profile=None) -> np.ndarray:
    """Predicted arc lengths (W, horizon) mapped to x, y (W, horizon, 2) [m] on the track's own route of a
    `CompositePath` (even where a prediction runs beyond that route's ends).

    ``lateral``: the offsets the predicted arc lengths are placed at: the protocol's model (None:
    ``proto.lateral``, with the fitted `pirl_sim.lateral.MeanOffsetProfile` ``profile`` for "mean-path" and
    "plane"), or ``"recorded"``: the recorded future offsets, which leaves the error along the path only."""
    lateral = proto.lateral if lateral is None else lateral
    out = np.empty((len(windows), proto.horizon, 2))
    composite = isinstance(model.path, CompositePath)
    neighbours = profile.predict(test, windows, s_pred) if lateral == "neighbours" else None
    offsets = np.empty((len(windows), proto.horizon))
    segments = np.full(len(windows), -1)  # the track's own route, or -1: the path's segment at each point
    for w, (i, step) in enumerate(windows):
        t = test[i]
        seg = int(t.metadata.get("segment", 0))
        if composite and "segment" in t.metadata:
            segments[w] = seg
        if lateral == "recorded":
            offsets[w] = t.metadata["d"][step + 1 : step + 1 + proto.horizon]
        elif neighbours is not None:
            offsets[w] = neighbours[w]
        else:
            offsets[w] = predict_offsets(lateral, t.metadata["d"][step], seg, observed_s(t)[step], s_pred[w], profile)
    s_pred = np.asarray(s_pred, dtype=float)
    on_route = segments >= 0  # mapped point by point, so all windows of each kind in one call
    if on_route.any():
        out[on_route] = model.path.to_cartesian(s_pred[on_route], offsets[on_route], segment=segments[on_route, None])
    if not on_route.all():
        out[~on_route] = model.path.to_cartesian(s_pred[~on_route], offsets[~on_route])
    return out


def _recorded_xy(test, windows, horizon: int) -> np.ndarray:
    """The recorded positions (W, horizon, 2) [m] after each window's start."""
    return np.stack([np.asarray(test[i].metadata["xy"])[step + 1 : step + 1 + horizon] for i, step in windows])


def _errors(model, test, windows, s_pred, proto, lateral: str | None = None, profile=None) -> np.ndarray:
    """Distances (W, horizon) [m] between predicted arc lengths mapped to x, y (`_positions`) and the recorded
    positions."""
    xy = _positions(model, test, windows, s_pred, proto, lateral, profile)
    return np.linalg.norm(xy - _recorded_xy(test, windows, proto.horizon), axis=-1)


def _speed_heading_at_end(test, windows, horizon: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The true speed [m/s] and heading [rad] (W,) at each window's last predicted step: as recorded (``v_obs``,
    ``psi_obs`` of the metadata: the track file's vx, vy and psi_rad), else from the last two recorded positions."""
    speed, heading = np.empty(len(windows)), np.empty(len(windows))
    for w, (i, step) in enumerate(windows):
        meta, t = test[i].metadata, step + horizon
        if "v_obs" in meta and "psi_obs" in meta:
            speed[w], heading[w] = float(np.asarray(meta["v_obs"])[t]), float(np.asarray(meta["psi_obs"])[t])
        else:
            move = np.diff(np.asarray(meta["xy"])[t - 1 : t + 1], axis=0)[0]
            speed[w], heading[w] = float(np.hypot(*move)) / dt, float(np.arctan2(move[1], move[0]))
    return speed, heading


def _future_scores(model, test, windows, s_futures, proba, proto, profile, dt: float, K: int) -> dict:
    """minADE_K, minFDE_K, the INTERACTION miss rate and the mixture NLL per step (sigma 1 m) of the futures
    along the path (W, K', horizon) with probabilities (W, K'), placed by the protocol's lateral model; named
    by the K asked for (a learner may give fewer, K' <= K)."""
    xy = np.stack([_positions(model, test, windows, s_futures[:, k], proto, profile=profile)
                   for k in range(s_futures.shape[1])],
                  axis=1)
    truth = _recorded_xy(test, windows, proto.horizon)
    speed, heading = _speed_heading_at_end(test, windows, proto.horizon, dt)
    return {f"min_ade@{K}": float(min_ade(xy, truth).mean()), f"min_fde@{K}": float(min_fde(xy, truth).mean()),
            f"miss_rate@{K}": float(interaction_miss(xy, truth, speed, heading).mean()),
            f"nll_per_step@{K}": float(mixture_nll(xy, proba, truth, 1.0).mean() / proto.horizon)}


def fit_lateral_profile(train, kind: str = "mean-path", path=None, horizon: int | None = None):
    """`pirl_sim.lateral.MeanOffsetProfile` fitted on training pieces: per route from (route, arc length,
    recorded offset) for ``kind="mean-path"``, that backed by the profile pooled in the plane from their
    positions on ``path`` (the model's reference path) for ``"plane"``; for ``"neighbours"`` a
    `pirl_sim.lateral.NeighbourOffsets` on the ``"plane"`` profile for predictions of ``horizon`` steps; None for
    ``"hold"``."""
    if kind == "hold":
        return None
    if kind == "neighbours":
        if horizon is None:
            raise ValueError("the 'neighbours' lateral model needs the prediction horizon [steps]")
        return NeighbourOffsets().fit(fit_lateral_profile(train, "plane", path), train, horizon)
    if kind == "plane":
        pooled = MeanOffsetProfile().fit_plane(
            path, [np.asarray(t.metadata["xy"], dtype=float) for t in train])  # type: ignore[arg-type]
        return fit_lateral_profile(train, "mean-path").backed_by(pooled)
    segment = np.concatenate([np.full(t.n_steps + 1, int(t.metadata.get("segment", 0))) for t in train])
    s = np.concatenate([observed_s(t) for t in train])  # where each offset was observed
    d = np.concatenate([np.asarray(t.metadata["d"], dtype=float) for t in train])
    return MeanOffsetProfile().fit(segment, s, d)



_IRL_WARNINGS = {IRLConvergenceWarning: "irl_convergence_warnings",
                 HessianRegularizationWarning: "hessian_regularization_warnings"}


def _fit_with_diagnostics(fit) -> dict:
    """Run ``fit()`` (returns the fitted learner); count the IRL's warnings, pass every other warning on.

    Returns {"irl_convergence_warnings", "hessian_regularization_warnings", "irl_converged", "irl_groups",
    "irl_from"} (in this order, the rows' columns; ``irl_from`` empty: a fit of its own).
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        learner = fit()
    out = {name: 0 for name in _IRL_WARNINGS.values()}
    for w in caught:
        name = next((n for c, n in _IRL_WARNINGS.items() if issubclass(w.category, c)), None)
        if name is not None:
            out[name] += 1
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
    res = getattr(learner, "irl_result_", None)
    converged = np.asarray(res.converged, dtype=bool) if res is not None else np.zeros(0, dtype=bool)
    out["irl_converged"], out["irl_groups"], out["irl_from"] = (int(converged.sum()), int(converged.size),
                                                                 "")  # type: ignore[assignment]
    return out


def _shared_knn_fits(learner_specs) -> dict[int, int]:
    """{spec index: index of the spec whose fit it reuses} for PIRL-kNN specs that differ only in parameters that
    do not enter the IRL (`pirl_sim.learners.PIRLKNN.HEAD_PARAMS`: k, the aggregate, the selection); each group
    reuses the fit of its smallest k, the one whose fit succeeds whenever any does."""
    from pirl_sim.learners.knn import PIRLKNN

    groups: dict[str, list[int]] = {}
    for i, (_, key, params) in enumerate(learner_specs):
        if key == "pirl-knn":
            rest = {k: v for k, v in params.items() if k not in PIRLKNN.HEAD_PARAMS}
            groups.setdefault(repr(sorted(rest.items())), []).append(i)
    out = {}
    for members in groups.values():
        base = min(members, key=lambda i: learner_specs[i][2].get("n_neighbors", PIRLKNN().n_neighbors))
        out.update({i: base for i in members if i != base})
    return out


def fit_scene_speed(scene, tracks, **kwargs):
    """`pirl_sim.speed_fit.fit_desired_speed` on the (curvature, speed) of every state of ``tracks`` (pieces of
    ``scene``)."""
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
    fitted = _training_weights(learner, len(train)) if any("theta" in t.metadata for t in train) else None
    # the inferred weights of the test windows, and the IRL's own recovery on the training tracks
    for col, weights, owners in (("weight_error", theta, [test[i] for i, _ in windows]),
                                 ("irl_weight_error", fitted, train)):
        known = [j for j, t in enumerate(owners) if "theta" in t.metadata]
        if known and weights is not None:
            true = np.stack([owners[j].metadata["theta"] for j in known])
            out[col] = float(np.median(weight_recovery_error(np.asarray(weights)[known], true,
                                                             model.features.reference_index)))
        elif has_truth:
            out[col] = np.nan
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



def replay_seed(scene, seed: int, methods, proto: ReplayProtocol, *, desired_speed=None, n_futures: int = 0) -> dict:
    """One split seed of the replay: every method's row, per-window MED and predictions of a few windows.

    Parameters
    ----------
    scene, seed, proto : pirl_sim.scenarios.replay.ReplayScene, int, ReplayProtocol   split seed (not ``proto.seeds``)
    methods : list of (name, key, params)   ``key``: a pseudo-learner of `METHODS` or a learner of
                                 `pirl_sim.learners.LEARNERS` fitted with ``params``; ``name``: its row's ``method``
    desired_speed : None, "fit" or (a_lat, v_max)   the scene's own, fitted on the split (`fit_scene_speed`), or given
    n_futures : int              K > 0: also score K futures (``min_ade@K``, ..., mixture NLL with sigma 1 m)

    Returns
    -------
    result : dict                ``methods`` {name: {"row", "errors" (W,) MED [m], "shown"}}, ``examples``; ValueError
                                 for an unknown method, futures with closed loops, under 4 usable tracks, no test window
    """
    from pirl_sim.learners import LEARNERS, make_learner
    from pirl_sim.learners.knn import MIXTURES, steer_segment

    unknown = [key for _, key, _ in methods if key not in METHODS and key not in LEARNERS]
    if unknown:
        raise ValueError(f"unknown replay method(s) {unknown}; choose from {sorted([*METHODS, *LEARNERS])}")
    averaging = [name for name, _, params in methods if params.get("aggregate") in MIXTURES]
    if proto.rollout != "open" and (n_futures or averaging):
        what = f"n_futures={n_futures!r}" if n_futures else f"{averaging[0]} (it averages its neighbours' futures)"
        raise ValueError(f"{what} predicts open-loop plans; rollout {proto.rollout!r} is not available for it")
    tracks = usable_tracks(scene, proto)
    has_truth = any("theta" in t.metadata for t in tracks)
    plan = _open_plan(proto.horizon, proto.mpc_horizon)  # the futures' open-loop plans [steps]
    train, test, counts = split_by_track(tracks, seed, proto.test_fraction)
    model, speed, _ = desired_speed_model(scene, desired_speed, train)
    dt = model.dynamics.dt
    counts = {**counts, **speed}
    windows = _windows(test, proto)
    if not windows:
        raise ValueError("no test window: tracks are too short for the protocol")
    profile = fit_lateral_profile(train, proto.lateral, model.path, proto.horizon)
    recorded_s = np.stack([test[i].states[step + 1 : step + 1 + proto.horizon, 0] for i, step in windows])
    counts["lateral_floor"] = float(_errors(model, test, windows, recorded_s, proto, profile=profile).mean())
    histories = start_histories(scene, test, windows, proto)
    x0 = np.stack([h.states[-1] for h in histories])
    reuse = _shared_knn_fits(methods)
    # name -> (s_pred, fit_s, predict_s, extra); spec index -> (learner, diagnostics)
    predicted, fitted = {}, {}  # type: ignore[var-annotated]
    for i in sorted(range(len(methods)), key=lambda i: i in reuse):  # shared fits first
        name, key, params = methods[i]
        t0 = time.perf_counter()
        if key in ("cv", "ca"):
            s_pred = KinematicModel(model, key).predict_states(x0, None, proto.horizon)[:, 1:, 0]
            predicted[name] = (s_pred, 0.0, 0.0, {})
        elif key == "hindsight":
            futures = [test[j].window(step, step + proto.horizon) for j, step in windows]
            if proto.start == "history":  # fitted from the state its prediction starts from
                futures = [steer_segment(model.dynamics, x, f) for x, f in zip(x0, futures)]
            oracle = make_learner("pirl-knn", model=model, n_neighbors=1, irl_max_iter=400)
            diag = _fit_with_diagnostics(lambda: oracle.fit(futures))
            fit_s = time.perf_counter() - t0
            s_pred = predict_path_states(model, x0, oracle.demo_theta_, proto.horizon)[:, 1:, 0]
            predicted[name] = (s_pred, fit_s, 0.0, diag)
        elif key == "direct":
            reg = DirectRegression(model, proto.history, proto.horizon, lags=history_lags(dt, proto.history),
                                   online=proto.start == "history").fit(train)
            fit_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            predicted[name] = (reg.predict_s(histories), fit_s, time.perf_counter() - t0, {})
        elif key != "cv-xy":
            if i in reuse:  # the same IRL: only what follows it anew
                base, diag = fitted[reuse[i]]
                default = type(base)().get_params()
                learner = base.with_aggregate(train, **{k: params.get(k, default[k]) for k in base.HEAD_PARAMS})
                diag = dict(diag, irl_from=methods[reuse[i]][0])
            else:
                learner = make_learner(key, model=model, window=proto.history, windows="sliding", **params)
                diag = _fit_with_diagnostics(lambda: learner.fit(train))
            fitted[i] = (learner, diag)
            fit_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            mixture = getattr(learner, "aggregate", "weights") in MIXTURES  # the mean of several futures
            # a mixture's weights only score against known weights (its own rollouts make them again)
            theta = learner.infer_weights(histories) if has_truth or not mixture else None
            if mixture:
                s_pred = learner.predict_states(histories, plan)[:, 1 : proto.horizon + 1, 0]
            else:
                s_pred = predict_path_states(model, x0, theta, proto.horizon,  # type: ignore[arg-type]
                                             rollout=proto.rollout,
                                             mpc_horizon=proto.mpc_horizon)[:, 1:, 0]
            extra = {**_truth_scores(learner, train, test, windows, theta, model, has_truth), **diag}
            if len(getattr(learner, "lookup_ahead", ())):  # the road-ahead weight in use (chosen or given)
                extra["ahead_weight"] = float(learner.ahead_weight_)
            if n_futures:
                fut, proba = learner.predict_futures(histories, plan, n_futures=int(n_futures), random_state=seed)
                extra.update(_future_scores(model, test, windows, fut[:, :, 1 : proto.horizon + 1, 0], proba,
                                            proto, profile, dt, int(n_futures)))
            predicted[name] = (s_pred, fit_s, time.perf_counter() - t0, extra)
    shown = np.linspace(0, len(windows) - 1, min(4, len(windows))).astype(int)  # windows of the S-T figure
    examples = {"t": dt * np.arange(-proto.history, proto.horizon + 1),
                "truth": np.stack([test[windows[w][0]].states[windows[w][1] - proto.history:
                                                             windows[w][1] + proto.horizon + 1, 0] for w in shown])}
    entry = entry_windows(test, windows, proto)
    out, plane = {}, {}
    for name, key, _ in methods:
        if key == "cv-xy":  # in the plane, at the velocity between the last two recorded positions
            last = np.stack([np.asarray(test[i].metadata["xy"])[step - 1 : step + 1] for i, step in windows])
            pred = last[:, 1:] + (last[:, 1:] - last[:, :1]) / dt * (dt * np.arange(1, proto.horizon + 1))[:, None]
            err = np.linalg.norm(pred - _recorded_xy(test, windows, proto.horizon), axis=-1)
            s_pred, fit_s, pred_s, extra, path = None, 0.0, 0.0, {}, {}  # type: ignore[assignment]
            plane[name] = pred
        else:
            s_pred, fit_s, pred_s, extra = predicted[name]
            err = _errors(model, test, windows, s_pred, proto, profile=profile)
            path = {"med_path": float(_errors(model, test, windows, s_pred, proto, "recorded").mean())}
        row = {"seed": seed, "method": name, "med": float(err.mean()), **path, "n_windows": len(windows), **counts,
               "fit_s": fit_s, "predict_s": pred_s, **extra}
        if entry is not None:
            row.update(n_entry_windows=int(entry.sum()),
                       med_entry=float(err[entry].mean()) if entry.any() else float("nan"),
                       med_not_entry=float(err[~entry].mean()) if not entry.all() else float("nan"))
        for k in proto.fde_steps:
            row[f"de@{k * dt:.1f}s"] = float(err[:, k - 1].mean())
        out[name] = {"row": row, "errors": err.mean(axis=1), "shown": None if s_pred is None else s_pred[shown]}
    examples.update(_scenes(model, test, windows, methods, out, predicted, plane, proto, profile))
    return {"methods": out, "examples": examples}


def _scenes(model, test, windows, methods, out, predicted, plane, proto, profile) -> dict:
    """The windows where the best learner (lowest MED of the methods that are not baselines) beats CA by most
    and loses to it by most, in the plane: ``scene_windows`` [gain, loss], ``scene_history`` (2, history + 1, 2) and ``scene_future`` (2, horizon, 2)
    [m]; each method's entry gets ``scene`` (2, horizon, 2), its predictions there. Nothing without CA or a
    learner."""
    names = [name for name, _, _ in methods]
    learners = [i for i, (_, key, _) in enumerate(methods) if key not in METHODS]
    ca = [i for i, (_, key, _) in enumerate(methods) if key == "ca"]
    for entry in out.values():
        entry["scene"] = None
    if not learners or not ca:
        return {}
    best = min(learners, key=lambda i: out[names[i]]["row"]["med"])
    diff = out[names[ca[0]]]["errors"] - out[names[best]]["errors"]
    chosen = [int(np.argmax(diff)), int(np.argmin(diff))]
    at = [windows[w] for w in chosen]
    for name, _, _ in methods:
        if name in plane:
            out[name]["scene"] = plane[name][chosen]
        else:
            out[name]["scene"] = _positions(model, test, at, predicted[name][0][chosen], proto, profile=profile)
    history = np.stack([np.asarray(test[i].metadata["xy"])[step - proto.history : step + 1] for i, step in at])
    return {"scene_windows": np.array(chosen, dtype=float),
            "scene_history": history, "scene_future": _recorded_xy(test, at, proto.horizon)}


# ------------------------------------------------------------------------------------------ the sweep scenario
RECORDED_PARAMS = {
    "tracks": Param("path", None, "a vehicle_tracks_*.csv file or a directory of them (required)"),
    "map": Param("path", None, "the Lanelet2 OSM map of the recording (required)"),
    "files": Param("int", 0, "use the first N track files, sorted by name (0: every file)"),
    "load": Param("table", None, "keyword arguments of pirl_sim.scenarios.replay.load_replay: dt, estimate, noise "
                  "{sigma_s, sigma_v, sigma_j, sigma_a}, selection, max_steps, features, arc_length, smoothing, "
                  "speed_smoothing, a_lat, v_max (absent: its defaults, but estimate 'speeds' with history starts)"),
    "replay": Param("table", None, "the rest of the replay: fde_steps (absent: ReplayProtocol's below the "
                    "horizon, and the horizon), test_fraction, rollout, mpc_horizon, lateral, start (ReplayProtocol), "
                    "desired_speed ('fit' or [a_lat, v_max]; absent: the scene's) and n_futures"),
}
_LOAD_KEYS = ("dt", "estimate", "noise", "selection", "max_steps", "features", "arc_length", "smoothing",
              "speed_smoothing", "a_lat", "v_max")
#: ReplayProtocol's fields a config sets (the windows come from the protocol, the seed from the cell), and the rest
_REPLAY_KEYS = (*(f.name for f in fields(ReplayProtocol) if f.name not in ("history", "horizon", "stride", "seeds")),
                "desired_speed", "n_futures")
_SIDECARS = ("ground_truth.csv", "driver_steps.csv", "run.json")  #: files beside the tracks that a scene reads


def recorded_files(params: dict) -> list[Path]:
    """The track files of a ``recorded`` scene: ``tracks`` itself, or the track files in that directory (the
    first ``files`` by name when ``files`` > 0)."""
    tracks = Path(params["tracks"])
    if tracks.is_file():
        return [tracks]
    if not tracks.is_dir():
        raise ValueError(f"tracks {str(tracks)!r} is neither a file nor a directory")
    files = find_track_files(tracks)
    return files[: params["files"]] if params["files"] else files  # sorted by name


def recorded_fingerprint(params: dict) -> str:
    """sha256 (20 hex digits) of the names and bytes of the scene's track files, the sidecars beside them
    (`_SIDECARS`) and the map: part of every cell key, so other data never reuse a stored cell."""
    h = hashlib.sha256()
    files = [Path(f) for f in recorded_files(params)]
    sidecars = sorted({f.parent / name for f in files for name in _SIDECARS if (f.parent / name).is_file()})
    for f in [*files, *sidecars, Path(params["map"])]:
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:20]


def _load_kwargs(load: dict) -> dict:
    out = dict(load)
    if "noise" in out:
        out["noise"] = EstimateNoise(**out["noise"])
    return out


def _replay_settings(spec: dict) -> tuple[ReplayProtocol, object, int]:
    """(protocol, desired speed, n_futures) of a cell spec."""
    replay, p = dict(spec["scenario_params"]["replay"]), spec["protocol"]
    desired = replay.pop("desired_speed", None)
    n_futures = int(replay.pop("n_futures", 0))
    default_fde = [k for k in ReplayProtocol.fde_steps if k < p["horizon"]] + [p["horizon"]]  # the default's that fit
    replay["fde_steps"] = tuple(replay.get("fde_steps", default_fde))
    proto = ReplayProtocol(history=p["history_steps"], horizon=p["horizon"], stride=p["stride"],
                           seeds=(spec["seed"],), **replay)
    return proto, (tuple(desired) if isinstance(desired, list) else desired), n_futures


def _check_recorded(params: dict) -> dict:
    if not Path(params["map"]).is_file():
        raise ValueError(f"map {params['map']!r} is not a file")
    if params["files"] < 0:
        raise ValueError(f"files must be >= 0 (0: every file), got {params['files']!r}")
    recorded_files(params)  # neither a file nor a directory, or a directory without track files: ValueError
    for name, keys in (("load", _LOAD_KEYS), ("replay", _REPLAY_KEYS)):
        check_keys(f"parameter {name!r}", params[name], keys)
    if isinstance(params["load"].get("noise"), dict):
        _load_kwargs(params["load"])  # EstimateNoise checks the noise model
    dt = params["load"].get("dt", 0.2)
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or dt <= 0 or not np.isclose(dt / 0.1, round(dt / 0.1)):
        raise ValueError(f"load.dt must be a positive multiple of the 0.1 s frames, got {dt!r}")
    if params["replay"].get("rollout", "open") != "open" and params["replay"].get("n_futures", 0):
        raise ValueError(f"replay.n_futures = {params['replay']['n_futures']!r} scores open-loop futures, but "
                         f"replay.rollout = {params['replay']['rollout']!r} re-plans at every step: use rollout 'open'")
    desired = params["replay"].get("desired_speed")
    if not (desired is None or desired == "fit" or (isinstance(desired, list) and len(desired) == 2)):
        raise ValueError(f"replay.desired_speed must be 'fit' or [a_lat, v_max], got {desired!r}")
    return params


def _check_protocol(params: dict, protocol: dict) -> None:
    """The rolling protocol only, and the `ReplayProtocol` of its windows and the ``replay`` parameter (e.g.
    ``fde_steps`` beyond the horizon) valid: at the config check, before any cell."""
    if protocol["kind"] != "rolling":
        raise ValueError(f"runs the rolling protocol, not {protocol['kind']!r}")
    try:
        _replay_settings({"scenario_params": params, "protocol": protocol, "seed": 0})
    except (TypeError, ValueError) as exc:
        raise ValueError(f"parameter 'replay': {exc}") from None


def _check_recorded_learner(params: dict, name: str, learner_params: dict) -> None:
    """A closed-loop rollout re-plans at every step: a learner that averages or chooses among its neighbours'
    open-loop futures cannot predict it (refused at the config check, not in every cell)."""
    from pirl_sim.learners.knn import MIXTURES

    if params["replay"].get("rollout", "open") != "open" and learner_params.get("aggregate") in MIXTURES:
        raise ValueError(f"rolls out closed loops (replay.rollout = {params['replay']['rollout']!r}), but {name} with "
                         f"aggregate = {learner_params['aggregate']!r} predicts open-loop futures: use rollout "
                         "'open', or another aggregate")


def _recorded_shape(params: dict) -> TrainShape:
    """An upper bound from the files alone: every valid vehicle track of every file, whole, the longest ones in
    the training set (so the config check reads every track file and rejects a k larger than the training set)."""
    stride = int(round(params["load"].get("dt", 0.2) / 0.1))  # model steps of 0.1 s frames
    lengths = []
    for f in recorded_files(params):
        try:
            df = read_tracks(f, kind="vehicle")
        except ValueError:  # the replay keeps a file's valid tracks: count those
            df, _ = read_tracks_lenient(f)
            if df is None:
                raise ValueError(f"{f}: no valid track (not an INTERACTION vehicle track file, or every track has a "
                                 "bad row)") from None
        lengths += [int((n - 1) // stride) for n in df["track_id"].value_counts()]
    n = len(lengths)
    n_train = n - max(1, int(round(params["replay"].get("test_fraction", 0.25) * n))) if n > 1 else n
    return TrainShape(n_train, tuple(sorted(lengths, reverse=True)[:n_train]), exact=False)


def load_scene(params: dict):
    """The `pirl_sim.scenarios.replay.ReplayScene` of a ``recorded`` scene's parameters (the last 2 kept for the
    next cells of this process: loading is deterministic). Without ``load.estimate``, a scene replayed with
    history starts (``replay.start``, `ReplayProtocol`'s default) is read with ``estimate="speeds"``, as
    ``pirl-sim replay`` reads it: a position-only fit over a short history lags the car's speed."""
    start = (params.get("replay") or {}).get("start", ReplayProtocol.start)
    load = {"estimate": "speeds" if start == "history" else "positions", **params["load"]}
    return _load_scene(json.dumps([params["tracks"], params["map"], params["files"], load], sort_keys=True))


@lru_cache(maxsize=2)
def _load_scene(key: str):
    tracks, map_path, files, load = json.loads(key)
    return load_replay(recorded_files({"tracks": tracks, "files": files}), map_path, **_load_kwargs(load))


def method_id(spec: dict) -> str:
    """The name a cell's method has inside its task (its learner and parameters as JSON; the report maps it to
    the cell's label)."""
    return json.dumps([spec["learner"], spec["learner_params"]], sort_keys=True, separators=(",", ":"))


def _group(spec: dict) -> str:
    """Cells of one task: the same scene, protocol and split seed (`run_recorded_cells`)."""
    return json.dumps({k: v for k, v in spec.items() if k not in ("learner", "learner_params")}, sort_keys=True)


def _plain(x):
    """JSON data of a method's result: arrays as lists, NaN as None (`decode_method` reverses it)."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_plain(v) for v in x]
    x = x.item() if isinstance(x, np.generic) else x  # numpy scalars as Python's bool, int, float
    return None if isinstance(x, float) and not np.isfinite(x) else x


def decode_method(result: dict) -> dict:
    """A stored cell's ``result`` back into `replay_seed`'s per-method entry and examples: (entry, examples)."""
    result = result["replay"]
    row = {k: (np.nan if v is None else v) for k, v in result["row"]}
    shown = None if result["shown"] is None else np.array(result["shown"], dtype=float)
    scene = None if result.get("scene") is None else np.array(result["scene"], dtype=float)
    entry = {"row": row, "errors": np.array(result["errors"], dtype=float), "shown": shown, "scene": scene}
    return entry, {k: np.array(v, dtype=float) for k, v in result["examples"].items()}  # type: ignore[return-value]


def run_recorded_cells(specs: list[dict]) -> list[tuple[dict, dict]]:
    """Run the cells of one task (one scene, protocol and split seed; `pirl_sim.engine.worker.run_cells` calls it and
    adds the task's time shared equally, its distinct warnings and the worker): `replay_seed` with every cell's
    method.

    Returns
    -------
    list of (scores, timings), one per spec: ``scores`` = the sweep's scores (``med``, ``fde`` at the last of
    ``fde_steps``, ``med_std`` over the windows, ``n_predictions`` windows, ``weight_error``, ``ari``,
    ``n_train``, ``n_test`` tracks, ``n_warnings`` IRL diagnostics) and ``replay`` = {"row": [[column, value],
    ...] (in order), "errors" (W,), "shown", "examples"} (NaN as None; `decode_method`); ``timings``: the row's
    ``fit_s`` and ``predict_s`` (as ``evaluate_s``).
    """
    scene = load_scene(specs[0]["scenario_params"])
    proto, desired_speed, n_futures = _replay_settings(specs[0])
    methods = [(method_id(s), s["learner"], {k: tuple(v) if isinstance(v, list) else v
                                             for k, v in s["learner_params"].items()}) for s in specs]
    res = replay_seed(scene, specs[0]["seed"], methods, proto, desired_speed=desired_speed, n_futures=n_futures)
    fde = f"de@{proto.fde_steps[-1] * scene.model.dynamics.dt:.1f}s"
    out = []
    for m in res["methods"].values():  # in the order of methods
        row = m["row"]
        scores = _plain({  # the sweep's tidy table (`pirl_sim.engine.run.SCORE_COLUMNS`), and the replay's own
            "med": row["med"], "med_std": float(np.std(m["errors"])), "fde": row[fde],
            "weight_error": row.get("weight_error"), "ari": row.get("ari"), "n_styles": None,
            "n_train": row["n_train"], "n_test": row["n_test"], "n_predictions": row["n_windows"],
            "n_warnings": int(row.get("irl_convergence_warnings", 0) + row.get("hessian_regularization_warnings", 0)),
            "replay": {"row": list(row.items()), "errors": m["errors"], "shown": m["shown"], "scene": m["scene"],
                       "examples": res["examples"]}})
        out.append((scores, {"fit_s": row["fit_s"], "evaluate_s": row["predict_s"]}))
    return out


#: the recorded kind, and the same under its former name ``replay``
SPEC = ScenarioSpec(
    "recorded", "recorded roundabout tracks replayed as `pirl-sim replay` does: split by track per seed, every test "
    "window predicted and scored in metres (module pirl_sim.experiments.recorded)",
    RECORDED_PARAMS, _check_recorded, None, _recorded_shape, recorded_fingerprint,
    run_cells=run_recorded_cells, task_group=_group, check_protocol=_check_protocol,
    check_learner=_check_recorded_learner,
)
SPECS = (SPEC, replace(SPEC, name="replay", summary="the recorded scenario's former name"))
