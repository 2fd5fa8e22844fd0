"""Continuous-domain maximum-entropy IRL with a Laplace approximation (Levine & Koltun, ICML 2012).

A demonstration with stacked controls U is one open-loop optimum of its linear cost C = theta . f(U), up to
Boltzmann noise; its Laplace log-likelihood is ``-1/2 g^T H^-1 g + 1/2 log|H| - d/2 log(2 pi)`` with g, H the
gradient and Hessian of C in U. `fit_weights` maximises it over groups of demonstrations tied by integer
``labels`` (one group per demonstration, one for all, or one per cluster) in one batched, damped Newton iteration
in the coordinates ``w = (log beta, log(theta_k / theta_ref))``, bounded by ``log_bounds``; weights are reported
normalised (reference weight 1). ``hessian="auto"`` (the default) refits with the Gauss-Newton cost Hessian the
groups whose exact Hessian needed a regularisation (`HessianRegularizationWarning`) or did not converge;
`IRLResult` holds the weights, the convergence flags and the final projected gradient.

The likelihood, its identifiability, the Hessian regularisation and the convergence rules are explained in the
documentation's "The two likelihoods" page.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from .dynamics import LinearDynamics
from .features import FeatureDerivatives, FeatureSet
from .trajectory import Trajectory, stack_trajectories

__all__ = [
    "HessianRegularizationWarning",
    "IRLConvergenceWarning",
    "LogNormalPrior",
    "IRLResult",
    "LaplaceBlock",
    "laplace_nll",
    "fit_weights",
    "attach_gauss_newton",
    "HESSIANS",
]

LOG_2PI = float(np.log(2.0 * np.pi))
_START_BOX = 9.0  # initial log-weights are kept within +-9 (factor 8,000) of 1
_MAX_RESTARTS = 3
_TRAP_LOG = -6.0  # a normalised weight below e^-6 = 0.0025 whose likelihood still wants it larger is restarted
_RESTART_VALUES = (-4.0, -2.0, 0.0, 2.0)
_GTOL = 1e-6  # projected gradient in w per demonstration below which a Gauss-Newton fit stops iterating
# A group whose line search stalled counts as converged below this projected gradient per demonstration (a 1 %
# change of a weight then changes its negative log-likelihood by < 1e-5 per demonstration; measured: the paper's
# passage reproduction has 2 of 500 per-demo fits stalled at 2e-4 and 4.5e-4, at the resolution of their
# objective, and none between 1e-9 and 2e-4).
_GTOL_STALLED = 1e-3
#: How `fit_weights` forms the cost Hessian in the likelihood (module doc).
HESSIANS = ("exact", "gauss_newton", "auto")


class HessianRegularizationWarning(UserWarning):
    """A demonstration's cost Hessian was not positive definite and was shifted."""


class IRLConvergenceWarning(UserWarning):
    """The batched Newton iteration stopped before meeting its tolerance for some groups."""


@dataclass(frozen=True)
class LogNormalPrior:
    """Independent Gaussian prior on the optimisation coordinates w (see module doc), for MAP estimation.

    Parameters
    ----------
    mean, std : array, shape (K,)
        Entry ``ref`` is for log beta (the scale), the others for log of the normalised weights.
    """

    mean: np.ndarray
    std: np.ndarray

    def __post_init__(self) -> None:
        mean = np.atleast_1d(np.asarray(self.mean, dtype=float))
        std = np.atleast_1d(np.asarray(self.std, dtype=float))
        if mean.shape != std.shape or mean.ndim != 1:
            raise ValueError(f"prior mean and std must be 1-D of equal length, got {mean.shape} and {std.shape}")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(std))):
            raise ValueError(f"prior mean and std must be finite, got {mean} and {std}")
        if np.any(std <= 0):
            raise ValueError(f"prior std must be > 0, got {std}")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)


