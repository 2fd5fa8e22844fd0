"""The replay experiment: learners and baselines predicting recorded (or simulated) tracks, scored in metres.

For each split seed the selected tracks are split by track into train and test. Every test track is predicted
at every ``stride``-th step t with t >= history and t + horizon <= its length: learners infer weights from the
last ``history`` steps and the MPC predicts the next ``horizon`` steps from the estimated state at t; the
prediction is mapped to Cartesian metres on the track's own path at its last observed lateral offset and
compared with the recorded positions. Baselines use the same windows:

- ``CV (path)``: constant speed along the path, ``CA (path)``: constant acceleration along the path (speed
  kept >= 0), both from the estimated state at t;
- ``CV (x, y)``: constant velocity in the plane from the last two recorded positions.

Scores per (seed, method): MED [m] (mean over windows of the mean distance over the horizon) and
displacement errors at fixed horizons. Differences between methods are paired by window, averaged per seed,
and reported with their standard error over the seeds: on ~60 real test tracks the gaps between methods
were as large as the split-to-split noise, so a single split proves nothing.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pirl_sim.metrics import adjusted_rand_index, match_styles, weight_recovery_error
from pirl_sim.validation import is_positive_int

__all__ = ["ReplayProtocol", "run_replay", "paired_differences", "BASELINES"]

BASELINES = ("CV (path)", "CA (path)", "CV (x, y)")


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
    """

    history: int = 10
    horizon: int = 15
    stride: int = 5
    fde_steps: tuple[int, ...] = (5, 10, 15)
    test_fraction: float = 0.25
    seeds: tuple[int, ...] = (0, 1, 2)

    def __post_init__(self) -> None:
        for name in ("history", "horizon", "stride"):
            v = getattr(self, name)
            if not is_positive_int(v):
                raise ValueError(f"{name} must be a positive number of steps, got {v!r}")
        if any(not 1 <= k <= self.horizon for k in self.fde_steps):
            raise ValueError(f"fde_steps must lie in [1, horizon={self.horizon}], got {self.fde_steps}")
        if not 0 < self.test_fraction < 1:
            raise ValueError(f"test_fraction must be in (0, 1), got {self.test_fraction!r}")
        if not self.seeds:
            raise ValueError("need at least one split seed")


def _windows(test, proto: ReplayProtocol):
    out = []
    for i, t in enumerate(test):
        for step in range(proto.history, t.n_steps - proto.horizon + 1, proto.stride):
            out.append((i, step))
    return out


def _errors(model, test, windows, s_pred, proto) -> np.ndarray:
    """Distances (W, horizon) between predicted arc lengths mapped to x, y and the recorded positions."""
    err = np.empty((len(windows), proto.horizon))
    for w, (i, step) in enumerate(windows):
        t = test[i]
        xy = model.path.to_cartesian(s_pred[w], np.full(proto.horizon, t.metadata["d"][step]))
        err[w] = np.linalg.norm(xy - t.metadata["xy"][step + 1 : step + 1 + proto.horizon], axis=1)
    return err


def _baseline_s(kind: str, x0: np.ndarray, horizon: int, dt: float) -> np.ndarray:
    tt = dt * np.arange(1, horizon + 1)
    s0, v0, a0 = x0[:, :1], x0[:, 1:2], x0[:, 2:3]
    if kind == "CV (path)":
        return s0 + v0 * tt
    # constant acceleration, stopping rather than reversing
    t_stop = np.where(a0 < 0, np.minimum(-v0 / np.minimum(a0, -1e-12), tt[-1]), tt[-1])
    tc = np.minimum(tt, t_stop)
    return s0 + v0 * tc + 0.5 * a0 * tc**2


