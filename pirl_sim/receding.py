"""Receding-horizon IRL: the weights of drivers who re-plan every step.

A driver who re-plans every step over H steps is modelled step by step: ``u_t = pi_theta(x_t) + e_t``, with
``pi_theta(x)`` the first control of the converged (bounded) MPC over H steps from x under the cost
``theta . f`` (`RecedingPolicy`). `fit_receding` fits groups of steps (one per track, one for all, or one per
cluster) by batched Levenberg-Marquardt in the log weights, the MPC's derivatives in theta by implicit
differentiation of its optimality conditions with the active bounds. The MPC ignores the scale of theta, so only
the normalised weights are identified; the fitted sigma is the control noise (``beta = 1 / sigma^2`` in results).
Each fitted log weight comes with a standard error from the fit's Gauss-Newton information: a weight the data
do not inform (e.g. a headway weight of a car that never came near a vehicle ahead) gets a large or infinite one.
`STEP_MASK` metadata leaves out steps whose control was not the driver's own.

The model, its derivatives and its fit are explained in the documentation's "The two likelihoods" page.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.linalg

from .irl import shift_to_pd
from .model import DriverModel
from .mpc import BoxQP
from .trajectory import Trajectory
from .validation import is_positive_int

__all__ = ["RecedingPolicy", "PolicySolution", "RecedingSteps", "RecedingResult", "receding_steps", "fit_receding",
           "receding_residuals", "cauchy_scale", "cauchy_nll", "log_standard_errors", "STEP_MASK"]

#: metadata key of a trajectory's per-step mask (bool, shape (n_steps,)): False = the control at that step
#: was not the driver's own (overridden by a simulator, handed back, ...) and is left out of the likelihood
STEP_MASK = "step_mask"

_CHUNK = 2048  # steps per vectorised expansion (bounds the memory of the (chunk, d, d) Hessians)


@dataclass(frozen=True)
class PolicySolution:
    """Converged MPC plans from M starts, and d pi / d theta there.

    Attributes
    ----------
    U : array (M, H, n_u)        plans; ``U[:, 0]`` is pi_theta(x0)
    dU : array (M, H, n_u, K)    d U / d theta (implicit differentiation, module doc)
    bounded : array (M,) bool    the plan has at least one active bound
    converged : array (M,) bool
    gauss_newton : array (M,) bool  the exact Newton step was not a descent direction somewhere on the way
                                 (indefinite cost Hessian): Gauss-Newton steps were taken there
    """

    U: np.ndarray
    dU: np.ndarray
    bounded: np.ndarray
    converged: np.ndarray
    gauss_newton: np.ndarray

    @property
    def first(self) -> np.ndarray:
        """pi_theta(x0), shape (M, n_u)."""
        return self.U[:, 0]

    @property
    def jac(self) -> np.ndarray:
        """d pi / d theta, shape (M, n_u, K)."""
        return self.dU[:, 0]

    def predicted(self, theta_new: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """First-order prediction of the plans under other weights (M, K): a warm start, (M, H, n_u)."""
        return self.U + np.einsum("mhuk,mk->mhu", self.dU, theta_new - theta)


class RecedingPolicy:
    """pi_theta(x): the first control of the converged bounded MPC over ``horizon`` steps, and d pi / d theta.

    Newton's method on the exact cost with a backtracking line search (Gauss-Newton steps where the exact
    Newton step is not a descent direction), batched over starts; starts whose unconstrained optimum breaks
    a bound of ``model.bounds`` are re-solved by sequential bounded QPs (`pirl_sim.mpc.BoxQP`, DAQP) until
    the plan moves less than ``tol``; a warm start that sits on a bound goes to the QPs directly. Starts
    outside the state bounds are first moved inside them, as the simulated drivers do.

    Parameters
    ----------
    model : DriverModel
    horizon : int      H [steps], >= 1
    tol : float        convergence: largest control change of a Newton / QP step [control units]
    max_iter : int     Newton iterations (and, separately, bounded QPs) per solve
    """

    def __init__(self, model: DriverModel, horizon: int, *, tol: float = 1e-6, max_iter: int = 30):
        if not isinstance(model, DriverModel):
            raise TypeError(f"model must be a pirl_sim.DriverModel, got {type(model).__name__}")
        if not is_positive_int(horizon):
            raise ValueError(f"horizon must be a positive number of steps, got {horizon!r}")
        if not is_positive_int(max_iter):
            raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
        if not (math.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be > 0, got {tol!r}")
        self.model = model
        self.horizon = int(horizon)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self._qp = BoxQP(model.dynamics, model.bounds) if model.bounds is not None else None
        if self._qp is not None:
            self._x_lo, self._x_hi, self._u_lo, self._u_hi = (
                model.bounds.resolve(model.dynamics))  # type: ignore[union-attr, var-annotated]
        self.n_qp = 0
        self._cond: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._outers: dict[int, object] = {}

    # ------------------------------------------------------------------ pieces
    def start_states(self, x0: np.ndarray) -> np.ndarray:
        """Starts moved inside the state bounds (a stopped car does not decelerate further), (M, n_x)."""
        x0 = np.array(np.atleast_2d(x0), dtype=float)
        if self._qp is None:
            return x0
        x0 = self._qp.clip_start(x0)
        names = self.model.dynamics.state_names
        if "v [m/s]" in names and "a [m/s^2]" in names:
            iv, ia = names.index("v [m/s]"), names.index("a [m/s^2]")
            stopped = x0[:, iv] <= self._x_lo[iv]
            x0[stopped, ia] = np.maximum(x0[stopped, ia], 0.0)
        return x0

    def _rollout(self, x0: np.ndarray, U: np.ndarray) -> np.ndarray:
        """States (M, H + 1, n_x) from starts (M, n_x) and plans (M, H, n_u), by two matrix products."""
        dyn = self.model.dynamics
        H = U.shape[1]
        if H not in self._cond:
            phi, gamma = dyn.condensed(H)
            self._cond[H] = (phi.reshape(H * dyn.n_x, dyn.n_x).T.copy(),
                             gamma.reshape(H * dyn.n_x, H * dyn.n_u).T.copy())
        phiT, gT = self._cond[H]
        future = (x0 @ phiT + U.reshape(U.shape[0], -1) @ gT).reshape(U.shape[0], H, dyn.n_x)
        return np.concatenate([x0[:, None, :], future], axis=1)

    def _outer(self, H: int):
        """The tabulated outer-product expansion of the model's cost over H steps (`pirl_sim.mpc`), or None when
        the reference feature is not quadratic."""
        if H not in self._outers:
            from .mpc import _OuterExpansion

            feats = self.model.features
            quadratic_ref = feats.features[feats.reference_index].quadratic
            self._outers[H] = _OuterExpansion(self.model.dynamics, feats, H) if quadratic_ref else None
        return self._outers[H]

    def _expand(self, x0, U, theta, gauss_newton: bool = False):
        """Values (M, K), gradients (M, K, d) and the cost Hessian (M, d, d) at U, in chunks: the Hessian as
        coefficients times tabulated stage outer products (one matrix product, `pirl_sim.mpc`), or by
        `FeatureSet.expansion` for a model whose reference feature is not quadratic."""
        dyn, feats = self.model.dynamics, self.model.features
        M, d = U.shape[0], U.shape[1] * U.shape[2]
        K = feats.n_features
        if M == 0:  # e.g. no bounded QP of a round could be solved
            return np.empty((0, K)), np.empty((0, K, d)), np.empty((0, d, d))
        exp = self._outer(U.shape[1])

        def chunk(sl):
            X = self._rollout(x0[sl], U[sl])
            if exp is None:
                ex = feats.expansion(dyn, X, U[sl], theta[sl], gauss_newton=gauss_newton)
                return ex.values, ex.grad, ex.hess
            m = X.shape[0]
            values, sigma, jj, ww = exp.stage_terms(X, U[sl], theta[sl], per_feature=True)  # sigma (m, K, N, q)
            grad = exp.chain(sigma.reshape(m * K, exp.N, exp.q)).reshape(m, K, d)
            return values, grad, exp.hessians(theta[sl], jj, None if gauss_newton else ww, 1.0)

        if M <= _CHUNK:
            return chunk(slice(0, M))
        values, grad, hess = np.empty((M, K)), np.empty((M, K, d)), np.empty((M, d, d))
        for lo in range(0, M, _CHUNK):
            sl = slice(lo, lo + _CHUNK)
            values[sl], grad[sl], hess[sl] = chunk(sl)
        return values, grad, hess

    def _cost(self, x0, U, theta):
        dyn, feats = self.model.dynamics, self.model.features
        out = np.empty(U.shape[0])
        for lo in range(0, U.shape[0], _CHUNK):
            sl = slice(lo, lo + _CHUNK)
            out[sl] = np.einsum("mk,mk->m", theta[sl], feats.values(self._rollout(x0[sl], U[sl]), U[sl]))
        return out

    # ------------------------------------------------------------------ solve
    def solve(self, x0: np.ndarray, theta: np.ndarray, init: np.ndarray | None = None) -> PolicySolution:
        """Converged plans from starts x0 (M, n_x) under weights theta (K,) or (M, K), with d pi / d theta.

        ``init`` (M, H, n_u) warm-starts Newton (default zeros).
        """
        dyn, feats = self.model.dynamics, self.model.features
        x0 = self.start_states(x0)
        if x0.ndim != 2 or x0.shape[1] != dyn.n_x or not np.all(np.isfinite(x0)):
            raise ValueError(f"start states must be finite with shape (M, {dyn.n_x}), got {x0.shape}")
        M, H, n_u, K = x0.shape[0], self.horizon, dyn.n_u, feats.n_features
        theta = np.broadcast_to(feats.weights(theta), (M, K)).astype(float)
        if np.any(theta < 0):
            raise ValueError("weights must be >= 0 for the MPC")
        U = np.zeros((M, H, n_u)) if init is None else np.array(init, dtype=float)
        if U.shape != (M, H, n_u) or not np.all(np.isfinite(U)):
            raise ValueError(f"init must be finite with shape {(M, H, n_u)}, got {U.shape}")
        d = H * n_u
        values, grad, hess = self._expand(x0, U, theta)
        cost = np.einsum("mk,mk->m", theta, values)
        converged = np.zeros(M, dtype=bool)
        dU = np.zeros((M, d, K))  # d U* / d theta
        gauss_newton = np.zeros(M, dtype=bool)
        # a warm start that sits on a bound keeps its active set: straight to the bounded QPs
        on_bound = np.zeros(M, dtype=bool)
        if self._qp is not None and init is not None:
            on_bound = self._qp.touches(x0, U)
        todo = np.flatnonzero(~on_bound)
        for _ in range(self.max_iter):
            if not len(todo):
                break
            g = np.einsum("mk,mkd->md", theta[todo], grad[todo])
            # one factorisation per start: the Newton step and H^-1 grad f_k for d U* / d theta
            rhs = np.concatenate([g[..., None], np.swapaxes(grad[todo], 1, 2)], axis=2)
            sol = _solve_rows(hess[todo], rhs)
            full, Y = -sol[..., 0], -sol[..., 1:]
            promised = -0.5 * np.einsum("md,md->m", g, full)
            uphill = ~(promised >= 0) | ~np.all(np.isfinite(full), axis=1)
            if uphill.any():  # not a descent direction: the exact Hessian is indefinite there
                rows = todo[uphill]
                gauss_newton[rows] = True
                gn = self._expand(x0[rows], U[rows], theta[rows], gauss_newton=True)[2]
                _, gn_pd, _, _ = shift_to_pd(gn, 1e-9)
                full[uphill] = -np.linalg.solve(gn_pd, g[uphill][..., None])[..., 0]
                promised[uphill] = -0.5 * np.einsum("md,md->m", g[uphill], full[uphill])
            full = full.reshape(len(todo), H, n_u)
            # converged: the step is below tol, or the decrease it promises is below the floating-point
            # resolution of the cost (a line search could not see it); derivatives are kept from before the
            # step, which is smaller than tol
            tiny = ((np.max(np.abs(full), axis=(1, 2)) <= self.tol) | (promised <= 1e-13 * np.abs(cost[todo]))) \
                & ~uphill
            if tiny.any():
                rows = todo[tiny]
                U[rows] += full[tiny]
                dU[rows] = Y[tiny]
                converged[rows] = True
                todo, full = todo[~tiny], full[~tiny]
                if not len(todo):
                    break
            # backtracking: halve the step of the starts where it does not lower the cost (only those are
            # evaluated again)
            alpha = np.ones(len(todo))
            trial = U[todo] + full
            trial_cost = self._cost(x0[todo], trial, theta[todo])
            worse = trial_cost > cost[todo] + 1e-13 * np.abs(cost[todo])
            for _half in range(20):
                if not worse.any():
                    break
                j = np.flatnonzero(worse)
                alpha[j] /= 2.0
                trial[j] = U[todo[j]] + alpha[j, None, None] * full[j]
                trial_cost[j] = self._cost(x0[todo[j]], trial[j], theta[todo[j]])
                worse[j] = trial_cost[j] > cost[todo[j]] + 1e-13 * np.abs(cost[todo[j]])
            step = alpha * np.max(np.abs(full), axis=(1, 2))
            ok = ~worse | (step <= self.tol)
            rows = todo[ok]
            U[rows] = trial[ok]
            values[rows], grad[rows], hess[rows] = self._expand(x0[rows], U[rows], theta[rows])
            cost[rows] = np.einsum("mk,mk->m", theta[rows], values[rows])
            todo = todo[ok]  # a start whose line search failed stays unconverged
        left = np.flatnonzero(~converged & ~on_bound)
        if len(left):  # unconverged: derivatives at the last plan
            dU[left] = self._implicit(x0[left], U[left], grad[left], hess[left])
        bounded = np.zeros(M, dtype=bool)
        if self._qp is not None:
            bad = np.flatnonzero((self._qp.violation(x0, U) > 1e-9) | on_bound)
            converged[bad] = False
            qp_tol = max(self.tol, 1e-8)
            for _ in range(self.max_iter):  # sequential bounded QPs, one batched expansion per round
                if not len(bad):
                    break
                g = np.einsum("mk,mkd->md", theta[bad], grad[bad])
                _, A, _, _ = shift_to_pd(hess[bad], 1e-9)
                b = g - np.einsum("mij,mj->mi", A, U[bad].reshape(len(bad), -1))
                moved = np.full(len(bad), -1.0)
                for j, m in enumerate(bad):  # type: ignore[assignment]
                    try:
                        new = self._qp.solve(A[j], b[j], x0[m], H).reshape(H, n_u)
                    except RuntimeError:  # infeasible from this start: keep the plan, unconverged
                        continue
                    self.n_qp += 1
                    moved[j] = np.max(np.abs(new - U[m]))
                    U[m] = new
                solved = moved >= 0
                rows = bad[solved]
                values[rows], grad[rows], hess[rows] = self._expand(x0[rows], U[rows], theta[rows])
                done = solved & (moved <= qp_tol)
                converged[bad[done]] = True
                bad = bad[solved & ~done]
            bounded = self._qp.touches(x0, U)
            rows = np.flatnonzero(bounded)
            if len(rows):
                dU[rows] = self._implicit(x0[rows], U[rows], grad[rows], hess[rows])
        return PolicySolution(U, dU.reshape(M, H, n_u, K), bounded, converged, gauss_newton)

    def _implicit(self, x0, U, grad, hess) -> np.ndarray:
        """d U* / d theta (M, d, K) at plans U with their active bounds (module doc)."""
        M, K, d = grad.shape
        _, hess, _, _ = shift_to_pd(hess, 1e-9)
        out = np.empty((M, d, K))
        for m in range(M):
            C = self._active_matrix(x0[m], U[m]) if self._qp is not None else np.zeros((0, d))
            Z = scipy.linalg.null_space(C) if len(C) else np.eye(d)
            if Z.shape[1] == 0:  # every control pinned by a bound
                out[m] = 0.0
                continue
            R = Z.T @ hess[m] @ Z
            out[m] = -Z @ np.linalg.solve(R, Z.T @ grad[m].T)
        return out

    def _active_matrix(self, x0: np.ndarray, U: np.ndarray, tol: float = 1e-7) -> np.ndarray:
        """Rows (n_a, d) of the active bounds of one plan U (H, n_u) from x0 (n_x,)."""
        dyn = self.model.dynamics
        H, n_u = U.shape
        _, gamma = dyn.condensed(H)
        X = dyn.rollout(x0, U)[1:]
        near = lambda v, lo, hi: (np.abs(v - lo) <= tol) | (np.abs(v - hi) <= tol)
        rows = []
        for k, i in zip(*np.nonzero(near(U, self._u_lo, self._u_hi))):
            e = np.zeros(H * n_u)
            e[k * n_u + i] = 1.0
            rows.append(e)
        for k, j in zip(*np.nonzero(near(X, self._x_lo, self._x_hi))):
            rows.append(gamma[k, j].reshape(-1))
        return np.array(rows).reshape(len(rows), H * n_u)


def _solve_rows(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Batched solve of A (M, d, d) X = B (M, d, r); rows with a singular A give NaN instead of raising."""
    try:
        return np.linalg.solve(A, B)
    except np.linalg.LinAlgError:
        out = np.full(B.shape, np.nan)
        for m in range(A.shape[0]):
            try:
                out[m] = np.linalg.solve(A[m], B[m])
            except np.linalg.LinAlgError:
                pass
        return out


