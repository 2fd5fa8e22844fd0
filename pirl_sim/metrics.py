"""Scores: mean Euclidean distance, ADE/FDE, weight recovery, clustering agreement.

All are pure functions over arrays. Positions are (..., T, P) arrays in metres.
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
]


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
        return float(euclidean_errors(predicted, truth).mean(axis=1).mean())
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
