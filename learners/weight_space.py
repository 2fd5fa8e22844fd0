"""Costs as distributions over the weights: per-demonstration posteriors and per-style likelihoods of histories.

A demonstration's weights are described by ``z = log(theta_k / theta_ref)`` for k != ref (D = K - 1 numbers),
the scale (rationality or noise) marginalised out. `demo_posteriors` gives a Gaussian posterior over z per
demonstration (flat prior inside the IRL's box ``log_bounds``): the Laplace posterior of the per-demonstration
IRL for ``likelihood="trajectory"``, the Gauss-Newton information of the receding-horizon fit for
``likelihood="receding"``; coordinates at a bound of the box are dropped and a weak prior of one box width keeps
every covariance finite. `style_log_likelihoods` evaluates, per style, the likelihood the IRL maximised at the
style's fitted weights (for the first T steps of an episode, ``episode_steps=N``: the Boltzmann prefix marginal);
`paired_log_likelihoods` does so for paired histories and weights.

The posteriors and likelihoods are explained in the documentation's "The learners" page.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from pirl_sim.irl import LaplaceBlock, attach_gauss_newton, laplace_nll
from pirl_sim.model import DriverModel
from pirl_sim.receding import RecedingPolicy, cauchy_scale, receding_steps
from pirl_sim.trajectory import Trajectory

__all__ = ["demo_posteriors", "style_log_likelihoods", "paired_log_likelihoods", "information_to_covariance"]


def _param_map(K: int, ref: int) -> np.ndarray:
    """P with log theta = P w (w = (log beta at ref, log normalised weights elsewhere)), as `pirl_sim.irl`."""
    P = np.eye(K)
    P[:, ref] = 1.0
    return P


def information_to_covariance(info: np.ndarray, at_bound: np.ndarray, log_bounds: tuple[float, float],
                              keep: np.ndarray) -> np.ndarray:
    """Marginal covariances of the coordinates ``keep`` from information matrices (module doc).

    Parameters
    ----------
    info : array (M, n, n)        information (Hessian of the negative log-likelihood) in n coordinates
    at_bound : array (M, n) bool  coordinates at a bound of the box: their information is dropped
    log_bounds : (low, high)      the box; its width sets the weak prior
    keep : int array (D,)         coordinates whose marginal covariance is returned

    Returns
    -------
    array (M, D, D)
    """
    info = 0.5 * (info + np.swapaxes(info, 1, 2))
    free = ~np.asarray(at_bound, dtype=bool)
    info = info * free[:, :, None] * free[:, None, :]
    lam, vec = np.linalg.eigh(info)
    info = np.einsum("mij,mj,mkj->mik", vec, np.maximum(lam, 0.0), vec)
    width = float(log_bounds[1] - log_bounds[0])
    n = info.shape[1]
    cov = np.linalg.inv(info + np.eye(n)[None] / width**2)
    cov = cov[:, keep][:, :, keep]
    return 0.5 * (cov + np.swapaxes(cov, 1, 2))


def demo_posteriors(model: DriverModel, trajectories: Sequence[Trajectory], result, *, likelihood: str,
                    log_bounds: tuple[float, float], horizon: int | None = None, step_stride: int = 1,
                    loss: str = "cauchy", prior=None, prior_rows: np.ndarray | None = None,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per-demonstration posterior over the log normalised weights (module doc).

    Parameters
    ----------
    model : DriverModel
    trajectories : sequence of M Trajectory
    result : IRLResult or RecedingResult   the per-demonstration fit (group i = trajectory i)
    likelihood, log_bounds : {"trajectory", "receding"}, (low, high)
    horizon, step_stride, loss : the receding likelihood's MPC horizon [steps], step stride and noise model
    prior, prior_rows : LogNormalPrior, bool array (M,), optional   the prior of the rows fitted as MAP under it

    Returns
    -------
    means, covariances : array (M, D), (M, D, D)   log normalised weights of the non-reference features
    """
    feats = model.features
    K, ref = feats.n_features, feats.reference_index
    others = np.array([k for k in range(K) if k != ref], dtype=int)
    M = len(trajectories)
    means = np.log(result.normalized[:, others])
    if likelihood == "trajectory":
        info = np.zeros((M, K, K))
        P = _param_map(K, ref)
        blocks = model.laplace_blocks(trajectories)
        gn_rows = np.zeros(M, dtype=bool) if result.gauss_newton is None else np.asarray(result.gauss_newton, bool)
        if gn_rows.any():
            blocks = attach_gauss_newton(blocks, feats, model.dynamics, model.check(trajectories))
        for block, idx in blocks:
            for use_gn in (False, True):
                sel = gn_rows[idx] == use_gn
                if not sel.any():
                    continue
                b = block if sel.all() else block.subset(sel)
                if use_gn:
                    b = b.gauss_newton()
                rows = idx[sel]
                theta = result.theta[rows]
                _, g, H, _, _ = laplace_nll(theta, b, order=2)
                dphi = theta * g
                Hphi = theta[:, :, None] * H * theta[:, None, :] + np.einsum("mk,kl->mkl", dphi, np.eye(K))
                info[rows] = np.einsum("ka,mkl,lb->mab", P, Hphi, P, optimize=True)
        if prior is not None and prior_rows is not None:
            info[np.asarray(prior_rows, dtype=bool)] += np.diag(1.0 / np.asarray(prior.std, dtype=float) ** 2)
        at_bound = np.asarray(result.at_bound, dtype=bool)
        return means, information_to_covariance(info, at_bound, log_bounds, others)
    if likelihood != "receding":
        raise ValueError(f"likelihood must be 'trajectory' or 'receding', got {likelihood!r}")
    steps = receding_steps(trajectories, int(horizon), stride=int(step_stride))  # type: ignore[arg-type]
    theta = result.normalized[steps.owner]
    sol = RecedingPolicy(model, int(horizon)).solve(steps.x, theta, steps.init)  # type: ignore[arg-type]
    J = sol.jac[:, :, others] * theta[:, None, others]  # d pi / d z, (S, n_u, D)
    var = _noise_variance(np.asarray(result.sigma, dtype=float), steps.u, loss)[steps.owner]
    info = np.zeros((M, len(others), len(others)))
    ok = np.asarray(sol.converged, dtype=bool)  # an unconverged plan's sensitivity is not the policy's (module doc)
    np.add.at(info, steps.owner[ok], np.einsum("sui,suj->sij", J[ok], J[ok]) / var[ok, None, None])
    at_bound = np.asarray(result.at_bound, dtype=bool)[:, others]
    return means, information_to_covariance(info, at_bound, log_bounds, np.arange(len(others)))