# ---------------------------------------------------------------------------------------------- data
@dataclass(frozen=True)
class RecedingSteps:
    """The recorded steps a receding-horizon likelihood scores.

    Attributes
    ----------
    x : array (S, n_x)        state at each step
    u : array (S, n_u)        control the driver applied there
    init : array (S, H, n_u)  warm start: the recorded controls that followed (last one repeated)
    owner : array (S,) int    index of the trajectory each step comes from
    """

    x: np.ndarray
    u: np.ndarray
    init: np.ndarray
    owner: np.ndarray

    @property
    def n_steps(self) -> int:
        return self.x.shape[0]


def receding_steps(trajectories: Sequence[Trajectory], horizon: int, *, stride: int = 1) -> RecedingSteps:
    """Every ``stride``-th step of each trajectory that its `STEP_MASK` metadata (if any) keeps.

    Raises ValueError if a mask has the wrong shape or leaves no step at all.
    """
    if not is_positive_int(horizon):
        raise ValueError(f"horizon must be a positive number of steps, got {horizon!r}")
    if not is_positive_int(stride):
        raise ValueError(f"stride must be a positive number of steps, got {stride!r}")
    xs, us, inits, owners = [], [], [], []
    for i, t in enumerate(trajectories):
        keep = np.zeros(t.n_steps, dtype=bool)
        keep[::stride] = True
        mask = t.metadata.get(STEP_MASK)
        if mask is not None:
            mask = np.asarray(mask)
            if mask.shape != (t.n_steps,) or mask.dtype != bool:
                raise ValueError(f"trajectory {i}: {STEP_MASK!r} must be a bool array of shape ({t.n_steps},), "
                                 f"got {mask.dtype} {mask.shape}")
            keep &= mask
        idx = np.flatnonzero(keep)
        if not len(idx):
            continue
        padded = np.concatenate([t.controls, np.repeat(t.controls[-1:], horizon, axis=0)])
        xs.append(t.states[idx])
        us.append(t.controls[idx])
        inits.append(np.stack([padded[j : j + horizon] for j in idx]))
        owners.append(np.full(len(idx), i))
    if not xs:
        raise ValueError(f"no usable step: the step masks (metadata {STEP_MASK!r}) leave nothing of "
                         f"{len(trajectories)} trajectories")
    return RecedingSteps(np.concatenate(xs), np.concatenate(us), np.concatenate(inits), np.concatenate(owners))


