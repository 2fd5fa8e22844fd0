"""Styles found back in weight space from the per-track fits of a recovery study (``pirl-sim recover``).

Every PIRL track's fitted log weights are a noisy measurement of its driver's: the fit's standard errors
(`pirl_sim.receding.log_standard_errors`) say how noisy. A weight the track's data do not determine (one with an
infinite standard error; an interaction weight that the study's rule does not count as identified,
`pirl_sim.experiments.recovery.IDENTIFIED_SE` and ``MIN_NEAR_STEPS``, which the study passes: near an obstacle for
one or two steps, a fit can end far off with a small local error) enters with `UNKNOWN_SE`, so it is integrated
out rather than clustered on. `style_mixtures` fits a deconvolved Gaussian mixture with as many components as the
population has styles (`pirl_sim.deconvolution.extreme_deconvolution`) to each run's tracks and to all runs of a
simulator and noise level pooled, and scores it:

- ``ari``: adjusted Rand index of the tracks' most probable components against their drivers' styles;
- ``mean_err_<f>``: for weight f, the largest over styles of |component mean - mean true log weight of the style's
  tracks| (components paired with styles by the Hungarian method on the tracks' assignments).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

__all__ = ["UNKNOWN_SE", "SE_FLOOR", "identified", "determined", "diagonal_covariances", "style_mixtures",
           "track_measurements"]

#: [log] standard error given to a weight the track's data do not determine: wide against any spread of styles
#: (log weights of the styles differ by a few units), so the mixture integrates it out
UNKNOWN_SE = 1e3
#: [log] smallest standard error used: the noise-free fits' errors can be 1e-5, far below the styles' own spread
SE_FLOOR = 0.01
#: restarts of the mixture fit (the best log-likelihood kept)
N_INIT = 5


def identified(tracks: pd.DataFrame, feature: str, *, identified_se: float, min_near_steps: int) -> np.ndarray:
    """Bool (N,): the tracks (rows of a recovery study's ``tracks.csv``) whose fit identifies the interaction weight
    ``feature``: a standard error of its log at most ``identified_se`` (not NaN / inf) and at least
    ``min_near_steps`` usable steps within reach of its obstacle (``<feature>_steps``)."""
    return determined(tracks[f"se_log_{feature}"].to_numpy(dtype=float), tracks[f"{feature}_steps"].to_numpy(),
                      identified_se=identified_se, min_near_steps=min_near_steps)


def determined(se: np.ndarray, near_steps: np.ndarray, *, identified_se: float, min_near_steps: int) -> np.ndarray:
    """Bool, the shape of ``se``: an interaction weight is identified where the standard error of its log is at
    most ``identified_se`` (NaN and inf are not) and at least ``min_near_steps`` steps came within reach of its
    obstacle (``near_steps``, broadcast against ``se``)."""
    return (np.asarray(se, dtype=float) <= identified_se) & (np.asarray(near_steps) >= min_near_steps)


def diagonal_covariances(se: np.ndarray) -> np.ndarray:
    """Measurement covariances (N, F, F) of independent standard errors ``se`` (N, F)."""
    se = np.asarray(se, dtype=float)
    return se[:, :, None] * np.eye(se.shape[1]) * se[:, None, :]


def track_measurements(tracks: pd.DataFrame, features: list[str], *, identified_se: float,
                       min_near_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Fitted log weights X (N, F) and their measurement covariances S (N, F, F) (diagonal) of the tracks
    (rows of a recovery study's ``tracks.csv``) for ``features``; an interaction weight (a feature with a
    ``<f>_steps`` column) counts only with a standard error <= ``identified_se`` and >= ``min_near_steps`` steps
    within reach of its obstacle; module doc for the unknown weights."""
    X = np.log(tracks[[f"theta_hat_{f}" for f in features]].to_numpy(dtype=float))
    se = tracks[[f"se_log_{f}" for f in features]].to_numpy(dtype=float)
    known = np.isfinite(se)
    for j, f in enumerate(features):
        if f"{f}_steps" in tracks:  # an interaction weight: only where identified (the study's rule)
            known[:, j] &= identified(tracks, f, identified_se=identified_se, min_near_steps=min_near_steps)
    se = np.where(known, np.maximum(np.nan_to_num(se, nan=UNKNOWN_SE), SE_FLOOR), UNKNOWN_SE)
    return X, diagonal_covariances(se)


def _score(group: pd.DataFrame, features: list[str], seed: int, rule: dict) -> dict:
    from sklearn.metrics import adjusted_rand_score

    from pirl_sim.deconvolution import extreme_deconvolution
    from pirl_sim.metrics import match_styles

    names = sorted(group["style_name"].unique())
    truth = group["style_name"].map({n: i for i, n in enumerate(names)}).to_numpy()
    row: dict = {"tracks": len(group), "styles": len(names)}
    if len(group) < 2 * len(names):
        return dict(row, ari=math.nan, **{f"mean_err_{f}": math.nan for f in features})
    X, S = track_measurements(group, features, **rule)
    mix = extreme_deconvolution(X, S, len(names), rng=np.random.default_rng(seed), n_init=N_INIT)
    labels = mix.predict_proba(X, S).argmax(axis=1)
    row["ari"] = float(adjusted_rand_score(truth, labels))
    pairs = match_styles(truth, labels)
    true_log = np.log(group[[f"theta_{f}" for f in features]].to_numpy(dtype=float))
    for j, f in enumerate(features):
        errs = [abs(mix.means[c, j] - true_log[truth == s, j].mean()) for c, s in pairs.items()]
        row[f"mean_err_{f}"] = float(max(errs)) if len(pairs) == len(names) else math.nan
    return row


def style_mixtures(tracks: pd.DataFrame, features: list[str], seed: int = 0, *, identified_se: float,
                   min_near_steps: int) -> pd.DataFrame:
    """Per run (``simulator``, ``control_noise``, ``seed``) and, with several seeds, pooled over the seeds: the
    mixture's scores (module doc) with ``tracks`` and ``styles``. ``tracks``: a recovery study's ``tracks.csv``
    rows; ``features``: the fitted weights to cluster on (e.g. every weight but the reference); ``seed`` seeds the
    mixture's restarts; ``identified_se``, ``min_near_steps``: the study's rule for interaction weights
    (`track_measurements`)."""
    rule = {"identified_se": float(identified_se), "min_near_steps": int(min_near_steps)}
    if not features:
        raise ValueError("style_mixtures needs at least one feature to cluster on, got none")
    missing = [c for f in features for c in (f"theta_{f}", f"theta_hat_{f}", f"se_log_{f}") if c not in tracks]
    if missing:
        raise ValueError(f"tracks lack the columns {missing} (a recovery study's tracks.csv has them)")
    rows = []
    for (sim, noise), runs in tracks.groupby(["simulator", "control_noise"], sort=False):
        parts = [(str(s), g) for s, g in runs.groupby("seed", sort=False)]
        if len(parts) > 1:
            parts.append(("pooled", runs))
        for label, g in parts:
            rows.append({"simulator": sim, "control_noise": noise, "seed": label, **_score(g, features, seed, rule)})
    return pd.DataFrame(rows)
