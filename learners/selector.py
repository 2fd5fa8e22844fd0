"""A bank of costs and a learned choice among them: PIRL-kNN's ``aggregate="selected"`` (issue 12).

PIRL-kNN with ``target="next"`` fits one cost to what followed every training window and, online, averages the
futures of the costs whose histories look most like the query's. On the development roundabouts the cost
family can represent the next seconds (the cost fitted on each test window's own future predicts far better
than constant acceleration), but the nearest histories' costs rolled out from the query's state often do not:
which cost predicts a situation well is not the same as which histories are near in the look-up space.

The selection learns that directly. A *bank* of ``n`` costs is taken from the per-segment costs (`cost_bank`:
the segment nearest each k-means centre of the log weights, so the bank spans the fitted costs); every bank
cost is rolled out from the start of each of a set of training windows and scored against what the driver did
(`rollout_errors`); one regression per bank cost learns that error from the window's look-up keys
(`ErrorRegression`); online, the bank costs get probabilities ``softmin(predicted error / temperature)``
(`softmin`), a posterior over costs whose futures are averaged (or drawn) like the neighbours' futures.
The prediction is still the MPC under learned costs; only the choice of cost is learned from predictive error.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cost_bank", "rollout_errors", "ErrorRegression", "softmin"]


def cost_bank(log_theta: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Indices (n',) of up to ``n`` rows of ``log_theta`` (S, K) that span them: for each centre of a k-means
    clustering (``n`` clusters, ``seed``), the row nearest to it; duplicates removed, so n' <= n. Sorted."""
    from sklearn.cluster import KMeans

    log_theta = np.asarray(log_theta, dtype=float)
    if not 1 <= n <= len(log_theta):
        raise ValueError(f"a bank of n={n!r} costs needs 1 <= n <= {len(log_theta)} (the costs fitted)")
    centres = KMeans(n_clusters=int(n), n_init=4, random_state=seed).fit(log_theta).cluster_centers_
    dist = ((log_theta[:, None, :] - centres[None]) ** 2).sum(axis=-1)  # (S, n)
    return np.unique(dist.argmin(axis=0))


def rollout_errors(model, x0: np.ndarray, theta: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Mean |error| [m] (M, C) along the path over the steps of ``truth`` (M, F) [m] of the MPC's prediction
    from each start ``x0`` (M, n_x) under each cost ``theta`` (C, K)."""
    M, C, F = len(x0), len(theta), truth.shape[1]
    states = model.predict_states(np.repeat(x0, C, axis=0), np.tile(theta, (M, 1)), F)
    s = states[:, 1:, 0].reshape(M, C, F)
    return np.abs(s - truth[:, None, :]).mean(axis=-1)


class ErrorRegression:
    """One gradient-boosted regression per bank cost of its rollout error on the look-up keys
    (`sklearn.ensemble.HistGradientBoostingRegressor`, ``max_iter`` iterations, no early stopping, seed 0:
    same data, same bytes).

    Attributes
    ----------
    models_ : list of C fitted regressors
    """

    def __init__(self, max_iter: int = 100) -> None:
        self.max_iter = int(max_iter)

    def fit(self, keys: np.ndarray, errors: np.ndarray) -> ErrorRegression:
        """keys (N, d), errors (N, C) [m]."""
        from sklearn.ensemble import HistGradientBoostingRegressor

        self.models_ = [HistGradientBoostingRegressor(max_iter=self.max_iter, early_stopping=False, random_state=0)
                        .fit(keys, errors[:, c]) for c in range(errors.shape[1])]
        return self

    def predict(self, keys: np.ndarray) -> np.ndarray:
        """Predicted errors (M, C) [m] of the bank costs for keys (M, d)."""
        return np.stack([m.predict(keys) for m in self.models_], axis=1)


def softmin(errors: np.ndarray, temperature: float) -> np.ndarray:
    """Probabilities (M, C), rows summing to 1, ``exp(-(e - min e) / temperature)`` normalised; ``temperature``
    [m] > 0 (smaller: nearer the single best predicted cost)."""
    z = -(errors - errors.min(axis=1, keepdims=True)) / float(temperature)
    w = np.exp(z)
    return w / w.sum(axis=1, keepdims=True)
