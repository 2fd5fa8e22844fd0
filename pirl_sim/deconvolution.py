"""Gaussian mixtures of noisy measurements with known per-point covariances ("extreme deconvolution").

Each point i is a noisy measurement ``x_i = v_i + e_i`` of an unseen ``v_i`` drawn from a mixture
``sum_j alpha_j N(m_j, V_j)``, with ``e_i ~ N(0, S_i)`` and S_i known, so ``p(x_i) = sum_j alpha_j
N(x_i | m_j, V_j + S_i)``: per-demonstration weight estimates of very different precision cluster on what they
really tell. Fitted by the EM algorithm of Bovy, Hogg & Roweis (2011, Annals of Applied Statistics 5(2B)), with
optional minimum-message-length pruning of components (``prune=True``, Figueiredo & Jain 2002), or under a
Dirichlet-process prior by truncated stick-breaking variational inference (`dp_deconvolution`; Blei & Jordan
2006, Normal-Wishart priors as Bishop 2006, section 10.2; prior strengths `MEAN_PRECISION_PRIOR`,
`COVARIANCE_PRIOR_SCALE`).

The mixtures in weight space of the learners are explained in the documentation's "The learners" page.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import digamma
from sklearn.cluster import KMeans

__all__ = ["XDMixture", "extreme_deconvolution", "xd_log_prob", "dp_deconvolution"]

_LOG_2PI = float(np.log(2.0 * np.pi))
#: beta_0 of `dp_deconvolution`'s Normal-Wishart prior: mu_j ~ N(m_0, (beta_0 Lambda_j)^-1). scikit-learn's default
#: 1 inflates a component's covariance by beta_0 / N_j times the square of its distance to the points' mean
#: (the Normal-Wishart couples them); 0.01 keeps the prior on the means vague.
MEAN_PRECISION_PRIOR = 0.01
#: the Wishart prior's inverse scale in `dp_deconvolution`, per unit of the points' covariance. scikit-learn uses 1
#: (the points' covariance); deconvolution EM amplifies what a prior adds to a component's covariance by its slow
#: convergence (on three clusters of 120 noisy points, 1 doubled their deconvolved variances); a weaker one lets
#: a few points form a tight component of their own (0.03 and 0.01 split one of those clusters at a truncation
#: of 8), so the prior here is a tenth of it.
COVARIANCE_PRIOR_SCALE = 0.1


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


def _check_fit(X, S, rng, components: tuple[str, Any], n_init, max_iter, reg_covar) -> tuple[np.ndarray, np.ndarray]:
    """The checks every mixture fit here makes of its input (points, rng, counts, regularisation); ``components``
    is (the parameter's name, the number of components asked for, at most the number of points)."""
    X, S = _check_points(X, S)
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    name, n_components = components
    for label, v in ((name, n_components), ("n_init", n_init), ("max_iter", max_iter)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{label} must be a positive integer, got {v!r}")
    if n_components > len(X):
        raise ValueError(f"{name}={n_components} is more than the {len(X)} points")
    if not (np.isfinite(reg_covar) and reg_covar > 0):
        raise ValueError(f"reg_covar must be > 0, got {reg_covar!r}")
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
    X, S : array (N, D), (N, D, D)    noisy points (here: per-demonstration log weights) and their covariances
    n_components : int                J (with ``prune``: the largest number of components)
    rng : numpy.random.Generator      seeds the k-means++ initialisations, one seed per restart
    n_init, max_iter, tol : int, int, float   restarts (highest log-likelihood kept), EM iterations, tolerance [nats]
    reg_covar : float                 added to the diagonal of every component covariance V_j
    prune : bool                      Figueiredo & Jain's minimum-message-length weight update (module doc)

    Returns
    -------
    mixture : XDMixture
    """
    X, S = _check_fit(X, S, rng, ("n_components", n_components), n_init, max_iter, reg_covar)
    N, D = X.shape
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
    return best  # type: ignore[return-value]


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


def _clean(X: np.ndarray, S: np.ndarray) -> np.ndarray:
    """X with the coordinates measured less precisely than the points spread replaced by the median of the
    well-measured values (`_init`'s rule), for initialisations and data-based priors."""
    N, D = X.shape
    X = X.copy()
    var = np.einsum("nii->ni", S)
    for i in range(D):
        vague = var[:, i] > np.var(X[:, i])
        if vague.any() and not vague.all():
            good = X[~vague, i]
            vague = var[:, i] > max(np.var(good), np.finfo(float).tiny)
            X[vague, i] = np.median(X[~vague, i]) if (~vague).any() else np.median(good)
    return X


def dp_deconvolution(
    X: np.ndarray,
    S: np.ndarray,
    max_components: int,
    *,
    rng: np.random.Generator,
    concentration: float | None = None,
    n_init: int = 1,
    max_iter: int = 500,
    tol: float = 1e-5,
    reg_covar: float = 1e-6,
) -> XDMixture:
    """A Dirichlet-process mixture of noisy points by truncated stick-breaking variational inference (module doc).

    Parameters
    ----------
    X, S : array (N, D), (N, D, D)    noisy points (here: per-demonstration log weights) and their covariances
    max_components : int              T, the truncation of the stick-breaking construction (at most N)
    rng : numpy.random.Generator      seeds the k-means++ initialisations, one seed per restart
    concentration : float or None     alpha of the Dirichlet process, > 0; None: 1 / max_components
    n_init, max_iter, tol : int, int, float   restarts (highest evidence lower bound kept), iterations, tolerance
    reg_covar : float                 added to the diagonals of the Wishart scale and every covariance, > 0

    Returns
    -------
    mixture : XDMixture               components with N_j >= 0.5, in stick order; ``log_likelihood``: the ELBO [nats]
    """
    X, S = _check_fit(X, S, rng, ("max_components", max_components), n_init, max_iter, reg_covar)
    N, D = X.shape
    alpha = 1.0 / max_components if concentration is None else concentration
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float, np.integer, np.floating)) \
            or not np.isfinite(alpha) or alpha <= 0:
        raise ValueError(f"concentration (the Dirichlet process's alpha) must be a number > 0 or None, got "
                         f"{concentration!r}")
    S = 0.5 * (S + np.swapaxes(S, 1, 2)) + reg_covar * np.eye(D)[None]
    clean = _clean(X, S)
    spread = np.cov(clean.T).reshape(D, D) if N > 1 else np.eye(D)
    prior = (clean.mean(axis=0), MEAN_PRECISION_PRIOR, float(D),
             COVARIANCE_PRIOR_SCALE * spread + reg_covar * np.eye(D))
    best, best_bound = None, -np.inf
    for _ in range(int(n_init)):
        seed = int(rng.integers(2**31 - 1))
        labels = KMeans(n_clusters=int(max_components), n_init=1, random_state=seed).fit(clean).labels_
        resp = np.zeros((N, int(max_components)))
        resp[np.arange(N), labels] = 1.0
        fit, bound = _dp_vi(X, S, resp, float(alpha), prior, int(max_iter), float(tol))
        if bound > best_bound:
            best, best_bound = fit, bound
    return best  # type: ignore[return-value]


def _dp_vi(X, S, resp, alpha, prior, max_iter, tol):
    """Coordinate ascent from responsibilities ``resp`` (N, T); returns (XDMixture, bound)."""
    N, D = X.shape
    T = resp.shape[1]
    m0, beta0, nu0, cov0 = prior
    W0inv = cov0  # the Wishart's inverse scale, as scikit-learn's covariance_prior: E[Lambda] = nu0 cov0^-1 a priori
    Sinv = np.linalg.inv(S)  # (N, D, D)
    Sinv_x = np.einsum("nab,nb->na", Sinv, X)
    logdet_S = np.linalg.slogdet(S)[1]
    # start: q(v_i | j) = the measurement itself, then the Normal-Wishart posteriors from resp
    b = np.broadcast_to(X[:, None, :], (N, T, D)).copy()
    Bcov = np.broadcast_to(S[:, None], (N, T, D, D)).copy()
    prev = None
    converged = False
    n_iter = 0
    for n_iter in range(1, max_iter + 1):
        # Normal-Wishart posteriors (Bishop 10.60-10.63) from the expected statistics of the v_i
        Nj = resp.sum(axis=0) + 10 * np.finfo(float).eps
        vbar = np.einsum("nj,nja->ja", resp, b) / Nj[:, None]
        d = b - vbar[None]
        scatter = (np.einsum("nj,nja,njb->jab", resp, d, d) + np.einsum("nj,njab->jab", resp, Bcov)) / Nj[:, None, None]
        beta = beta0 + Nj
        m = (beta0 * m0[None] + Nj[:, None] * vbar) / beta[:, None]
        nu = nu0 + Nj
        dm = vbar - m0[None]
        Winv = W0inv[None] + Nj[:, None, None] * scatter + (beta0 * Nj / (beta0 + Nj))[:, None, None] * np.einsum(
            "ja,jb->jab", dm, dm)
        Winv = 0.5 * (Winv + np.swapaxes(Winv, 1, 2))
        W = np.linalg.inv(Winv)
        ELam = nu[:, None, None] * W  # (T, D, D)
        ELog_det = (digamma(0.5 * (nu[:, None] - np.arange(D)[None])).sum(axis=1) + D * np.log(2.0)
                    - np.linalg.slogdet(Winv)[1])
        # sticks
        g1 = 1.0 + Nj
        g2 = alpha + np.concatenate([np.cumsum(Nj[::-1])[::-1][1:], [0.0]])
        e_log_w = digamma(g1) - digamma(g1 + g2)
        e_log_1mw = digamma(g2) - digamma(g1 + g2)
        e_log_pi = e_log_w + np.concatenate([[0.0], np.cumsum(e_log_1mw)[:-1]])
        e_log_pi[-1] = np.concatenate([[0.0], np.cumsum(e_log_1mw)])[-2]  # the last stick: w_T = 1
        # q(v_i | z_i = j)
        P = ELam[None] + Sinv[:, None]  # (N, T, D, D)
        Bcov = np.linalg.inv(P)
        Bcov = 0.5 * (Bcov + np.swapaxes(Bcov, 2, 3))
        b = np.einsum("njab,njb->nja", Bcov, np.einsum("jab,jb->ja", ELam, m)[None] + Sinv_x[:, None])
        # responsibilities
        dv = b - m[None]
        e_quad = D / beta[None] + np.einsum("nja,jab,njb->nj", dv, ELam, dv) + np.einsum("jab,njba->nj", ELam, Bcov)
        dx = X[:, None, :] - b
        e_meas = np.einsum("nja,nab,njb->nj", dx, Sinv, dx) + np.einsum("nab,njba->nj", Sinv, Bcov)
        entropy = 0.5 * np.linalg.slogdet(Bcov)[1] + 0.5 * D * (1.0 + _LOG_2PI)
        log_rho = (e_log_pi[None] + 0.5 * ELog_det[None] - 0.5 * e_quad - 0.5 * (e_meas + logdet_S[:, None])
                   - D * _LOG_2PI + entropy)
        top = log_rho.max(axis=1, keepdims=True)
        resp = np.exp(log_rho - top)
        resp /= resp.sum(axis=1, keepdims=True)
        sizes = resp.sum(axis=0)
        state = np.concatenate([sizes / N, m.ravel(), Winv.ravel() / nu.repeat(D * D)])
        if prev is not None and np.max(np.abs(state - prev)) < tol:
            converged = True
            break
        prev = state
    # the bound's data part: sum_i log sum_j rho_ij (what the responsibilities normalise) minus the KL terms of
    # the sticks and the Normal-Wishart posteriors would complete it; for comparing restarts of one data set the
    # data part and the sticks' KL are used
    bound = float(np.sum(top[:, 0] + np.log(np.sum(np.exp(log_rho - top), axis=1))))
    bound -= float(np.sum(_beta_kl(g1, g2, 1.0, alpha)))
    e_pi = g1 / (g1 + g2) * np.concatenate([[1.0], np.cumprod(g2 / (g1 + g2))[:-1]])
    e_pi[-1] = 1.0 - e_pi[:-1].sum()
    keep = sizes >= 0.5
    weights = np.maximum(e_pi[keep], 0.0)
    cov = np.linalg.inv(ELam[keep])
    fit = XDMixture(weights / weights.sum(), m[keep], 0.5 * (cov + np.swapaxes(cov, 1, 2)), bound, n_iter, converged)
    return fit, bound


def _beta_kl(a, b, a0, b0) -> np.ndarray:
    """KL(Beta(a, b) || Beta(a0, b0)), elementwise."""
    from scipy.special import betaln

    return (betaln(a0, b0) - betaln(a, b) + (a - a0) * digamma(a) + (b - b0) * digamma(b)
            + (a0 - a + b0 - b) * digamma(a + b))