# ---------------------------------------------------------------------------------------------- kernels
@dataclass(frozen=True)
class LaplaceBlock:
    """Derivatives of a batch of equal-length demonstrations, prepared for fast likelihood evaluation.

    When every feature Hessian is shared by the batch and the pencil of Hessians is simultaneously
    diagonalisable by one congruence (always so for two features), the block is stored in that eigenbasis:
    ``V^T H_k V = diag(lam_k)``. Every likelihood evaluation is then O(M K d) instead of O(M K d^3).

    Attributes
    ----------
    grad : array, shape (M, K, d)   gradients (in the eigenbasis when ``diagonal``)
    hess : array, shape (M' , K, d, d) or None
    lam : array, shape (K, d) or None  eigen-spectra when ``diagonal``
    log_det_v : float  log|det V| (the likelihood's constant from the change of basis)
    """

    grad: np.ndarray
    hess: np.ndarray | None
    lam: np.ndarray | None
    log_det_v: float = 0.0
    gauss_newton_block: "LaplaceBlock | None" = None

    @property
    def diagonal(self) -> bool:
        return self.lam is not None

    def gauss_newton(self) -> "LaplaceBlock":
        """The same demonstrations with Gauss-Newton Hessians, when attached (`attach_gauss_newton`); else
        the block itself (quadratic features: the two are equal)."""
        return self.gauss_newton_block if self.gauss_newton_block is not None else self

    @property
    def n_demos(self) -> int:
        return self.grad.shape[0]

    @property
    def dim(self) -> int:
        return self.grad.shape[2]

    def subset(self, mask: np.ndarray) -> "LaplaceBlock":
        """The block restricted to the demonstrations where ``mask`` (M,) is True."""
        hess = self.hess
        if hess is not None and hess.shape[0] > 1:
            hess = hess[mask]
        gn = self.gauss_newton_block.subset(mask) if self.gauss_newton_block is not None else None
        return LaplaceBlock(self.grad[mask], hess, self.lam, self.log_det_v, gn)

    @classmethod
    def from_derivatives(cls, der: FeatureDerivatives, reference_index: int, *, rtol: float = 1e-9) -> "LaplaceBlock":
        grad, hess = der.grad, der.hess
        if der.shared_hessian or (grad.shape[0] == 1 and hess.shape[0] == 1):
            H = hess[0]
            K = H.shape[0]
            H_ref = H[reference_index]
            others = [k for k in range(K) if k != reference_index]
            try:
                if others:
                    _, V = scipy.linalg.eigh(H[others[0]], H_ref)
                else:
                    _, V = scipy.linalg.eigh(H_ref, np.eye(H_ref.shape[0]))
            except np.linalg.LinAlgError:
                return cls(grad, hess, None)
            D = np.einsum("ia,kij,jb->kab", V, H, V, optimize=True)
            diag = np.einsum("kaa->ka", D)
            off = D - np.einsum("ka,ab->kab", diag, np.eye(D.shape[1]))
            scale = np.max(np.abs(diag), axis=1, keepdims=True) + 1e-300
            if np.all(np.abs(off) <= rtol * scale[:, :, None] * 10 * D.shape[1]):
                ghat = np.einsum("ia,mki->mka", V, grad)
                _, logabsdet = np.linalg.slogdet(V)
                return cls(ghat, None, diag, float(logabsdet))
        return cls(grad, hess, None)


