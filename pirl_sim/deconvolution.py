"""Gaussian mixtures of noisy measurements with known per-point covariances ("extreme deconvolution").

Each point i is a noisy measurement ``x_i = v_i + e_i`` of an unseen ``v_i`` drawn from the mixture
``sum_j alpha_j N(m_j, V_j)``, with ``e_i ~ N(0, S_i)`` and S_i known, so that
``p(x_i) = sum_j alpha_j N(x_i | m_j, V_j + S_i)``. The EM algorithm of Bovy, Hogg & Roweis (2011), "Extreme
deconvolution: inferring complete distribution functions from noisy, heterogeneous and incomplete
observations", Annals of Applied Statistics 5(2B), 1657-1677 (their section 2, equations (8)-(15)), written
here from the paper with numpy:

- E-step: ``T_ij = V_j + S_i``, ``q_ij ∝ alpha_j N(x_i | m_j, T_ij)``, and the posterior of v_i under
  component j, mean ``b_ij = m_j + V_j T_ij^-1 (x_i - m_j)``, covariance ``B_ij = V_j - V_j T_ij^-1 V_j``;
- M-step: ``alpha_j = sum_i q_ij / N``, ``m_j = sum_i q_ij b_ij / q_j``,
  ``V_j = sum_i q_ij [(m_j - b_ij)(m_j - b_ij)^T + B_ij] / q_j + reg_covar I``.

A point with a large S_i pulls its component's mean and covariance little, which is the point: per-demonstration
weight estimates of very different precision cluster on what they really tell.

Pruning (``prune=True``): Figueiredo & Jain's (2002, "Unsupervised learning of finite mixture models", IEEE
TPAMI 24(3)) minimum-message-length search for the number of components. The weights' update becomes their
equation (17), ``alpha_j ∝ max(0, sum_i q_ij - P / 2)`` with P the parameters of one component, which
annihilates components that too few points support; after convergence the least probable component is removed
and EM resumes, down to one component (their outer loop), and the fit with the shortest message length
(their equation (15): minus the log-likelihood plus ``P/2 sum_j log(N alpha_j / 12) + J/2 log(N / 12) +
J (P + 1) / 2``) is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sklearn.cluster import KMeans

__all__ = ["XDMixture", "extreme_deconvolution", "xd_log_prob"]

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class XDMixture:
    """A fitted deconvolved mixture over D dimensions with J components.

    Attributes
    ----------
    weights : array (J,)            mixing proportions alpha_j, summing to 1
    means : array (J, D)
    covariances : array (J, D, D)   of the underlying (noise-free) distribution
    log_likelihood : float          sum_i log p(x_i) at the end [nats]
    n_iter : int
    converged : bool                the log-likelihood changed by less than ``tol`` per point
    """

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    log_likelihood: float
    n_iter: int
    converged: bool

    def __post_init__(self) -> None:
        w = np.asarray(self.weights, dtype=float)
        m = np.asarray(self.means, dtype=float)
        c = np.asarray(self.covariances, dtype=float)
        if w.ndim != 1 or m.ndim != 2 or c.shape != (m.shape[0], m.shape[1], m.shape[1]) or w.shape[0] != m.shape[0]:
            raise ValueError(f"expected weights (J,), means (J, D), covariances (J, D, D); got {w.shape}, {m.shape}, "
                             f"{c.shape}")
        if np.any(w < 0) or not np.isclose(w.sum(), 1.0):
            raise ValueError(f"weights must be >= 0 and sum to 1, got {w}")
        for name, arr in (("weights", w), ("means", m), ("covariances", c)):
            object.__setattr__(self, name, arr)

    @property
    def n_components(self) -> int:
        return self.weights.shape[0]

    def log_prob(self, X: np.ndarray, S: np.ndarray) -> np.ndarray:
        """log alpha_j + log N(x_i | m_j, V_j + S_i), shape (N, J), for points X (N, D), covariances S (N, D, D)."""
        return xd_log_prob(X, S, self.weights, self.means, self.covariances)

    def predict_proba(self, X: np.ndarray, S: np.ndarray) -> np.ndarray:
        """Responsibilities q_ij of each component for noisy points X (N, D) with covariances S (N, D, D)."""
        lp = self.log_prob(X, S)
        lp -= lp.max(axis=1, keepdims=True)
        p = np.exp(lp)
        return p / p.sum(axis=1, keepdims=True)


def _check_points(X, S) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, dtype=float)
    S = np.asarray(S, dtype=float)
    if X.ndim != 2:
        raise ValueError(f"points must have shape (N, D), got {X.shape}")
    N, D = X.shape
    if S.shape != (N, D, D):
        raise ValueError(f"measurement covariances must have shape ({N}, {D}, {D}), got {S.shape}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(S))):
        raise ValueError("points and measurement covariances must be finite")
    return X, S


def xd_log_prob(X, S, weights, means, covariances) -> np.ndarray:
    """log alpha_j + log N(x_i | m_j, V_j + S_i), shape (N, J) (see `XDMixture.log_prob`)."""
    X, S = _check_points(X, S)
    T = covariances[None] + S[:, None]  # (N, J, D, D)
    L = np.linalg.cholesky(T)
    r = X[:, None, :] - means[None]  # (N, J, D)
    z = np.linalg.solve(L, r[..., None])[..., 0]
    logdet = 2.0 * np.sum(np.log(np.einsum("njdd->njd", L)), axis=-1)
    with np.errstate(divide="ignore"):
        logw = np.log(weights)[None]
    return logw - 0.5 * (np.sum(z**2, axis=-1) + logdet + X.shape[1] * _LOG_2PI)


def extreme_deconvolution(
    X: np.ndarray,
    S: np.ndarray,
    n_components: int,
    *,
    rng: np.random.Generator,
    n_init: int = 3,
    max_iter: int = 500,
    tol: float = 1e-7,
    reg_covar: float = 1e-6,
    prune: bool = False,
) -> XDMixture:
    """Fit a deconvolved Gaussian mixture by EM (Bovy, Hogg & Roweis 2011; module doc).

    Parameters
    ----------
    X : array (N, D)
        Noisy points (here: per-demonstration log weights).
    S : array (N, D, D)
        Their measurement covariances (symmetric positive semi-definite).
    n_components : int
        J (with ``prune``: the largest number of components; fewer may survive).
    rng : numpy.random.Generator
        Seeds the initialisations (k-means++ on X, one seed per restart).
    n_init : int
        Restarts; the fit with the highest (penalised, with ``prune``) log-likelihood is kept.
    max_iter : int
        EM iterations per restart.
    tol : float
        Stop when the log-likelihood per point changes by less than this [nats].
    reg_covar : float
        Added to the diagonal of every component covariance V_j (keeps it positive definite).
    prune : bool
        Figueiredo & Jain's minimum-message-length weight update (module doc).

    Returns
    -------
    XDMixture
    """
    X, S = _check_points(X, S)
    N, D = X.shape
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    for name, v in (("n_components", n_components), ("n_init", n_init), ("max_iter", max_iter)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    if n_components > N:
        raise ValueError(f"n_components={n_components} is more than the {N} points")
    if not (np.isfinite(reg_covar) and reg_covar > 0):
        raise ValueError(f"reg_covar must be > 0, got {reg_covar!r}")
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    best, best_score = None, -np.inf
    for _ in range(int(n_init)):
        seed = int(rng.integers(2**31 - 1))
        fit = _em(X, S, _init(X, S, int(n_components), seed, float(reg_covar)), int(max_iter), float(tol),
                  float(reg_covar), prune)
        candidates = [fit]
        while prune and fit.n_components > 1:  # Figueiredo & Jain's outer loop: drop the least probable one
            keep = np.arange(fit.n_components) != int(np.argmin(fit.weights))
            start = (fit.weights[keep] / fit.weights[keep].sum(), fit.means[keep], fit.covariances[keep])
            fit = _em(X, S, start, int(max_iter), float(tol), float(reg_covar), prune)
            candidates.append(fit)
        for cand in candidates:
            score = cand.log_likelihood - (_mml_penalty(cand, N) if prune else 0.0)
            if score > best_score:
                best, best_score = cand, score
    return best


def _mml_penalty(fit: XDMixture, N: int) -> float:
    """Figueiredo & Jain's message-length terms beyond -log-likelihood, for comparing restarts."""
    D = fit.means.shape[1]
    P = D + D * (D + 1) / 2
    J = fit.n_components
    return P / 2 * np.sum(np.log(N * fit.weights / 12.0)) + J / 2 * np.log(N / 12.0) + J * (P + 1) / 2


