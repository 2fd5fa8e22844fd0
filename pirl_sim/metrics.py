"""Scores: mean Euclidean distance, ADE/FDE, weight recovery, clustering agreement, and multi-modal scores.

All are pure functions over arrays. Positions are (..., T, P) arrays in metres. Multi-modal scores take K
predicted futures per case, ``futures`` (M, K, T, P), with their probabilities ``proba`` (M, K) where needed,
against the true futures ``truth`` (M, T, P), T the predicted steps only: `min_ade`, `min_fde` and
`interaction_miss` follow the INTERACTION prediction challenge (INTERPRET, single-agent track); `mixture_nll`
[nats] scores the true future under an isotropic Gaussian mixture around the K futures.

Definitions and thresholds are in the documentation's "Protocols and metrics" page.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment
from sklearn.metrics import adjusted_rand_score

__all__ = [
    "euclidean_errors",
    "med",
    "ade_fde",
    "weight_recovery_error",
    "adjusted_rand_index",
    "match_styles",
    "min_ade",
    "min_fde",
    "interaction_longitudinal_threshold",
    "interaction_miss",
    "mixture_nll",
    "INTERACTION_LATERAL_THRESHOLD",
]

INTERACTION_LATERAL_THRESHOLD = 1.0  # [m] the challenge's lateral miss threshold
_LON_SPEEDS = (1.4, 11.0)  # [m/s] the challenge's longitudinal threshold: 1 m below the first, 2 m above the second
_LON_THRESHOLDS = (1.0, 2.0)  # [m]


def euclidean_errors(predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """|p_hat - p| at every step, shape (..., T), for positions (..., T, P) [m]."""
    predicted = np.asarray(predicted, dtype=float)
    truth = np.asarray(truth, dtype=float)
    if predicted.shape != truth.shape:
        raise ValueError(f"predicted positions {predicted.shape} and true positions {truth.shape} differ in shape")
    if predicted.ndim < 2:
        raise ValueError(f"positions must be (..., T, P), got shape {predicted.shape}")
    for name, arr in (("predicted", predicted), ("true", truth)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} positions contain non-finite values")
    return np.linalg.norm(predicted - truth, axis=-1)


def med(predicted: Sequence[np.ndarray] | np.ndarray, truth: Sequence[np.ndarray] | np.ndarray) -> float:
    """Mean Euclidean Distance, the paper's metric: (1/M) sum_i (1/N_i) sum_j |xi_ij - xi_hat_ij| [m].

    Takes equal-length arrays (M, T, P) or sequences of (T_i, P) arrays of different lengths.
    """
    if isinstance(predicted, np.ndarray) and predicted.ndim == 3:
        return float(euclidean_errors(predicted, truth).mean(axis=1).mean())  # type: ignore[arg-type]
    predicted, truth = list(predicted), list(truth)
    if len(predicted) != len(truth) or not predicted:
        raise ValueError(f"need the same non-zero number of predictions and truths, got {len(predicted)} and {len(truth)}")
    return float(np.mean([euclidean_errors(p, t).mean() for p, t in zip(predicted, truth)]))


def ade_fde(predicted: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Average and final displacement errors [m] over positions (M, T, P)."""
    err = euclidean_errors(predicted, truth)
    return float(err.mean()), float(err[..., -1].mean())


def weight_recovery_error(estimated: np.ndarray, true: np.ndarray, reference_index: int) -> np.ndarray:
    """Per-row error of normalised weights: mean over non-reference features of |log(est / true)|.

    Both inputs (M, K) or (K,) are normalised weights (reference feature = 1); the error is scale-free and
    treats over- and under-estimation by the same factor alike. Returns (M,) or a scalar.
    """
    est = np.asarray(estimated, dtype=float)
    tru = np.asarray(true, dtype=float)
    if est.shape != tru.shape:
        raise ValueError(f"estimated {est.shape} and true {tru.shape} weights differ in shape")
    if np.any(est <= 0) or np.any(tru <= 0):
        raise ValueError("weights must be positive to compare on a log scale")
    K = est.shape[-1]
    others = [k for k in range(K) if k != reference_index]
    if not others:
        raise ValueError("a single feature has nothing to recover beyond its scale")
    return np.mean(np.abs(np.log(est[..., others] / tru[..., others])), axis=-1)


