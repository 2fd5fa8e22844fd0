"""A bank of costs and a learned choice among them: PIRL-kNN's ``aggregate="selected"``.

A *bank* of ``n`` costs is taken from the per-segment costs of PIRL-kNN with ``target="next"`` (`cost_bank`: the
segment nearest each k-means centre of the log weights). ``selector="errors"``: every bank cost is rolled out
from the start of training windows (`rollout_errors`), one regression per bank cost learns that error from the
window's look-up keys (`ErrorRegression`), and online the bank costs get probabilities
``softmin(predicted error / temperature)`` (`softmin`). ``selector="forecast"``: one regression of the positions
over the next steps on the keys (`FutureRegression`), and online the mixture of the bank's futures nearest to that
forecast (`mixture_weights`: least squares over the probability simplex). Either way the prediction is the MPC
under learned costs; only the choice of costs is learned from predictive error.

The selection is explained in the documentation's "The learners" page.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cost_bank", "rollout_errors", "ErrorRegression", "softmin", "FutureRegression", "mixture_weights"]


def cost_bank(log_theta: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Indices (n',) of up to ``n`` rows of ``log_theta`` (S, K) that span them: for each centre of a k-means
    clustering (``n`` clusters, ``seed``), the row nearest to it; duplicates removed, so n' <= n; every row
    when n >= S. Sorted."""
    from sklearn.cluster import KMeans

    log_theta = np.asarray(log_theta, dtype=float)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"a bank of n={n!r} costs needs a whole number n >= 1")
    if n >= len(log_theta):
        return np.arange(len(log_theta))
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


class FutureRegression:
    """The positions over the next F steps regressed on keys: per step k, a gradient-boosted ensemble
    (`sklearn.ensemble.HistGradientBoostingRegressor`, no early stopping, seed ``random_state``) of the position
    minus a given base (e.g. constant acceleration from the window's end), ``s_k = base_k + g_k(keys)``. PIRL-select's
    forecast and the replay's direct regression (`pirl_sim.evaluation.direct`) are both this.

    ``n_components=n``: one ensemble per principal component of the residuals ``s - base`` instead of one per step
    ("The learners" page, "In detail: learners.selector").

    Attributes
    ----------
    models_ : list of F (or n_components) fitted regressors
    mean_ : array (F,)                 (n_components) the residuals' mean
    components_ : array (n, F)         (n_components) their principal directions, orthonormal rows
    explained_variance_ratio_ : array (n,)   (n_components) the share of the residuals' variance of each
    """

    def __init__(self, max_iter: int = 200, learning_rate: float = 0.05, random_state: int = 0,
                 n_components: int | None = None) -> None:
        self.max_iter, self.learning_rate, self.random_state = int(max_iter), float(learning_rate), int(random_state)
        if n_components is not None and (isinstance(n_components, bool) or not isinstance(n_components, (int, np.integer))
                                         or n_components < 1):
            raise ValueError(f"n_components must be a positive integer or None, got {n_components!r}")
        self.n_components = None if n_components is None else int(n_components)

    def _regressor(self):
        from sklearn.ensemble import HistGradientBoostingRegressor

        return HistGradientBoostingRegressor(max_iter=self.max_iter, learning_rate=self.learning_rate,
                                             early_stopping=False, random_state=self.random_state)

    def fit(self, keys: np.ndarray, base: np.ndarray, truth: np.ndarray) -> FutureRegression:
        """keys (N, d); base and truth (N, F) [m]."""
        y = np.asarray(truth, dtype=float) - np.asarray(base, dtype=float)
        if self.n_components is None or self.n_components >= y.shape[1]:
            self.models_ = [self._regressor().fit(keys, y[:, k]) for k in range(y.shape[1])]
            return self
        self.mean_ = y.mean(axis=0)
        _, sv, vt = np.linalg.svd(y - self.mean_, full_matrices=False)
        n = self.n_components
        self.components_ = vt[:n]
        self.explained_variance_ratio_ = sv[:n] ** 2 / max(float(np.sum(sv**2)), np.finfo(float).tiny)
        scores = (y - self.mean_) @ self.components_.T
        self.models_ = [self._regressor().fit(keys, scores[:, c]) for c in range(n)]
        return self

    def predict(self, keys: np.ndarray, base: np.ndarray) -> np.ndarray:
        """Forecast positions (M, F) [m] for keys (M, d) and the base (M, F) [m]."""
        g = np.stack([m.predict(keys) for m in self.models_], axis=1)
        if getattr(self, "components_", None) is not None:
            g = self.mean_ + g @ self.components_
        return np.asarray(base, dtype=float) + g


def mixture_weights(futures: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Probabilities (M, C), rows summing to 1, of the mixture of ``futures`` (M, C, F) [m] nearest to ``target``
    (M, F) [m] in least squares: ``min_w || sum_c w_c futures[m, c] - target[m] ||`` over ``w >= 0``,
    ``sum w = 1`` (`scipy.optimize.nnls` with the sum as a heavily weighted extra equation, then normalised;
    a row whose solution vanishes gets the single nearest future)."""
    from scipy.optimize import nnls

    futures, target = np.asarray(futures, dtype=float), np.asarray(target, dtype=float)
    M, C, F = futures.shape
    out = np.zeros((M, C))
    for m in range(M):
        diff = futures[m] - target[m]  # (C, F): the mixture's error is sum_c w_c diff_c when sum w = 1
        scale = 1e3 * max(1.0, float(np.abs(diff).max()))
        w, _ = nnls(np.vstack([diff.T, np.full((1, C), scale)]), np.concatenate([np.zeros(F), [scale]]))
        total = w.sum()
        if total > 0:
            out[m] = w / total
        else:
            out[m, np.abs(diff).sum(axis=1).argmin()] = 1.0
    return out