def _cholesky_rows(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched Cholesky that tolerates failures: factors (M, d, d) and a mask of rows that are not PD.

    numpy factors a whole stack or raises; after a failure each matrix is factored by LAPACK's ``potrf``,
    which reports instead of raising, so only the failing rows need an eigen-decomposition.
    """
    try:
        return np.linalg.cholesky(H), np.zeros(H.shape[0], dtype=bool)
    except np.linalg.LinAlgError:
        pass
    L = np.zeros_like(H)
    bad = np.zeros(H.shape[0], dtype=bool)
    for m in range(H.shape[0]):
        c, info = scipy.linalg.lapack.dpotrf(H[m], lower=1, clean=1)
        if info == 0:
            L[m] = c
        else:
            bad[m] = True
    return L, bad


def shift_to_pd(H: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray, int, float]:
    """Cholesky of H (M, d, d); matrices that are not positive definite get the smallest diagonal shift
    (-lambda_min + eps * mean |diag|) that makes them so.

    Returns
    -------
    L : (M, d, d) factors, H : the (shifted) matrices, n_shifted : int, worst : most negative eigenvalue
    """
    L, H, bad, worst = _shift_to_pd_rows(H, eps)
    return L, H, int(bad.sum()), worst


def _shift_to_pd_rows(H: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """`shift_to_pd` with the mask (M,) of the shifted matrices instead of their count."""
    L, bad = _cholesky_rows(H)
    if not bad.any():
        return L, H, bad, np.inf
    Hb = H[bad]
    eig_min = np.linalg.eigvalsh(Hb)[:, 0]
    scale = np.abs(np.einsum("mii->m", Hb)) / H.shape[1] + np.finfo(float).tiny
    shift = np.maximum(-eig_min, 0.0) + eps * scale
    H = H.copy()
    H[bad] = Hb + shift[:, None, None] * np.eye(H.shape[1])
    L[bad] = np.linalg.cholesky(H[bad])
    return L, H, bad, float(eig_min.min())


def laplace_nll(theta: np.ndarray, block: LaplaceBlock, order: int = 1, eps: float = 1e-9):
    """Negative Laplace log-likelihood of each demonstration and its derivatives in theta.

    Parameters
    ----------
    theta : array (M, K)     absolute weights (scale included), one row per demonstration; > 0 for features whose
                             Hessians are only positive semi-definite
    block : LaplaceBlock
    order : {0, 1, 2}        0: values only; 1: and gradients; 2: and Hessians

    Returns
    -------
    nll, grad, hess : array (M,), (M, K) or None, (M, K, K) or None
    n_regularized, worst_eig : int, float   demonstrations whose Hessian needed a shift; most negative eigenvalue
    """
    nll, grad, hess, bad, worst = _laplace_nll(theta, block, order, eps)
    return nll, grad, hess, int(bad.sum()), worst


def _laplace_nll(theta: np.ndarray, block: LaplaceBlock, order: int = 1, eps: float = 1e-9):
    """`laplace_nll` with the mask (M,) of regularised demonstrations in place of their count.

    From `_BLAS_MIN_DIM` steps up the sums over the features and the d x d entries are matrix products (BLAS)
    rather than einsums, and L^-1 g a triangular solve (LAPACK ``dtrtrs``) rather than a general one: the same
    numbers, to rounding (`_laplace_nll_einsum` below, the original form)."""
    theta = np.asarray(theta, dtype=float)
    d = block.dim
    if block.diagonal:
        return _diag_nll(theta, block, order, eps)
    if d < _BLAS_MIN_DIM:
        return _laplace_nll_einsum(theta, block, order, eps)
    M, K = theta.shape
    hess = block.hess
    shared = hess.shape[0] == 1  # type: ignore[union-attr]  # one set of Hessians for every demonstration of the block
    hflat = hess.reshape(hess.shape[0], K, d * d)  # type: ignore[union-attr]
    G = np.einsum("mk,mkd->md", theta, block.grad)
    H = (theta @ hflat[0] if shared else (theta[:, None, :] @ hflat)[:, 0]).reshape(M, d, d)
    L, H, bad, worst = _shift_to_pd_rows(H, eps)
    logdet = 2.0 * np.sum(np.log(np.einsum("mii->mi", L)), axis=1)
    y = _tri_solve_rows(L, G)  # L^-1 g
    nll = 0.5 * np.sum(y**2, axis=1) - 0.5 * logdet + 0.5 * d * LOG_2PI
    if order == 0:
        return nll, None, None, bad, worst
    Hinv = np.linalg.inv(H)
    h = (Hinv @ G[:, :, None])[..., 0]  # H^-1 g
    if shared:
        Hk_h = (h @ hflat[0].reshape(K * d, d).T).reshape(M, K, d)  # H_k h (H_k symmetric)
        trace = Hinv.reshape(M, d * d) @ hflat[0].T  # tr(H^-1 H_k)
    else:
        Hk_h = (hess.reshape(M, K * d, d) @ h[:, :, None]).reshape(M, K, d)  # type: ignore[union-attr]
        trace = (hflat @ Hinv.reshape(M, d * d, 1))[..., 0]
    grad = (block.grad @ h[:, :, None])[..., 0] - 0.5 * (Hk_h @ h[:, :, None])[..., 0] - 0.5 * trace
    if order == 1:
        return nll, grad, None, bad, worst
    E = block.grad - Hk_h
    term1 = (E @ Hinv) @ np.swapaxes(E, 1, 2)
    hess_b = np.broadcast_to(hess, (M,) + hess.shape[1:]) if shared else hess  # type: ignore[arg-type, union-attr]
    B = Hinv[:, None] @ hess_b  # H^-1 H_k
    Bt = np.swapaxes(B, 2, 3).reshape(M, K, d * d)
    term2 = 0.5 * (B.reshape(M, K, d * d) @ np.swapaxes(Bt, 1, 2))  # tr(H^-1 H_k H^-1 H_l) / 2
    return nll, grad, term1 + term2, bad, worst


#: `_laplace_nll` takes the matrix-product form from this many steps (d) up; below it, for many short
#: demonstrations (e.g. 16,000 next-steps segments of 15 steps), the einsum form costs less (measured with
#: Hessians: 1.8 vs 2.5 s for 16,000 demonstrations of 15 steps; 5.0 vs 3.0 ms for 8 of 40 steps; values alone:
#: 5.4 vs 2.2 ms for 8 of 100 steps)
_BLAS_MIN_DIM = 24


def _laplace_nll_einsum(theta: np.ndarray, block: LaplaceBlock, order: int = 1, eps: float = 1e-9):
    """`_laplace_nll` of a block of short demonstrations (d < `_BLAS_MIN_DIM`): einsums and batched solves."""
    d = block.dim
    G = np.einsum("mk,mkd->md", theta, block.grad)
    H = np.einsum("mk,mkij->mij", theta, block.hess)  # type: ignore[arg-type]
    L, H, bad, worst = _shift_to_pd_rows(H, eps)
    logdet = 2.0 * np.sum(np.log(np.einsum("mii->mi", L)), axis=1)
    y = np.linalg.solve(L, G[..., None])[..., 0]
    nll = 0.5 * np.sum(y**2, axis=1) - 0.5 * logdet + 0.5 * d * LOG_2PI
    if order == 0:
        return nll, None, None, bad, worst
    Hinv = np.linalg.inv(H)
    h = np.einsum("mij,mj->mi", Hinv, G)
    hess_b = (np.broadcast_to(block.hess,  # type: ignore[arg-type]
                              (G.shape[0],) + block.hess.shape[1:])  # type: ignore[union-attr]
              if block.hess.shape[0] == 1 else block.hess)  # type: ignore[union-attr]
    Hk_h = np.einsum("mkij,mj->mki", hess_b, h)  # type: ignore[arg-type]
    grad = (
        np.einsum("mki,mi->mk", block.grad, h)
        - 0.5 * np.einsum("mki,mi->mk", Hk_h, h)
        - 0.5 * np.einsum("mij,mkij->mk", Hinv, hess_b)  # type: ignore[arg-type]
    )
    if order == 1:
        return nll, grad, None, bad, worst
    E = block.grad - Hk_h
    term1 = np.einsum("mki,mij,mlj->mkl", E, Hinv, E, optimize=True)
    B = Hinv[:, None] @ hess_b
    term2 = 0.5 * np.einsum("mkij,mlji->mkl", B, B)
    return nll, grad, term1 + term2, bad, worst


def _tri_solve_rows(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solutions (M, d) of L_m y = b_m for lower triangular L (M, d, d), one LAPACK ``dtrtrs`` each (a batched
    LU solve, which does not see the triangle, costs several times more)."""
    trtrs = scipy.linalg.lapack.dtrtrs
    out = np.empty(b.shape)
    for m in range(b.shape[0]):
        out[m] = trtrs(L[m], b[m], lower=1)[0]
    return out


def _diag_nll(theta, block, order, eps):
    lam = block.lam  # (K, d)
    D = theta @ lam  # (M, d)
    worst = np.inf
    dmin = D.min(axis=1)
    scale = np.abs(D).max(axis=1) + np.finfo(float).tiny
    bad = dmin <= eps * scale
    if np.any(bad):
        worst = float(dmin[bad].min())
        D = D + np.where(bad, -dmin + eps * scale, 0.0)[:, None]
    G = np.einsum("mk,mkd->md", theta, block.grad)
    h = G / D
    d = block.dim
    nll = 0.5 * np.sum(G * h, axis=1) - 0.5 * np.sum(np.log(D), axis=1) + block.log_det_v + 0.5 * d * LOG_2PI
    if order == 0:
        return nll, None, None, bad, worst
    grad = (
        np.einsum("mkd,md->mk", block.grad, h)
        - 0.5 * np.einsum("kd,md->mk", lam, h**2)
        - 0.5 * np.einsum("kd,md->mk", lam, 1.0 / D)
    )
    if order == 1:
        return nll, grad, None, bad, worst
    E = block.grad - lam[None] * h[:, None, :]
    hess = np.einsum("mkd,mld,md->mkl", E, E, 1.0 / D, optimize=True) + 0.5 * np.einsum("kd,ld,md->mkl", lam, lam, 1.0 / D**2)
    return nll, grad, hess, bad, worst


# ---------------------------------------------------------------------------------------------- fitting
@dataclass(frozen=True)
class IRLResult:
    """Weights fitted per group.

    Attributes
    ----------
    theta : array (G, K)        absolute weights, beta * normalised
    normalized : array (G, K)   weights divided by the reference feature's weight (the reported form)
    beta : array (G,)           scale (the reference weight)
    neg_log_likelihood : array (G,)  summed over the group's demonstrations (prior excluded)
    at_bound : array (G, K) bool     coordinate w at its bound at the end
    converged : array (G,) bool      see the module doc
    n_iter, n_regularized : int      iterations; demonstrations whose Hessian needed a shift at the solution
    gauss_newton : array (G,) bool   groups fitted with Gauss-Newton Hessians; None: not recorded
    gradient_norm : array (G,)       largest |projected gradient| in w at the end; None: not recorded
    """

    theta: np.ndarray
    normalized: np.ndarray
    beta: np.ndarray
    neg_log_likelihood: np.ndarray
    at_bound: np.ndarray
    converged: np.ndarray
    n_iter: int
    n_regularized: int
    gauss_newton: np.ndarray | None = None
    gradient_norm: np.ndarray | None = None


def _param_map(K: int, ref: int) -> np.ndarray:
    """P with log theta = P w: log theta_ref = w_ref, log theta_k = w_ref + w_k."""
    P = np.eye(K)
    P[:, ref] = 1.0
    return P


def attach_gauss_newton(
    blocks: Sequence[tuple[LaplaceBlock, np.ndarray]],
    features: FeatureSet,
    dynamics: LinearDynamics,
    trajectories: Sequence[Trajectory],
) -> list[tuple[LaplaceBlock, np.ndarray]]:
    """Laplace blocks (as `pirl_sim.model.DriverModel.laplace_blocks` returns them: block and the indices of its
    trajectories) with their Gauss-Newton Hessians attached, for ``fit_weights(hessian="auto" | "gauss_newton")``.

    Quadratic feature sets are returned unchanged (their Hessians have no second-derivative term).
    """
    blocks = list(blocks)
    if features.quadratic:
        return blocks
    out = []
    for block, idx in blocks:
        states, controls, _ = stack_trajectories([trajectories[i] for i in idx])
        der = features.derivatives(dynamics, states, controls, gauss_newton=True)
        gn = LaplaceBlock.from_derivatives(der, features.reference_index)
        out.append((replace(block, gauss_newton_block=gn), idx))
    return out


#: the Gauss-Newton refit of ``hessian="auto"`` may take this many times ``max_iter`` iterations
GAUSS_NEWTON_ITER_FACTOR = 5


def fit_weights(
    blocks: Sequence[LaplaceBlock] | LaplaceBlock,
    labels: Sequence[np.ndarray] | np.ndarray | None,
    features: FeatureSet,
    *,
    n_groups: int | None = None,
    prior: LogNormalPrior | None = None,
    log_bounds: tuple[float, float] = (-20.0, 20.0),
    max_iter: int = 100,
    tol: float = 1e-7,
    hessian: str = "auto",
) -> IRLResult:
    """Maximum-likelihood (or MAP) weights, one vector per group of demonstrations, by batched damped Newton.

    Parameters
    ----------
    blocks, features : LaplaceBlock or sequence, FeatureSet   demonstrations by length; the reference feature
    labels, n_groups : int arrays (M_b,) or None, int   group of each, 0..G-1 (None: one each); G (default max + 1)
    prior : LogNormalPrior, optional            MAP: adds 1/2 sum ((w - mean) / std)^2 per group
    log_bounds : (low, high)                    box on every coordinate w (log beta and log normalised weights)
    max_iter, tol : int, float                  Newton iterations, and tolerance on the step in w
    hessian : {"auto", "exact", "gauss_newton"}   the cost Hessian in the likelihood (module doc)

    Returns
    -------
    result : IRLResult
    """
    if isinstance(blocks, LaplaceBlock):
        blocks = [blocks]
    blocks = list(blocks)
    if labels is None:
        if len(blocks) != 1:
            raise ValueError("labels=None (one group per demonstration) needs a single block")
        labels = [np.arange(blocks[0].n_demos)]
    elif isinstance(labels, np.ndarray) and labels.ndim == 1 and len(blocks) == 1:
        labels = [labels]
    labels = [np.asarray(lab, dtype=int) for lab in labels]
    if len(labels) != len(blocks):
        raise ValueError(f"need one label array per block: {len(labels)} label arrays for {len(blocks)} blocks")
    for b, lab in zip(blocks, labels):
        if lab.shape != (b.n_demos,):
            raise ValueError(f"labels of shape {lab.shape} do not match a block of {b.n_demos} demonstrations")
        if lab.size and lab.min() < 0:
            raise ValueError(f"labels must be >= 0, got {lab.min()}")
    if hessian not in HESSIANS:
        raise ValueError(f"hessian must be one of {HESSIANS}, got {hessian!r}")
    G = int(n_groups if n_groups is not None else max(int(lab.max()) + 1 for lab in labels if lab.size))
    K = features.n_features
    ref = features.reference_index
    low, high = float(log_bounds[0]), float(log_bounds[1])
    if not low < high:
        raise ValueError(f"log_bounds must be (low, high) with low < high, got {log_bounds}")
    if prior is not None and prior.mean.shape != (K,):
        raise ValueError(f"prior has {prior.mean.shape[0]} entries, features have {K}")
    settings = dict(features=features, prior=prior, low=low, high=high, max_iter=max_iter, tol=tol)

    n_demos = np.zeros(G)
    for lab in labels:
        np.add.at(n_demos, lab, 1.0)
    if hessian == "gauss_newton":
        fit = _newton([b.gauss_newton() for b in blocks], labels, G, n_demos, gauss_newton=True, **settings)
        gauss_newton = np.ones(G, dtype=bool)
    else:
        fit = _newton(blocks, labels, G, n_demos, gauss_newton=False, **settings)
        gauss_newton = np.zeros(G, dtype=bool)
    if hessian == "auto":
        has_gn = np.zeros(G, dtype=bool)
        for b, lab in zip(blocks, labels):
            if b.gauss_newton_block is not None:
                has_gn[lab] = True
        redo = has_gn & ((fit["reg"] > 0) | ~fit["converged"])
        if redo.any():
            new_label = np.full(G, -1)
            new_label[redo] = np.arange(int(redo.sum()))
            sub_blocks, sub_labels = [], []
            for b, lab in zip(blocks, labels):
                sel = redo[lab]
                if sel.any():
                    sub_blocks.append(b.gauss_newton() if sel.all() else b.subset(sel).gauss_newton())
                    sub_labels.append(new_label[lab[sel]])
            # the Gauss-Newton refit gets a longer budget: along the flat directions of nearly collinear
            # features (speed_sq / speed_hi of the speed-level set) damped Newton needs a few hundred steps
            sub = _newton(sub_blocks, sub_labels, int(redo.sum()), n_demos[redo], gauss_newton=True,
                          **dict(settings, max_iter=GAUSS_NEWTON_ITER_FACTOR * max_iter))
            for key in ("w", "f", "gw", "converged", "reg", "grad_norm"):
                fit[key][redo] = sub[key]
            fit["n_iter"] += sub["n_iter"]
            gauss_newton = redo
    w, f, converged, grad_norm = fit["w"], fit["f"], fit["converged"], fit["grad_norm"]
    if not np.all(converged):
        warnings.warn(
            f"IRL Newton iteration did not converge for {int((~converged).sum())} of {G} groups within "
            f"{max_iter} iterations (largest |gradient| {float(np.max(grad_norm[~converged])):.3g})",
            IRLConvergenceWarning,
            stacklevel=2,
        )
    n_reg = int(fit["reg"].sum())
    if n_reg:
        warnings.warn(
            f"{n_reg} demonstrations had a cost Hessian that was not positive definite at the fitted "
            f"weights (most negative eigenvalue {fit['worst']:.3g}); they were regularised by a diagonal shift",
            HessianRegularizationWarning,
            stacklevel=2,
        )
    theta = np.exp(w @ _param_map(K, ref).T)
    at_bound = (w <= low + 1e-9) | (w >= high - 1e-9)
    f_data = f - (0.5 * np.sum(((w - prior.mean) / prior.std) ** 2, axis=1) if prior is not None else 0.0)
    return IRLResult(
        theta=theta,
        normalized=features.normalize(theta),
        beta=theta[:, ref],
        neg_log_likelihood=f_data,
        at_bound=at_bound,
        converged=converged,
        n_iter=int(fit["n_iter"]),
        n_regularized=n_reg,
        gauss_newton=gauss_newton,
        gradient_norm=grad_norm,
    )


def _newton(blocks, labels, G, n_demos, *, features, prior, low, high, max_iter, tol, gauss_newton) -> dict:
    """The batched damped Newton iteration of `fit_weights` on given blocks (no warnings).

    ``gauss_newton``: the blocks hold Gauss-Newton Hessians; the start is the better (per group) of the
    stationarity estimate and equal weights, and a group also stops when its projected gradient is small.
    Otherwise the iteration is the original one (the paper's reproductions depend on it bit for bit).

    Returns a dict: w (G, K), f (G,) objective, gw (G, K), converged (G,), reg (G,) demonstrations
    regularised at the end, worst (most negative eigenvalue met at the end), grad_norm (G,), n_iter.
    """
    K = features.n_features
    ref = features.reference_index
    P = _param_map(K, ref)
    totals = {"reg": np.zeros(G), "worst": np.inf}
    subsets: dict = {}  # block index -> (mask bytes, subset): the active groups change only when some finish

    def subset(i: int, block, sel: np.ndarray):
        key = sel.tobytes()
        kept = subsets.get(i)
        if kept is None or kept[0] != key:
            kept = subsets[i] = (key, block.subset(sel))
        return kept[1]

    def objective(w: np.ndarray, order: int, active: np.ndarray | None = None):
        """Objective per group; with ``active``, only those groups' demonstrations are evaluated (the
        other entries are returned as 0 and must not be used)."""
        logt = w @ P.T
        theta = np.exp(logt)
        f = np.zeros(G)
        g = np.zeros((G, K)) if order >= 1 else None
        H = np.zeros((G, K, K)) if order >= 2 else None
        reg = np.zeros(G)
        for i, (block, lab) in enumerate(zip(blocks, labels)):
            if active is not None:
                sel = active[lab]
                if not sel.any():
                    continue
                if not sel.all():
                    block, lab = subset(i, block, sel), lab[sel]
            nll, dg, dH, bad, worst = _laplace_nll(theta[lab], block, order)
            np.add.at(reg, lab, bad)
            totals["worst"] = min(totals["worst"], worst)
            np.add.at(f, lab, nll)
            if order >= 1:
                np.add.at(g, lab, dg)  # type: ignore[arg-type]
            if order >= 2:
                np.add.at(H, lab, dH)  # type: ignore[arg-type]
        if order >= 1:
            totals["g_theta"] = g
            # chain rule: phi = log theta = P w
            dphi = theta * g
            gw = dphi @ P
        if order >= 2:
            Hphi = theta[:, :, None] * H * theta[:, None, :] + np.einsum("gk,kl->gkl", dphi, np.eye(K))
            Hw = np.einsum("ka,gkl,lb->gab", P, Hphi, P, optimize=True)
        if prior is not None:
            z = (w - prior.mean) / prior.std
            f = f + 0.5 * np.sum(z**2, axis=1)
            if order >= 1:
                gw = gw + z / prior.std
            if order >= 2:
                Hw = Hw + np.diag(1.0 / prior.std**2)[None]
        totals["reg"] = reg
        return f, (gw if order >= 1 else None), (Hw if order >= 2 else None)

    def projected(w: np.ndarray, gw: np.ndarray) -> np.ndarray:
        """|gradient| in w without the bound coordinates whose descent direction points outwards, (G,)."""
        out = ((w <= low + 1e-12) & (gw > 0)) | ((w >= high - 1e-12) & (gw < 0))
        return np.max(np.abs(np.where(out, 0.0, gw)), axis=1)

    gtol = _GTOL * np.maximum(n_demos, 1.0)
    w = _initial_guess(blocks, labels, G, features, low, high)
    if gauss_newton:  # a second start: equal weights at the same scale
        alt = w.copy()
        alt[:, [k for k in range(K) if k != ref]] = np.clip(0.0, low, high)
        f0, _, _ = objective(w, 0)
        f1, _, _ = objective(alt, 0)
        w = np.where((f1 < f0)[:, None], alt, w)
    done = np.zeros(G, dtype=bool)
    stalled = np.zeros(G, dtype=bool)  # finished because no step could improve any further
    eye = np.eye(K)
    others = [k for k in range(K) if k != ref]
    n_iter = 0
    for _restart in range(_MAX_RESTARTS + 1):
        damping = np.full(G, 1e-4)
        f, gw, Hw = objective(w, 2)
        if gauss_newton:
            done |= projected(w, gw) <= gtol
        while n_iter < max_iter and not np.all(done):
            n_iter += 1
            active = ~done
            # coordinates held at a bound where the descent direction points outwards
            at_low = (w <= low + 1e-12) & (gw > 0)
            at_high = (w >= high - 1e-12) & (gw < 0)
            free = ~(at_low | at_high)
            Hd = Hw + damping[:, None, None] * (np.abs(np.einsum("gkk->gk", Hw))[:, :, None] * eye + eye * 1e-12)
            Hd = np.where(free[:, :, None] & free[:, None, :], Hd, eye[None] * 1.0)
            rhs = np.where(free, -gw, 0.0)
            try:
                step = np.linalg.solve(Hd, rhs[..., None])[..., 0]
            except np.linalg.LinAlgError:
                step = rhs / np.maximum(np.abs(np.einsum("gkk->gk", Hd)), 1e-12)
            step = np.where(active[:, None], step, 0.0)
            w_new = np.clip(w + step, low, high)
            f_new, _, _ = objective(w_new, 0, active)
            better = (f_new <= f + 1e-12 * np.abs(f)) & active
            moved = np.max(np.abs(w_new - w), axis=1)
            w = np.where(better[:, None], w_new, w)
            damping = np.where(better, np.maximum(damping / 4.0, 1e-10), np.minimum(damping * 8.0, 1e12))
            small = moved < tol
            stuck = (~better) & (damping >= 1e12)
            stalled |= active & stuck & ~(better & small)
            done |= active & ((better & small) | stuck)
            todo = ~done
            if todo.any():
                f_u, gw_u, Hw_u = objective(w, 2, todo)
                f = np.where(todo, f_u, f)
                gw = np.where(todo[:, None], gw_u, gw)
                Hw = np.where(todo[:, None, None], Hw_u, Hw)
                if gauss_newton:
                    done |= todo & (projected(w, gw) <= gtol)
        # Escape the flat corner of the log parametrisation: a normalised weight driven towards 0 has a
        # vanishing gradient in w even when the (convex) likelihood in theta would still fall as it grows.
        # Where the theta-gradient says so, restart that coordinate from the best of a few values.
        if not others or n_iter >= max_iter:
            break
        _, _, _ = objective(w, 1)
        g_theta = totals["g_theta"]
        trapped = (w[:, others] < _TRAP_LOG) & (g_theta[:, others] < 0)  # type: ignore[index]
        if not trapped.any():
            break
        best_w, best_f = w.copy(), f.copy()
        for value in _RESTART_VALUES:
            trial = w.copy()
            trial[:, others] = np.where(trapped, np.clip(value, low, high), w[:, others])
            f_trial, _, _ = objective(trial, 0)
            take = f_trial < best_f
            best_w = np.where(take[:, None], trial, best_w)
            best_f = np.where(take, f_trial, best_f)
        moved_groups = best_f < f
        if not moved_groups.any():
            break
        w = best_w
        done &= ~moved_groups
        stalled &= ~moved_groups
    totals["worst"] = np.inf
    f, gw, _ = objective(w, 1)  # every group at the solution: values and regularisation counts
    grad_norm = projected(w, gw)
    converged = (done & ~stalled) | (grad_norm <= _GTOL_STALLED * np.maximum(n_demos, 1.0))
    return {"w": w, "f": f, "gw": gw, "converged": converged,
            "reg": totals["reg"].astype(int),  # type: ignore[attr-defined]
            "worst": totals["worst"], "grad_norm": grad_norm, "n_iter": n_iter}


def _initial_guess(blocks, labels, G, features: FeatureSet, low: float, high: float) -> np.ndarray:
    """Direction by least squares on the stationarity condition sum_k theta_k grad f_k = 0 (theta_ref = 1),
    then the scale that maximises the likelihood along that direction (beta = d / g^T H^-1 g)."""
    K = features.n_features
    ref = features.reference_index
    others = [k for k in range(K) if k != ref]
    AtA = np.zeros((G, len(others), len(others)))
    Atb = np.zeros((G, len(others)))
    for block, lab in zip(blocks, labels):
        A = block.grad[:, others, :]  # (M, K-1, d)
        b = block.grad[:, ref, :]
        np.add.at(AtA, lab, np.einsum("mkd,mld->mkl", A, A))
        np.add.at(Atb, lab, -np.einsum("mkd,md->mk", A, b))
    w = np.zeros((G, K))
    if others:
        reg = 1e-12 * (np.abs(np.einsum("gkk->g", AtA))[:, None, None] + 1e-300) * np.eye(len(others))
        sol = np.linalg.solve(AtA + reg, Atb[..., None])[..., 0]
        # Start well inside the box: in log coordinates the likelihood is flat where a weight is ~0, so a
        # start at a bound (a non-positive least-squares weight) would never leave it. Non-positive -> 1.
        start = np.where(sol > 0, np.log(np.where(sol > 0, sol, 1.0)), 0.0)
        w[:, others] = np.clip(start, max(low, -_START_BOX), min(high, _START_BOX))
    # scale along the direction
    theta = np.exp(w @ _param_map(K, ref).T)
    quad = np.zeros(G)
    dims = np.zeros(G)
    for block, lab in zip(blocks, labels):
        nll, *_ = laplace_nll(theta[lab], block, order=0)
        # nll = q - 1/2 logdet + const; recover q = 1/2 g^T H^-1 g from a second evaluation at twice the scale
        nll2, *_ = laplace_nll(2.0 * theta[lab], block, order=0)
        q = nll2 - nll + 0.5 * block.dim * np.log(2.0)  # q(2 theta) - q(theta) = q(theta)
        np.add.at(quad, lab, np.maximum(q, 0.0))
        np.add.at(dims, lab, block.dim)
    with np.errstate(divide="ignore"):
        w[:, ref] = np.clip(np.log(dims / 2.0) - np.log(np.maximum(quad, 1e-300)), low, high)
    return w