def _init(X, S, J, seed, reg_covar):
    """Start (weights, means, covariances) from k-means on the noisy points. A coordinate measured less precisely
    than the points spread in it (S_ii above the variance of the well-measured values) says nothing about where
    a centre is: k-means sees the median of the well-measured values there instead."""
    N, D = X.shape
    X = X.copy()
    var = np.einsum("nii->ni", S)
    for i in range(D):
        vague = var[:, i] > np.var(X[:, i])
        if vague.any() and not vague.all():
            good = X[~vague, i]
            vague = var[:, i] > max(np.var(good), np.finfo(float).tiny)
            X[vague, i] = np.median(X[~vague, i]) if (~vague).any() else np.median(good)
    km = KMeans(n_clusters=J, n_init=1, random_state=seed).fit(X)
    means = km.cluster_centers_.copy()
    labels = km.labels_
    spread = np.cov(X.T).reshape(D, D) if N > 1 else np.eye(D)
    spread = spread + reg_covar * np.eye(D)
    cov = np.empty((J, D, D))
    weights = np.empty(J)
    for j in range(J):
        mine = labels == j
        weights[j] = max(mine.sum(), 1) / N
        cov[j] = np.cov(X[mine].T).reshape(D, D) + reg_covar * np.eye(D) if mine.sum() > D else spread
    return weights / weights.sum(), means, cov