_CAUCHY_EFFICIENCY = 0.95  # of the Cauchy loss at Gaussian residuals (pirl_sim.receding: its scale's choice)
_CAUCHY_PER_SIGMA = 2.3849  # pirl_sim.receding's Cauchy scale per robust sigma


def _noise_variance(sigma: np.ndarray, controls: np.ndarray, loss: str) -> np.ndarray:
    """Variance per residual of the weights' information (module doc), floored like the Cauchy scale."""
    floor = cauchy_scale(0.0, controls) / _CAUCHY_PER_SIGMA  # the Cauchy scale's floor, as a sigma
    var = np.maximum(np.asarray(sigma, dtype=float), floor) ** 2
    return var if loss == "gauss" else var / _CAUCHY_EFFICIENCY


def style_log_likelihoods(model: DriverModel, histories: Sequence[Trajectory], *, likelihood: str,
                          theta: np.ndarray, normalized: np.ndarray, gauss_newton: np.ndarray | None = None,
                          sigma: np.ndarray | None = None, noise_floor_controls: np.ndarray | None = None,
                          horizon: int | None = None, step_stride: int = 1, loss: str = "cauchy",
                          episode_steps: int | None = None) -> np.ndarray:
    """log p(history | style j) for every history and style, shape (M, J) [nats] (module doc).

    Parameters
    ----------
    model : DriverModel
    histories : sequence of M Trajectory
    likelihood : {"trajectory", "receding"}
    theta, normalized : array (J, K)   absolute (trajectory likelihood) and normalised (receding) weights per style
    gauss_newton : array (J,) bool, optional  styles fitted with the Gauss-Newton cost Hessian (trajectory)
    sigma : array (J,)            fitted residual noise per style (receding) [control units]
    noise_floor_controls : array (S, n_u)  controls whose RMS floors the Cauchy scale (the training steps')
    horizon, step_stride, loss : as `demo_posteriors`
    episode_steps : int, optional   N: histories are the first steps of episodes of N steps (trajectory likelihood)
    """
    histories = model.check(histories)
    M = len(histories)
    if likelihood == "trajectory" and episode_steps is not None:
        lengths = np.array([h.n_steps for h in histories])
        out = np.empty((M, theta.shape[0]))
        short = lengths < int(episode_steps)
        for T in np.unique(lengths[short]):
            idx = np.flatnonzero(lengths == T)
            out[idx] = _prefix_log_likelihoods(model, [histories[i] for i in idx], theta, int(episode_steps))
        if (~short).any():
            idx = np.flatnonzero(~short)
            out[idx] = style_log_likelihoods(model, [histories[i] for i in idx], likelihood=likelihood, theta=theta,
                                             normalized=normalized, gauss_newton=gauss_newton)
        return out
    if likelihood == "trajectory":
        J = theta.shape[0]
        gn = np.zeros(J, dtype=bool) if gauss_newton is None else np.asarray(gauss_newton, dtype=bool)
        blocks = model.laplace_blocks(histories)
        if gn.any():
            blocks = attach_gauss_newton(blocks, model.features, model.dynamics, histories)
        out = np.empty((M, J))
        for block, idx in blocks:
            for j in range(J):
                b: LaplaceBlock = block.gauss_newton() if gn[j] else block
                nll, *_ = laplace_nll(np.tile(theta[j], (len(idx), 1)), b, order=0)
                out[idx, j] = -nll
        return out
    if likelihood != "receding":
        raise ValueError(f"likelihood must be 'trajectory' or 'receding', got {likelihood!r}")
    steps = receding_steps(histories, int(horizon), stride=int(step_stride))  # type: ignore[arg-type]
    policy = RecedingPolicy(model, int(horizon))  # type: ignore[arg-type]
    J = normalized.shape[0]
    out = np.zeros((M, J))
    floor_u = steps.u if noise_floor_controls is None else noise_floor_controls
    for j in range(J):
        r = steps.u - policy.solve(steps.x, np.tile(normalized[j], (steps.n_steps, 1)), steps.init).first
        if loss == "gauss":
            s = max(float(sigma[j]), 1e-12)  # type: ignore[index]
            per = -0.5 * (r / s) ** 2 - np.log(s) - 0.5 * np.log(2 * np.pi)
        else:
            c = float(cauchy_scale(sigma[j], floor_u))  # type: ignore[index]
            per = -np.log(np.pi * c) - np.log1p((r / c) ** 2)
        np.add.at(out[:, j], steps.owner, per.sum(axis=1))
    return out