# ---------------------------------------------------------------------------------------------- fit
@dataclass(frozen=True)
class RecedingResult:
    """Weights fitted per group by the receding-horizon likelihood (fields as `pirl_sim.irl.IRLResult`).

    Attributes
    ----------
    theta, normalized : array (G, K)   normalised weights (reference feature = 1): the MPC ignores scale
    beta : array (G,)                  1 / sigma^2, the residual precision [1 / control units^2]
    sigma : array (G,)                 fitted residual standard deviation [control units]
    neg_log_likelihood : array (G,)    with sigma profiled out (module doc)
    n_steps : array (G,) int           steps scored per group
    at_bound : array (G, K) bool       log weight at its bound (the reference entry: never)
    converged : array (G,) bool
    n_iter : int
    n_regularized : int                scored steps whose MPC took Gauss-Newton steps (indefinite cost Hessian)
    n_bounded : int                    plans with an active bound at the solution
    log_se : array (G, K) or None      standard error of each fitted log normalised weight (`log_standard_errors`;
                                       0 for the reference, inf where the data do not determine it); None in
                                       results saved without it
    """

    theta: np.ndarray
    normalized: np.ndarray
    beta: np.ndarray
    sigma: np.ndarray
    neg_log_likelihood: np.ndarray
    n_steps: np.ndarray
    at_bound: np.ndarray
    converged: np.ndarray
    n_iter: int
    n_regularized: int
    n_bounded: int
    log_se: np.ndarray | None = None