def adjusted_rand_index(labels_true: np.ndarray, labels_pred: np.ndarray) -> float:
    """Adjusted Rand index of two labelings (1 = identical partitions, ~0 = chance)."""
    labels_true = np.asarray(labels_true)
    labels_pred = np.asarray(labels_pred)
    if labels_true.shape != labels_pred.shape or labels_true.ndim != 1:
        raise ValueError(f"label arrays must be 1-D and equal in length, got {labels_true.shape} and {labels_pred.shape}")
    return float(adjusted_rand_score(labels_true, labels_pred))


def match_styles(labels_true: np.ndarray, labels_pred: np.ndarray) -> dict[int, int]:
    """Minimum-cost pairing of learned clusters to true styles (Hungarian on the confusion matrix).

    Returns {learned label: true style} for the paired clusters; unpaired learned clusters are left out.
    """
    labels_true = np.asarray(labels_true, dtype=int)
    labels_pred = np.asarray(labels_pred, dtype=int)
    t_vals, t_idx = np.unique(labels_true, return_inverse=True)
    p_vals, p_idx = np.unique(labels_pred, return_inverse=True)
    confusion = np.zeros((len(p_vals), len(t_vals)), dtype=int)
    np.add.at(confusion, (p_idx, t_idx), 1)
    rows, cols = linear_sum_assignment(-confusion)
    return {int(p_vals[r]): int(t_vals[c]) for r, c in zip(rows, cols)}


# ---------------------------------------------------------------------------------------------- multi-modal scores
def _finite(name: str, arr: np.ndarray) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        raise ValueError(f"{name} contain {int(bad.sum())} non-finite values (NaN or inf), e.g. at index "
                         f"{tuple(int(i) for i in np.argwhere(bad)[0])}")