def _prefix_log_likelihoods(model: DriverModel, histories: list[Trajectory], theta: np.ndarray, n_steps: int):
    """log N(U_h; U*_j[:T], [H_j^-1]_{:T,:T}) for histories of T < n_steps steps and styles j, shape (M, J)."""
    M, T = len(histories), histories[0].n_steps
    n_u = model.dynamics.n_u
    x0 = np.stack([h.states[0] for h in histories])
    U_h = np.stack([h.controls for h in histories]).reshape(M, T * n_u)
    out = np.empty((M, theta.shape[0]))
    gn = not model.features.quadratic
    for j, th in enumerate(theta):
        states = model.predict_states(x0, th, n_steps)
        controls = model.dynamics.controls_from_states(states)
        der = model.features.derivatives(model.dynamics, states, controls, gauss_newton=gn)
        H = np.einsum("k,mkij->mij", th, der.hess)
        cov = np.linalg.inv(H)[:, : T * n_u, : T * n_u]
        L = np.linalg.cholesky(0.5 * (cov + np.swapaxes(cov, 1, 2)))
        r = U_h - controls[:, :T].reshape(M, T * n_u)
        z = np.linalg.solve(np.broadcast_to(L, (M,) + L.shape[1:]), r[..., None])[..., 0]
        logdet = 2.0 * np.sum(np.log(np.einsum("mii->mi", L)), axis=1)
        out[:, j] = -0.5 * (np.sum(z**2, axis=1) + logdet + T * n_u * np.log(2.0 * np.pi))
    return out