#: `log_standard_errors`: a log weight whose squared loadings on the uninformed directions sum to more than this
#: has no standard error (inf). 1e-6 is a loading of 1e-3: across log-weight bounds 20 wide, an uninformed
#: direction could move such a weight by at most 0.02
FLAT_SHARE = 1e-6


def log_standard_errors(info: np.ndarray, sigma: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """Standard errors (G, F) of log weights from the Gauss-Newton information ``info`` (G, F, F) = J'WJ of
    residuals with scale ``sigma`` (G,): ``sigma sqrt(diag(info^-1))``. A direction whose eigenvalue is at most
    ``rcond`` times the largest (or every direction of a zero matrix) carries no information: a weight gets inf
    when more than `FLAT_SHARE` of it lies in such directions (a weight the data determine keeps its error when
    another one is free, even if the free direction leans on it by a rounding-sized loading)."""
    info = np.asarray(info, dtype=float)
    lam, V = np.linalg.eigh(info)
    top = lam.max(axis=1, keepdims=True)
    flat = (lam <= rcond * top) | (top <= 0.0)
    var = np.einsum("gik,gk->gi", V**2, np.where(flat, 0.0, 1.0 / np.where(flat, 1.0, lam)))
    lost = np.einsum("gik,gk->gi", V**2, flat.astype(float)) > FLAT_SHARE  # invariant to a rotation among them
    return np.where(lost, np.inf, np.asarray(sigma, dtype=float)[:, None] * np.sqrt(var))


def receding_residuals(model: DriverModel, trajectories: Sequence[Trajectory], theta: np.ndarray, horizon: int, *,
                       stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Residuals u_t - pi_theta(x_t) of every scored step (the steps `receding_steps` keeps: every ``stride``-th
    step its `STEP_MASK` allows), e.g. to score fitted weights on held-out tracks.

    Parameters
    ----------
    model : DriverModel
    trajectories : sequence of Trajectory
    theta : array (K,) or (M, K)     normalised weights, shared or one row per trajectory
    horizon : int                    MPC horizon [steps]

    Returns
    -------
    residuals : array (S, n_u) [control units]
    owner : array (S,) int            trajectory index of each step
    """
    trajectories = model.check(trajectories)
    steps = receding_steps(trajectories, horizon, stride=stride)
    theta = np.asarray(model.features.weights(theta), dtype=float)
    if theta.ndim == 2 and theta.shape[0] != len(trajectories):
        raise ValueError(f"theta has {theta.shape[0]} rows for {len(trajectories)} trajectories")
    th = theta[steps.owner] if theta.ndim == 2 else np.broadcast_to(theta, (steps.n_steps, theta.size))
    sol = RecedingPolicy(model, horizon).solve(steps.x, th, steps.init)
    return steps.u - sol.first, steps.owner


def cauchy_scale(sigma, controls: np.ndarray):
    """The Cauchy scale c [control units] of the ``loss="cauchy"`` residual model for a robust residual sigma
    (scalar or array): 2.385 sigma, floored at 1 % of the RMS of the recorded ``controls``."""
    floor = _CAUCHY_FLOOR * (np.sqrt(np.mean(np.square(controls))) + 1e-12)
    return np.maximum(_CAUCHY_C * np.asarray(sigma, dtype=float), floor)


def cauchy_nll(residuals: np.ndarray, scale: float) -> float:
    """Mean negative log-likelihood per scored control of residuals under Cauchy(0, scale) [nats]."""
    z = np.asarray(residuals, dtype=float) / scale
    return float(np.mean(np.log(np.pi * scale) + np.log1p(z**2)))


LOSSES = ("cauchy", "gauss")
_CAUCHY_C = 2.3849  # Cauchy scale per robust sigma: 95 % efficiency at Gaussian residuals
_MAD_SIGMA = 1.4826  # sigma per median absolute residual for Gaussian residuals
_GRID = (-2.0, 0.0, 2.0)  # start grid of each free log weight
_GRID_STEPS = 12  # steps per group that score the start grid
_GRID_JOINT = 3  # free weights searched jointly on the start grid; further ones one at a time
_GRID_MAX_FREE = 4  # more free weights start from the reference point (0 log weights)
_CAUCHY_FLOOR = 0.01  # smallest Cauchy scale, per RMS of the recorded controls
_MAX_STEP = 2.0  # largest Levenberg-Marquardt step in any log weight
_RESCALE_ROUNDS = 3  # refits with a smaller Cauchy scale once the residuals shrank
_COARSE_MIN = 2000  # steps from which a coarse pass comes first
_COARSE_KEEP = 40  # steps of a group that the coarse pass keeps at least (all if fewer)
_COARSE_TOL = 1e-2  # the coarse pass's tolerance on the log weights (it only finds the basin)
_COARSE_STRIDE = 8  # the first Levenberg-Marquardt pass uses every 8th step when there are many


def fit_receding(
    model: DriverModel,
    trajectories: Sequence[Trajectory],
    labels: np.ndarray | None = None,
    *,
    horizon: int,
    n_groups: int | None = None,
    stride: int = 1,
    loss: str = "cauchy",
    log_bounds: tuple[float, float] = (-20.0, 20.0),
    init: np.ndarray | None = None,
    max_iter: int = 50,
    tol: float = 1e-3,
) -> RecedingResult:
    """Receding-horizon IRL: maximum-likelihood normalised weights per group of trajectories.

    Parameters
    ----------
    model, horizon : DriverModel, int   the drivers' MPC model (its dt: the trajectories' step) and horizon H [steps]
    trajectories : sequence of Trajectory   each step counts unless its `STEP_MASK` metadata is False there
    labels, n_groups : int array (M,), int, optional   group of each trajectory (default: one each); G (see the page)
    stride, loss : int, {"cauchy", "gauss"}   score every ``stride``-th step; residual noise model (see the page)
    log_bounds, init : (low, high), array (K,) or (G, K) or None   box on the log normalised weights; start (see page)
    max_iter, tol : int, float          Levenberg-Marquardt iterations; stop when no log weight moves more

    Returns
    -------
    result : RecedingResult
    """
    trajectories = model.check(trajectories)
    feats = model.features
    K, ref = feats.n_features, feats.reference_index
    free = np.array([k for k in range(K) if k != ref], dtype=int)
    M = len(trajectories)
    labels = np.arange(M) if labels is None else np.asarray(labels)
    if labels.shape != (M,) or labels.dtype.kind not in "iu" or (M and labels.min() < 0):
        raise ValueError(f"labels must be {M} non-negative integers, got {labels!r}")
    G = int(n_groups) if n_groups is not None else int(labels.max()) + 1
    if G <= labels.max():
        raise ValueError(f"n_groups={n_groups} is not more than the largest label {int(labels.max())}")
    low, high = float(log_bounds[0]), float(log_bounds[1])
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise ValueError(f"log_bounds must be finite (low, high) with low < high, got {log_bounds!r}")
    if not is_positive_int(max_iter):
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    steps = receding_steps(trajectories, horizon, stride=stride)
    grp = labels[steps.owner]
    w = np.zeros((G, K))
    if init is not None:
        th0 = feats.normalize(np.broadcast_to(feats.weights(init), (G, K)))
        w = np.clip(np.log(th0), low, high)
    w[:, ref] = 0.0
    policy = RecedingPolicy(model, horizon)
    fit = _LM(policy, steps, grp, G, free, low, high, loss)
    if init is None and 0 < len(free) <= _GRID_MAX_FREE:
        w = fit.grid_start(w)
    if steps.n_steps >= _COARSE_MIN:  # a coarse pass on every 8th step finds the basin for a fraction of the cost
        coarse = np.zeros(steps.n_steps, dtype=bool)
        for g in range(G):  # but keeps at least _COARSE_KEEP steps of every group
            rows = np.flatnonzero(grp == g)
            coarse[rows[:: max(1, min(_COARSE_STRIDE, len(rows) // _COARSE_KEEP))]] = True
        w, _, n_coarse = fit.run(w, coarse, max_iter, max(tol, _COARSE_TOL))
    else:
        n_coarse = 0
    w, state, n_iter = fit.run_rescaled(w, np.ones(steps.n_steps, dtype=bool), max_iter, tol)
    counts = np.bincount(grp, minlength=G)
    has = counts > 0
    sigma, nll = fit.scale_and_nll(state.resid, counts)
    log_se = np.zeros((G, K))
    log_se[:, free] = log_standard_errors(fit.information(state), sigma)
    log_se[~has] = np.inf
    log_se[:, ref] = 0.0
    theta = np.exp(w)
    at_bound = np.zeros((G, K), dtype=bool)
    at_bound[:, free] = (w[:, free] <= low + 1e-9) | (w[:, free] >= high - 1e-9)
    return RecedingResult(
        theta=theta, normalized=theta.copy(), beta=1.0 / np.maximum(sigma**2, np.finfo(float).tiny),
        sigma=sigma, neg_log_likelihood=nll, n_steps=counts, at_bound=at_bound,
        converged=state.converged & has, n_iter=n_coarse + n_iter, n_regularized=int(state.gauss_newton.sum()),
        n_bounded=int(state.bounded.sum()), log_se=log_se,
    )


@dataclass
class _LMState:
    plans: np.ndarray
    dplans: np.ndarray
    theta: np.ndarray
    bounded: np.ndarray
    resid: np.ndarray
    jac: np.ndarray
    converged: np.ndarray
    gauss_newton: np.ndarray


class _LM:
    """Batched Levenberg-Marquardt over groups of steps in the free log weights (see `fit_receding`)."""

    def __init__(self, policy, steps, grp, G, free, low, high, loss):
        self.policy, self.steps, self.grp, self.G = policy, steps, grp, G
        self.free, self.low, self.high, self.loss = free, low, high, loss
        self.n_u = steps.u.shape[1]

    def _solve(self, w, rows, init):
        theta = np.exp(w[self.grp[rows]])
        sol = self.policy.solve(self.steps.x[rows], theta, init)
        return sol, self.steps.u[rows] - sol.first, theta

    def _jac(self, sol, theta):
        return -sol.jac[:, :, self.free] * theta[:, None, self.free]  # d r / d w

    def _scale(self, resid, grp_rows):
        """Cauchy scale c per group (G,) from the residuals' robust sigma (unused for "gauss")."""
        a = np.abs(resid).max(axis=1)
        sigma = np.full(self.G, 1.0 / _CAUCHY_C)
        for g in np.unique(grp_rows):
            sigma[g] = _MAD_SIGMA * np.median(a[grp_rows == g])
        # floor: 1 % of the controls' RMS. Below it residuals count as exact (least squares), so nearly
        # noise-free demonstrations keep a smooth objective instead of sum log |r|
        return cauchy_scale(sigma, self.steps.u)

    def _rho(self, resid, grp_rows, c):
        """Per-group objective: sum of 1/2 r^2 (gauss) or c^2/2 log(1 + (r/c)^2) (cauchy), and the IRLS
        weights per step (S, n_u)."""
        if self.loss == "gauss":
            per = 0.5 * resid**2
            wts = np.ones_like(resid)
        else:
            cc = c[grp_rows][:, None]
            z = (resid / cc) ** 2
            per = 0.5 * cc**2 * np.log1p(z)
            wts = 1.0 / (1.0 + z)
        return np.bincount(grp_rows, weights=per.sum(axis=1), minlength=self.G), wts

    def information(self, st) -> np.ndarray:
        """The Gauss-Newton information J'WJ (G, F, F) in the free log weights at a state of every step, W the
        loss's IRLS weights at the residuals' own scale."""
        grp = self.grp
        _, wts = self._rho(st.resid, grp, self._scale(st.resid, grp))
        F = len(self.free)
        info = np.zeros((self.G, F, F))
        np.add.at(info, grp, np.einsum("sui,su,suj->sij", st.jac, wts, st.jac, optimize=True))
        return info

    def run(self, w, use, max_iter, tol, groups=None, state=None):
        """LM from log weights w (G, K) on the steps where ``use`` (S,): (w, state, iterations).

        ``groups`` (G,) bool: fit only these (the others keep w); ``state``: the state of a previous run on
        the same steps and weights, to start from instead of solving again."""
        rows_all = np.flatnonzero(use)
        grp = self.grp[rows_all]
        G, free, low, high = self.G, self.free, self.low, self.high
        has = np.bincount(grp, minlength=G) > 0
        if groups is not None:
            has &= groups
        if state is None:
            sol, r, theta = self._solve(w, rows_all, self.steps.init[rows_all])
            st = _LMState(sol.U.copy(), sol.dU.copy(), theta, sol.bounded.copy(), r, self._jac(sol, theta), ~has,
                          sol.gauss_newton.copy())
        else:
            st = state
            st.converged = st.converged & ~has
        lam = np.full(G, 1e-3)
        n_iter = 0
        c = self._scale(st.resid, grp)  # the Cauchy scale is held during a run: one objective per run
        self.last_scale = c if groups is None else np.where(groups, c, self.last_scale)
        for n_iter in range(1, max_iter + 1):
            active = ~st.converged
            if not active.any():
                break
            f, wts = self._rho(st.resid, grp, c)
            JtJ = np.zeros((G, len(free), len(free)))
            Jtr = np.zeros((G, len(free)))
            np.add.at(JtJ, grp, np.einsum("sui,su,suj->sij", st.jac, wts, st.jac, optimize=True))
            np.add.at(Jtr, grp, np.einsum("sui,su,su->si", st.jac, wts, st.resid, optimize=True))
            wf = w[:, free]
            held = ((wf <= low + 1e-12) & (Jtr > 0)) | ((wf >= high - 1e-12) & (Jtr < 0))
            diag = np.einsum("gii->gi", JtJ)
            eye = np.eye(len(free))
            A = JtJ + lam[:, None, None] * eye * (diag[:, :, None] + 1e-12 * (1.0 + diag.max()))
            A = np.where(held[:, :, None] | held[:, None, :], eye[None], A)
            delta = np.linalg.solve(A, np.where(held, 0.0, -Jtr)[..., None])[..., 0]
            delta *= np.minimum(1.0, _MAX_STEP / np.maximum(np.abs(delta).max(axis=1, keepdims=True), 1e-300))
            w_trial = w.copy()
            w_trial[:, free] = np.where(active[:, None], np.clip(wf + delta, low, high), wf)
            moved = np.max(np.abs(w_trial - w), axis=1)
            sub = np.flatnonzero(active[grp])
            rows = rows_all[sub]
            guess = st.plans[sub] + np.einsum("shuk,sk->shu", st.dplans[sub],
                                              np.exp(w_trial[self.grp[rows]]) - st.theta[sub])
            sol_t, r_t, theta_t = self._solve(w_trial, rows, guess)
            f_t, _ = self._rho(r_t, grp[sub], c)
            better = active & (f_t <= f * (1 + 1e-12))
            small = moved <= tol
            acc = better[grp[sub]]
            a = sub[acc]
            st.plans[a], st.bounded[a], st.resid[a] = sol_t.U[acc], sol_t.bounded[acc], r_t[acc]
            st.dplans[a], st.theta[a], st.gauss_newton[a] = sol_t.dU[acc], theta_t[acc], sol_t.gauss_newton[acc]
            st.jac[a] = self._jac(sol_t, theta_t)[acc]
            w = np.where(better[:, None], w_trial, w)
            lam = np.where(better, np.maximum(lam / 5.0, 1e-9), np.minimum(lam * 10.0, 1e9))
            st.converged |= active & (small | (lam >= 1e9))
        return w, st, n_iter

    def run_rescaled(self, w, use, max_iter, tol):
        """`run`, then again for the groups whose residuals' robust scale fell by more than half (the Cauchy
        scale of a run comes from its first residuals; the loss should fit the final ones)."""
        w, st, n_iter = self.run(w, use, max_iter, tol)
        grp = self.grp[use]
        for _ in range(_RESCALE_ROUNDS):
            shrunk = self._scale(st.resid, grp) < 0.5 * self.last_scale
            if self.loss == "gauss" or not shrunk.any():
                break
            w, st, more = self.run(w, use, max_iter, tol, groups=shrunk, state=st)
            n_iter += more
        return w, st, n_iter

    def grid_start(self, w):
        """Start weights per group: the best point of a grid over the free log weights (each in
        `_GRID` = {-2, 0, 2}; the first `_GRID_JOINT` jointly, each further one alone from the best point so far), scored by the sum of |residual| on up to `_GRID_STEPS` steps per group (a median would let the steps that
        every cost explains alike, e.g. cruising at the speed limit, decide). The
        receding-horizon objective is not convex in the weights; a start in the wrong basin can end at a
        bound (measured on SUMO drivers who minimise acceleration)."""
        import itertools

        sub = []
        for g in range(self.G):
            rows = np.flatnonzero(self.grp == g)
            if len(rows):
                sub.append(rows[np.unique(np.linspace(0, len(rows) - 1, min(_GRID_STEPS, len(rows))).round()
                                          .astype(int))])
        sub = np.concatenate(sub)
        grp = self.grp[sub]
        best = np.full(self.G, np.inf)
        out = w.copy()
        joint, rest = self.free[:_GRID_JOINT], self.free[_GRID_JOINT:]

        def keep_better(start, columns, point):
            """The groups whose score improves at ``point`` in ``columns`` (from ``start``) take it."""
            nonlocal best
            trial = start.copy()
            trial[:, columns] = np.clip(point, self.low, self.high)
            _, r, _ = self._solve(trial, sub, self.steps.init[sub])
            score = np.bincount(grp, weights=np.abs(r).max(axis=1), minlength=self.G)  # L1: every step counts
            take = score < best
            best = np.where(take, score, best)
            out[take] = trial[take]

        for point in itertools.product(_GRID, repeat=len(joint)):  # the first weights jointly
            keep_better(w, joint, point)
        for k in rest:  # each further one alone, from the best point so far
            base = out.copy()
            for value in _GRID:
                keep_better(base, [k], [value])
        return out

    def scale_and_nll(self, resid, counts):
        """Fitted sigma (G,) and negative log-likelihood (G,) of the final residuals (module doc)."""
        grp = self.grp
        n = np.maximum(counts * self.n_u, 1)
        has = counts > 0
        if self.loss == "gauss":
            sigma2 = np.maximum(np.bincount(grp, weights=np.sum(resid**2, axis=1), minlength=self.G) / n,
                                np.finfo(float).tiny)
            return np.sqrt(sigma2), np.where(has, 0.5 * n * (np.log(2 * np.pi * sigma2) + 1.0), 0.0)
        c = self._scale(resid, grp)
        a = np.abs(resid).max(axis=1)
        sigma = np.array([_MAD_SIGMA * np.median(a[grp == g]) if counts[g] else 0.0 for g in range(self.G)])
        nll = np.bincount(grp, weights=np.sum(np.log(np.pi * c[grp][:, None]) + np.log1p((resid / c[grp][:, None]) ** 2),
                                              axis=1), minlength=self.G)
        return sigma, np.where(has, nll, 0.0)