def run_replay(scene, learner_specs, proto: ReplayProtocol = ReplayProtocol(), *, progress=None) -> dict:
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
    ``errors`` {(seed, method): per-window MED (W,)} and ``selected`` (number of tracks used).
    """
    from pirl_sim.learners import make_learner

    say = progress or (lambda msg: None)
    tracks = [t for t in scene.selected if t.n_steps >= proto.history + proto.horizon]
    if len(tracks) < 4:
        raise ValueError(
            f"only {len(tracks)} selected tracks have {proto.history + proto.horizon} steps; need at least 4"
        )
    model = scene.model
    dt = model.dynamics.dt
    rows, errors, examples = [], {}, {}
    # split by track: pieces of one long track never sit on both sides
    keys = [(t.metadata.get("file"), t.metadata.get("track_id", i)) for i, t in enumerate(tracks)]
    unique = sorted(set(keys), key=str)
    for seed in proto.seeds:
        order = np.random.default_rng(seed).permutation(len(unique))
        n_test = max(1, int(round(proto.test_fraction * len(unique))))
        test_keys = {unique[i] for i in order[:n_test]}
        test = [t for t, k in zip(tracks, keys) if k in test_keys]
        train = [t for t, k in zip(tracks, keys) if k not in test_keys]
        windows = _windows(test, proto)
        if not windows:
            raise ValueError("no test window: tracks are too short for the protocol")
        x0 = np.stack([test[i].states[step] for i, step in windows])
        histories = [test[i].window(step - proto.history, step) for i, step in windows]
        methods = {}
        for kind in BASELINES[:2]:
            methods[kind] = (_baseline_s(kind, x0, proto.horizon, dt), 0.0, 0.0, {})
        for name, key, params in learner_specs:
            learner = make_learner(key, model=model, window=proto.history, windows="sliding", **params)
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                learner.fit(train)
            fit_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            theta = learner.infer_weights(histories)
            s_pred = model.predict_states(x0, theta, proto.horizon)[:, 1:, 0]
            extra = _truth_scores(learner, train, test, windows, theta, model)
            methods[name] = (s_pred, fit_s, time.perf_counter() - t0, extra)
            say(f"seed {seed}: {name} fitted in {fit_s:.1f} s")
        if seed == proto.seeds[0]:  # a few windows for the S-T figure
            shown = np.linspace(0, len(windows) - 1, min(4, len(windows))).astype(int)
            examples = {
                "t": dt * np.arange(-proto.history, proto.horizon + 1),
                "truth": np.stack([test[windows[w][0]].states[windows[w][1] - proto.history:
                                                             windows[w][1] + proto.horizon + 1, 0] for w in shown]),
                "predictions": {name: m[0][shown] for name, m in methods.items()},
            }
        for name, (s_pred, fit_s, pred_s, extra) in methods.items():
            err = _errors(model, test, windows, s_pred, proto)
            errors[(seed, name)] = err.mean(axis=1)
            row = {"seed": seed, "method": name, "med": float(err.mean()), "n_windows": len(windows),
                   "n_train": len(train), "n_test": len(test), "fit_s": fit_s, "predict_s": pred_s, **extra}
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
               "n_train": len(train), "n_test": len(test), "fit_s": 0.0, "predict_s": 0.0}
        for k in proto.fde_steps:
            row[f"de@{k * dt:.1f}s"] = float(err[:, k - 1].mean())
        rows.append(row)
    rows = pd.DataFrame(rows)
    return {"rows": rows, "paired": paired_differences(errors, "TIRL"), "errors": errors, "selected": len(tracks),
            "examples": examples, "history": proto.history}


def _truth_scores(learner, train, test, windows, theta, model) -> dict:
    out = {}
    if all("style" in t.metadata for t in train) and hasattr(learner, "labels_"):
        truth = np.array([t.metadata["style"] for t in train])
        out["ari"] = adjusted_rand_index(truth, learner.labels_)
        out["matched_styles"] = len(match_styles(truth, learner.labels_))
    if all("theta" in test[i].metadata for i, _ in windows):
        true = np.stack([test[i].metadata["theta"] for i, _ in windows])
        out["weight_error"] = float(np.median(weight_recovery_error(theta, true, model.features.reference_index)))
    return out


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
    """Mean and standard deviation over seeds of every score, one row per method (sorted by MED)."""
    rows = result["rows"]
    scores = [c for c in rows.columns if c == "med" or c.startswith("de@") or c in ("ari", "weight_error")]
    agg = rows.groupby("method")[scores].agg(["mean", "std"])
    agg.columns = [f"{a}_{b}" for a, b in agg.columns]
    return agg.sort_values("med_mean").reset_index()


def write_replay_results(result: dict, scene, out_dir, command: str) -> None:
    """rows.csv, summary.csv/.md, paired.csv and README.md (with the selection counts) in ``out_dir``."""
    from pathlib import Path

    from pirl_sim.harness.reproduce import _markdown
    from pirl_sim.io.atomic import atomic_write_text

    out = Path(out_dir)
    summary = summarize(result)
    atomic_write_text(out / "rows.csv", result["rows"].to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "summary.csv", summary.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "paired.csv", result["paired"].to_csv(index=False, float_format="%.6g"))
    _write_figures(result, scene, out)
    n_inter = sum(t.metadata["interacted"] for t in scene.trajectories)
    lines = [
        "# Replay experiment",
        "",
        f"Made by `{command}`.",
        "",
        f"Tracks read: {scene.n_tracks}; converted: {len(scene.trajectories)}; flagged as interacting: {n_inter}; "
        f"used (not interacting, long enough): {result['selected']}. Skipped: {scene.skipped or 'none'}.",
        "",
        "## Scores (mean and std over split seeds)",
        "",
        _markdown(summary),
        "",
        "## Paired differences against TIRL (MED, per window; mean and standard error over seeds)",
        "",
        _markdown(result["paired"]),
        "",
        "![clusters](clusters.png) ![S-T](s_t.png)" + (" ![MED vs k](knn_k.png)" if (out / "knn_k.png").exists() else ""),
    ]
    atomic_write_text(out / "README.md", "\n".join(lines) + "\n")


def _write_figures(result: dict, scene, out) -> None:
    """clusters.png (PIRL-GMM, k=3, whole tracks), s_t.png (a few predicted windows), knn_k.png (when several
    kNN learners ran)."""
    import re

    from pirl_sim.harness import figures
    from pirl_sim.io.atomic import atomic_write_bytes
    from pirl_sim.learners import PIRLGMM

    tracks = scene.selected
    model = scene.model
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        gmm = PIRLGMM(model, n_components=min(3, len(tracks)), random_state=0).fit(tracks)
    styles = np.array([t.metadata.get("style", -1) for t in tracks])
    atomic_write_bytes(out / "clusters.png", figures.feature_clusters(
        model.feature_values(tracks), model.features.names, gmm.labels_, styles if np.all(styles >= 0) else None))
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