def paired_log_likelihoods(model: DriverModel, histories: Sequence[Trajectory], *, likelihood: str,
                           theta: np.ndarray, normalized: np.ndarray, gauss_newton: np.ndarray | None = None,
                           sigma: np.ndarray | None = None, noise_floor_controls: np.ndarray | None = None,
                           horizon: int | None = None, step_stride: int = 1, loss: str = "cauchy",
                           episode_steps: int | None = None) -> np.ndarray:
    """log p(history_p | weights_p) for P (history, weights) pairs, shape (P,) [nats]: `style_log_likelihoods`
    with one row of weights per history (``theta``, ``normalized`` (P, K); ``gauss_newton``, ``sigma`` (P,)).
    PIRL-kNN's ``weighting="likelihood"`` scores each history against its neighbours' weights with it."""
    histories = model.check(histories)
    P = len(histories)
    theta, normalized = np.asarray(theta, dtype=float), np.asarray(normalized, dtype=float)
    out = np.empty(P)
    if likelihood == "receding":
        steps = receding_steps(histories, int(horizon), stride=int(step_stride))  # type: ignore[arg-type]
        r = steps.u - RecedingPolicy(model, int(horizon)).solve(steps.x,  # type: ignore[arg-type]
                                                                normalized[steps.owner], steps.init).first
        floor_u = steps.u if noise_floor_controls is None else noise_floor_controls
        if loss == "gauss":
            s = np.maximum(np.asarray(sigma, dtype=float), 1e-12)[steps.owner][:, None]
            per = -0.5 * (r / s) ** 2 - np.log(s) - 0.5 * np.log(2 * np.pi)
        else:
            c = cauchy_scale(np.asarray(sigma, dtype=float), floor_u)[steps.owner][:, None]
            per = -np.log(np.pi * c) - np.log1p((r / c) ** 2)
        return np.bincount(steps.owner, weights=per.sum(axis=1), minlength=P)
    if likelihood != "trajectory":
        raise ValueError(f"likelihood must be 'trajectory' or 'receding', got {likelihood!r}")
    lengths = np.array([h.n_steps for h in histories])
    prefix = np.zeros(P, dtype=bool) if episode_steps is None else lengths < int(episode_steps)
    for T in np.unique(lengths[prefix]):
        idx = np.flatnonzero(prefix & (lengths == T))
        out[idx] = _paired_prefix(model, [histories[i] for i in idx], theta[idx],
                                  int(episode_steps))  # type: ignore[arg-type]
    gn = np.zeros(P, dtype=bool) if gauss_newton is None else np.asarray(gauss_newton, dtype=bool)
    whole = np.flatnonzero(~prefix)
    if whole.size:
        group = [histories[i] for i in whole]
        blocks = model.laplace_blocks(group)
        if gn[whole].any():
            blocks = attach_gauss_newton(blocks, model.features, model.dynamics, group)
        for block, idx in blocks:
            rows = whole[idx]
            for use_gn in (False, True):
                sel = gn[rows] == use_gn
                if not sel.any():
                    continue
                b = block if sel.all() else block.subset(sel)
                nll, *_ = laplace_nll(theta[rows[sel]], b.gauss_newton() if use_gn else b, order=0)
                out[rows[sel]] = -nll
    return out


def _paired_prefix(model: DriverModel, histories: list[Trajectory], theta: np.ndarray, n_steps: int) -> np.ndarray:
    """`_prefix_log_likelihoods` with one row of absolute weights per history, shape (P,)."""
    P, T = len(histories), histories[0].n_steps
    n_u = model.dynamics.n_u
    x0 = np.stack([h.states[0] for h in histories])
    U_h = np.stack([h.controls for h in histories]).reshape(P, T * n_u)
    states = model.predict_states(x0, theta, n_steps)
    controls = model.dynamics.controls_from_states(states)
    der = model.features.derivatives(model.dynamics, states, controls, gauss_newton=not model.features.quadratic)
    H = np.einsum("pk,pkij->pij", theta, np.broadcast_to(der.hess, (P,) + der.hess.shape[1:]))
    cov = np.linalg.inv(H)[:, : T * n_u, : T * n_u]
    L = np.linalg.cholesky(0.5 * (cov + np.swapaxes(cov, 1, 2)))
    r = U_h - controls[:, :T].reshape(P, T * n_u)
    z = np.linalg.solve(L, r[..., None])[..., 0]
    logdet = 2.0 * np.sum(np.log(np.einsum("pii->pi", L)), axis=1)
    return -0.5 * (np.sum(z**2, axis=1) + logdet + T * n_u * np.log(2.0 * np.pi))