def _check_futures(futures, truth) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``futures`` (M, K, T, P) and ``truth`` (M, T, P) as float arrays (module doc)."""
    futures = np.asarray(futures, dtype=float)
    truth = np.asarray(truth, dtype=float)
    if futures.ndim != 4:
        raise ValueError(f"futures must be (M cases, K futures, T steps, P coordinates), got shape {futures.shape}")
    M, K, T, P = futures.shape
    if K < 1:
        raise ValueError(f"need K >= 1 futures per case, got K={K} (futures of shape {futures.shape})")
    if T < 1 or P < 1:
        raise ValueError(f"futures need T >= 1 steps and P >= 1 coordinates, got shape {futures.shape}")
    if truth.shape != (M, T, P):
        raise ValueError(f"true futures must be (M, T, P) = {(M, T, P)} to match futures {futures.shape}, "
                         f"got shape {truth.shape}")
    _finite("predicted futures", futures)
    _finite("true futures", truth)
    return futures, truth


def _future_errors(futures, truth) -> np.ndarray:
    futures, truth = _check_futures(futures, truth)
    return np.linalg.norm(futures - truth[:, None], axis=-1)  # (M, K, T)


def min_ade(futures: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """minADE_K per case [m], shape (M,): min over the K futures of the mean Euclidean error over the T steps
    (INTERACTION's minADE, module doc). ``futures`` (M, K, T, P), ``truth`` (M, T, P) [m]."""
    return _future_errors(futures, truth).mean(axis=2).min(axis=1)


def min_fde(futures: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """minFDE_K per case [m], shape (M,): min over the K futures of the Euclidean error at the last step
    (INTERACTION's minFDE, module doc). ``futures`` (M, K, T, P), ``truth`` (M, T, P) [m]."""
    return _future_errors(futures, truth)[:, :, -1].min(axis=1)


def interaction_longitudinal_threshold(speed: np.ndarray) -> np.ndarray:
    """The INTERACTION challenge's longitudinal miss threshold [m] at true speeds ``speed`` [m/s] (any shape):
    1 m below 1.4 m/s, 1 + (v - 1.4) / (11 - 1.4) m from 1.4 to 11 m/s, 2 m above 11 m/s (module doc)."""
    v = np.asarray(speed, dtype=float)
    _finite("speeds", v)
    if np.any(v < 0):
        raise ValueError(f"speeds must be >= 0 m/s, got a minimum of {float(v.min())!r}")
    (v0, v1), (d0, d1) = _LON_SPEEDS, _LON_THRESHOLDS
    return np.clip(d0 + (d1 - d0) * (v - v0) / (v1 - v0), d0, d1)


def interaction_miss(futures: np.ndarray, truth: np.ndarray, speed: np.ndarray,
                     heading: np.ndarray | None = None) -> np.ndarray:
    """Missed cases by the INTERACTION challenge's rule (module doc), bool (M,); the miss rate is its mean.

    Parameters
    ----------
    futures : array (M, K, T, P) [m]   predicted positions, P = 2 (x, y) or P = 1 (along a line)
    truth : array (M, T, P) [m]
    speed : array (M,) [m/s]           true speed at the last step T (sets the longitudinal threshold)
    heading : array (M,) [rad] or None  true heading at T, measured from the x axis (required for P = 2;
                                        with P = 1 the whole error is longitudinal)

    A future misses when |lateral error| > 1 m or |longitudinal error| > `interaction_longitudinal_threshold`
    (strictly greater, as the challenge's "larger than"); the case misses when every one of its K futures misses.
    """
    futures, truth = _check_futures(futures, truth)
    M, K, T, P = futures.shape
    speed = np.asarray(speed, dtype=float)
    if speed.shape != (M,):
        raise ValueError(f"speed must be (M,) = ({M},), one true speed per case, got shape {speed.shape}")
    lon_max = interaction_longitudinal_threshold(speed)
    diff = futures[:, :, -1] - truth[:, None, -1]  # (M, K, P)
    if P == 1:
        lon, lat = diff[..., 0], np.zeros_like(diff[..., 0])
    elif P == 2:
        if heading is None:
            raise ValueError("heading (the true heading at the last step, (M,) [rad]) is required for 2-D positions")
        heading = np.asarray(heading, dtype=float)
        if heading.shape != (M,):
            raise ValueError(f"heading must be (M,) = ({M},), one true heading per case, got shape {heading.shape}")
        _finite("headings", heading)
        c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
        lon = c * diff[..., 0] + s * diff[..., 1]
        lat = -s * diff[..., 0] + c * diff[..., 1]
    else:
        raise ValueError(f"the miss rule needs positions with P = 1 or 2 coordinates, got P={P}")
    missed = (np.abs(lat) > INTERACTION_LATERAL_THRESHOLD) | (np.abs(lon) > lon_max[:, None])
    return missed.all(axis=1)


def mixture_nll(futures: np.ndarray, proba: np.ndarray, truth: np.ndarray, sigma: float) -> np.ndarray:
    """Negative log-likelihood [nats] of each true future under the Gaussian mixture around the K futures,
    shape (M,) (module doc): -log sum_k p_k prod_{t,p} N(y_tp; yhat_ktp, sigma^2).

    Parameters
    ----------
    futures : array (M, K, T, P) [m]
    proba : array (M, K)    the futures' probabilities: finite, >= 0, each row sums to 1 (within 1e-6)
    truth : array (M, T, P) [m]
    sigma : float [m]       standard deviation per step and coordinate, > 0

    Divide by T for nats per predicted step.
    """
    from scipy.special import logsumexp

    futures, truth = _check_futures(futures, truth)
    M, K, T, P = futures.shape
    proba = np.asarray(proba, dtype=float)
    if proba.shape != (M, K):
        raise ValueError(f"proba must be (M, K) = {(M, K)} to match futures {futures.shape}, got shape {proba.shape}")
    _finite("probabilities", proba)
    if np.any(proba < 0):
        raise ValueError(f"probabilities must be >= 0, got a minimum of {float(proba.min())!r}")
    sums = proba.sum(axis=1)
    if np.any(np.abs(sums - 1.0) > 1e-6):
        i = int(np.argmax(np.abs(sums - 1.0)))
        raise ValueError(f"each case's probabilities must sum to 1, case {i} sums to {float(sums[i])!r}")
    if isinstance(sigma, bool) or not isinstance(sigma, (int, float, np.integer, np.floating)) \
            or not np.isfinite(sigma) or sigma <= 0:
        raise ValueError(f"sigma must be a finite number of metres > 0, got {sigma!r}")
    sq = np.sum((futures - truth[:, None]) ** 2, axis=(2, 3))  # (M, K)
    log_kernel = -0.5 * sq / sigma**2 - T * P * (np.log(sigma) + 0.5 * np.log(2.0 * np.pi))
    with np.errstate(divide="ignore"):
        log_p = np.log(proba)
    return -logsumexp(log_p + log_kernel, axis=1)