def _em(X, S, start, max_iter, tol, reg_covar, prune) -> XDMixture:
    N, D = X.shape
    weights, means, cov = (np.array(a, dtype=float) for a in start)
    P = D + D * (D + 1) / 2
    eye = np.eye(D)
    prev = -np.inf
    converged = False
    n_iter = 0
    for n_iter in range(1, max_iter + 1):
        # E-step
        T = cov[None] + S[:, None]  # (N, J, D, D)
        Tinv = np.linalg.inv(T)
        r = X[:, None, :] - means[None]
        with np.errstate(divide="ignore"):
            lp = (np.log(weights)[None] - 0.5 * (np.einsum("nja,njab,njb->nj", r, Tinv, r)
                                                 + np.linalg.slogdet(T)[1] + D * _LOG_2PI))
        top = lp.max(axis=1, keepdims=True)
        ll = float(np.sum(top[:, 0] + np.log(np.sum(np.exp(lp - top), axis=1))))
        q = np.exp(lp - top)
        q /= q.sum(axis=1, keepdims=True)
        VTinv = cov[None] @ Tinv  # (N, J, D, D)
        b = means[None] + np.einsum("njab,njb->nja", VTinv, r)
        B = cov[None] - VTinv @ cov[None]
        # M-step
        qj = q.sum(axis=0)
        if prune:
            weights = np.maximum(qj - P / 2.0, 0.0)
            if not np.any(weights > 0):  # every component under-supported: keep the best one
                weights = (qj == qj.max()).astype(float)
        else:
            weights = qj.copy()
        keep = weights > 0
        if not keep.all():  # annihilated components leave
            q, qj, b, B, weights = q[:, keep], qj[keep], b[:, keep], B[:, keep], weights[keep]
            q /= q.sum(axis=1, keepdims=True)
            qj = q.sum(axis=0)
            prev = -np.inf
        weights = weights / weights.sum()
        safe = np.maximum(qj, 1e-300)
        means = np.einsum("nj,nja->ja", q, b) / safe[:, None]
        d = means[None] - b
        cov = (np.einsum("nj,nja,njb->jab", q, d, d) + np.einsum("nj,njab->jab", q, B)) / safe[:, None, None]
        cov = 0.5 * (cov + np.swapaxes(cov, 1, 2)) + reg_covar * eye
        if np.isfinite(prev) and abs(ll - prev) < tol * N:
            converged = True
            break
        prev = ll
    lp = xd_log_prob(X, S, weights, means, cov)
    top = lp.max(axis=1, keepdims=True)
    ll = float(np.sum(top[:, 0] + np.log(np.sum(np.exp(lp - top), axis=1))))
    return XDMixture(weights, means, cov, ll, n_iter, converged)
