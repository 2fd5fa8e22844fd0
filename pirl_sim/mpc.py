"""Model-predictive prediction under a learned linear cost.

For quadratic features the cost of a start x_0 and stacked controls U (length d = N n_u) is exactly

    C(U) = theta . f = 1/2 U^T A(theta) U + b(theta, x_0) . U + const,
    A = sum_k theta_k H_k,  b = sum_k theta_k (W_k x_0 + c_k),

so the unconstrained optimum is U* = -A^-1 b (`LQPredictor`, batched over starts and weights), and bounds on
states and controls make it a convex QP (`ConstrainedLQPredictor`), solved by DAQP through its own binding or
through casadi's ``conic`` interface (`BoxQP`). Both agree where no bound is active.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from .dynamics import LinearDynamics
from .features import FeatureSet
from .validation import is_positive_int

__all__ = ["QuadraticCost", "LQPredictor", "ConstrainedLQPredictor", "SequentialMPC", "BoxQP", "Bounds", "MAX_HORIZON"]


@dataclass(frozen=True)
class QuadraticCost:
    """The exact quadratic form of a quadratic `FeatureSet` over N steps of linear dynamics.

    Attributes
    ----------
    H : array (K, d, d)     Hessian of each feature in U
    W : array (K, d, n_x)   gradient of each feature at U = 0 is ``W_k x_0 + c_k``
    c : array (K, d)
    """

    dynamics: LinearDynamics
    features: FeatureSet
    n_steps: int
    H: np.ndarray = field(init=False, repr=False)
    W: np.ndarray = field(init=False, repr=False)
    c: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if int(self.n_steps) < 1:
            raise ValueError(f"n_steps must be >= 1, got {self.n_steps}")
        n_x = self.dynamics.n_x
        starts = np.vstack([np.zeros(n_x), np.eye(n_x)])
        H, b = self.features.quadratic_terms(self.dynamics, starts, int(self.n_steps))
        c = b[0]
        W = np.moveaxis(b[1:] - c[None], 0, -1)  # (K, d, n_x)
        for name, arr in (("H", H), ("W", W), ("c", c)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def dim(self) -> int:
        return self.H.shape[1]

    def terms(self, x0: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A (d, d) or (M, d, d) and b (M, d) for starts x0 (M, n_x) and weights (K,) or (M, K)."""
        x0 = np.atleast_2d(np.asarray(x0, dtype=float))
        theta = self.features.weights(theta)
        if theta.ndim == 1:
            A = np.tensordot(theta, self.H, axes=1)
            b = np.einsum("k,kdx,mx->md", theta, self.W, x0) + theta @ self.c
        else:
            if theta.shape[0] != x0.shape[0]:
                raise ValueError(f"got {theta.shape[0]} weight vectors for {x0.shape[0]} starts")
            A = np.einsum("mk,kij->mij", theta, self.H)
            b = np.einsum("mk,kdx,mx->md", theta, self.W, x0) + theta @ self.c
        return A, b


class LQPredictor:
    """Closed-form, batched MPC prediction for quadratic features (no constraints).

    Parameters
    ----------
    dynamics : LinearDynamics
    features : FeatureSet   (all features quadratic)
    """

    def __init__(self, dynamics: LinearDynamics, features: FeatureSet):
        if not features.quadratic:
            raise ValueError("LQPredictor needs quadratic features; use the sequential MPC for the others")
        self.dynamics = dynamics
        self.features = features
        self._costs: dict[int, QuadraticCost] = {}

    def cost(self, n_steps: int) -> QuadraticCost:
        n_steps = _check_horizon(n_steps)
        if n_steps not in self._costs:
            self._costs[n_steps] = QuadraticCost(self.dynamics, self.features, n_steps)
        return self._costs[n_steps]

    def controls(self, x0: np.ndarray, theta: np.ndarray, n_steps: int) -> np.ndarray:
        """Optimal controls, shape (M, N, n_u), for starts x0 (M, n_x) and weights (K,) shared or (M, K)."""
        x0 = _check_starts(x0, self.dynamics)
        cost = self.cost(n_steps)
        theta = self.features.weights(theta)
        if np.any(theta < 0):
            raise ValueError(f"weights must be >= 0 for a convex cost, got {theta}")
        A, b = cost.terms(x0, theta)
        if A.ndim == 2:
            L = np.linalg.cholesky(A)
            U = -_cho_solve(L, b.T).T
        else:
            U = -np.linalg.solve(A, b[..., None])[..., 0]
        return U.reshape(x0.shape[0], int(n_steps), self.dynamics.n_u)

    def predict(self, x0: np.ndarray, theta: np.ndarray, n_steps: int) -> np.ndarray:
        """Predicted states, shape (M, N + 1, n_x), starting with x0."""
        x0 = _check_starts(x0, self.dynamics)
        return self.dynamics.rollout(x0, self.controls(x0, theta, n_steps))


def _cho_solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    import scipy.linalg

    return scipy.linalg.cho_solve((L, True), B)


#: the longest horizon [steps] a predictor plans over, 1,000 s at dt = 0.1 s: the condensed matrices of a horizon
#: of N steps (`LinearDynamics.condensed`'s Gamma, N n_x x N n_u, and the K features' Hessians, K x (N n_u)^2) grow
#: with N^2 (N = 10,000, n_x = 3, n_u = 1, K = 3: about 5 GB), so longer ones are refused before any allocation
MAX_HORIZON = 10_000


def _check_horizon(n_steps) -> int:
    if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)):
        raise TypeError(f"horizon must be an integer number of steps, got {n_steps!r}")
    if n_steps < 1:
        raise ValueError(f"horizon must be >= 1 step, got {n_steps}")
    if n_steps > MAX_HORIZON:
        raise ValueError(f"horizon must be at most {MAX_HORIZON} steps (MAX_HORIZON: the MPC's matrices grow with "
                         f"the square of the horizon), got {n_steps}")
    return int(n_steps)


def _check_starts(x0: np.ndarray, dynamics: LinearDynamics) -> np.ndarray:
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    if x0.ndim != 2 or x0.shape[1] != dynamics.n_x:
        raise ValueError(f"start states must have shape (M, {dynamics.n_x}), got {x0.shape}")
    if not np.all(np.isfinite(x0)):
        raise ValueError(f"start states must be finite, got {x0[~np.isfinite(x0)][:3]}")
    return x0


@dataclass(frozen=True)
class Bounds:
    """Box bounds for the constrained MPC, by state and control name (``None`` = unbounded).

    Example: ``Bounds(state={"v [m/s]": (0.0, 15.0)}, control={"a [m/s^2]": (-3.0, 2.0)})``.
    """

    state: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    control: Mapping[str, tuple[float, float]] = field(default_factory=dict)

    def resolve(self, dynamics: LinearDynamics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Arrays (lower, upper) for states (n_x,) and controls (n_u,), checked against the names."""
        out = []
        for kind, mapping, names in (
            ("state", self.state, dynamics.state_names),
            ("control", self.control, dynamics.control_names),
        ):
            unknown = sorted(set(mapping) - set(names))
            if unknown:
                raise ValueError(f"unknown {kind} names {unknown}; allowed: {list(names)}")
            lo = np.full(len(names), -np.inf)
            hi = np.full(len(names), np.inf)
            for name, (a, b) in mapping.items():
                if not (a <= b) or np.isnan(a) or np.isnan(b):
                    raise ValueError(f"{kind} bound for {name!r} must satisfy low <= high, got ({a}, {b})")
                i = names.index(name)
                lo[i], hi[i] = a, b
            out += [lo, hi]
        return tuple(out)  # type: ignore[return-value]


class BoxQP:
    """Condensed QP over the stacked controls U with box bounds on states and controls.

    Solvers: ``"daqp"`` (default: the DAQP active-set solver through its own Python binding) or
    ``"casadi:<plugin>"`` (casadi's ``conic`` interface: ``casadi:daqp``, ``casadi:qpoases``, ...). Both give
    the same solutions (tested); the binding is faster because casadi converts every dense numpy matrix
    element by element (~0.1 ms for 40x40, measured in `benchmarks/bench_mpc.py`).

    ``min 1/2 U^T A U + b . U  s.t.  lo_x <= x_k(U) <= hi_x (bounded entries), lo_u <= u_k <= hi_u``,
    with ``x_k = Phi_k x_0 + Gamma_k U``. One solver per horizon, warm-started from its previous solution.
    """

    def __init__(self, dynamics: LinearDynamics, bounds: Bounds, solver: str = "daqp"):
        self.dynamics = dynamics
        self.solver = solver
        self._x_lo, self._x_hi, self._u_lo, self._u_hi = bounds.resolve(dynamics)
        if solver == "daqp":
            import daqp  # the solver's own Python binding: numpy in, no conversion layer

            self._daqp = daqp
        elif isinstance(solver, str) and solver.startswith("casadi:"):
            import casadi  # heavy: imported on use

            self._casadi = casadi
            if not casadi.has_conic(solver.split(":", 1)[1]):
                raise ValueError(f"casadi has no QP solver plugin {solver.split(':', 1)[1]!r}")
        else:
            raise ValueError(f"solver must be 'daqp' or 'casadi:<conic plugin>' (e.g. 'casadi:qpoases'), got {solver!r}")
        self._rows = np.flatnonzero(np.isfinite(self._x_lo) | np.isfinite(self._x_hi))
        self._rollout = _Rollouts(dynamics)
        self._solvers: dict[int, tuple] = {}
        self._warm: dict[int, np.ndarray] = {}

    def _setup(self, n_steps: int):
        if n_steps not in self._solvers:
            d = n_steps * self.dynamics.n_u
            _, gamma = self.dynamics.condensed(n_steps)
            A = gamma[:, self._rows, :, :].reshape(n_steps * len(self._rows), d)
            fixed = {
                "lo": np.tile(self._x_lo[self._rows], n_steps),
                "hi": np.tile(self._x_hi[self._rows], n_steps),
                "u_lo": np.tile(self._u_lo, n_steps),
                "u_hi": np.tile(self._u_hi, n_steps),
            }
            if self.solver == "daqp":
                from ctypes import c_int

                fixed["a"] = np.ascontiguousarray(A)
                fixed["sense"] = np.zeros(d + A.shape[0], dtype=c_int)
                self._solvers[n_steps] = (None, fixed)
            else:
                ca = self._casadi
                plugin = self.solver.split(":", 1)[1]
                opts: dict = {"error_on_fail": False}
                if plugin == "qpoases":
                    opts["printLevel"] = "none"
                elif plugin == "osqp":
                    opts["osqp"] = {"verbose": False, "eps_abs": 1e-9, "eps_rel": 1e-9}
                sparsity = {"h": ca.DM.ones(d, d).sparsity(), "a": ca.DM(np.ones_like(A)).sparsity()}
                # what does not change between solves is converted to casadi once (a dense numpy to DM
                # conversion costs ~0.1 ms per 40x40 matrix)
                fixed.update(a=ca.DM(A), lbx=ca.DM(fixed["u_lo"]), ubx=ca.DM(fixed["u_hi"]))
                self._solvers[n_steps] = (ca.conic("mpc", plugin, sparsity, opts), fixed)
        return self._solvers[n_steps]

    def violation(self, x0: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Largest bound violation of each row of a batch, shape (M,): 0 when feasible."""
        X = self._rollout(x0, U)[:, 1:]
        viol = np.maximum(self._x_lo - X, 0.0).max(axis=(1, 2)) if np.isfinite(self._x_lo).any() else 0.0
        viol = np.maximum(viol, np.maximum(X - self._x_hi, 0.0).max(axis=(1, 2)))
        viol = np.maximum(viol, np.maximum(self._u_lo - U, 0.0).max(axis=(1, 2)))
        return np.maximum(viol, np.maximum(U - self._u_hi, 0.0).max(axis=(1, 2)))

    def touches(self, x0: np.ndarray, U: np.ndarray, tol: float = 1e-7) -> np.ndarray:
        """Rows (M,) whose plan sits on a bound (an active set worth keeping when warm-starting)."""
        X = self._rollout(x0, U)[:, 1:]
        near = lambda v, lo, hi: (np.abs(v - lo) <= tol) | (np.abs(v - hi) <= tol)
        return near(X, self._x_lo, self._x_hi).any(axis=(1, 2)) | near(U, self._u_lo, self._u_hi).any(axis=(1, 2))

    def clip_start(self, x0: np.ndarray) -> np.ndarray:
        """Start states moved inside the state bounds (an estimate from noisy data can sit outside)."""
        return np.clip(x0, self._x_lo, self._x_hi)

    def solve_many(self, A: np.ndarray, b: np.ndarray, x0: np.ndarray, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
        """The QPs of many starts x0 (M, n_x) with Hessians A (M, d, d) and linear terms b (M, d): controls
        (M, d) (NaN where infeasible) and the mask (M,) of the feasible ones. The same solutions as `solve`
        row by row; with DAQP the bounds of every row are made at once and only the solver's own call is left
        in the loop (about 2.5x less time per QP of 15 controls)."""
        A, b, x0 = np.asarray(A, dtype=float), np.asarray(b, dtype=float), np.asarray(x0, dtype=float)
        M, d = b.shape
        out = np.full((M, d), np.nan)
        feasible = np.zeros(M, dtype=bool)
        if self.solver != "daqp":
            for m in range(M):
                try:
                    out[m] = self.solve(A[m], b[m], x0[m], n_steps)
                    feasible[m] = True
                except RuntimeError:
                    pass
            return out, feasible
        _, fixed = self._setup(n_steps)
        phi, _ = self.dynamics.condensed(n_steps)
        free = np.einsum("nij,mj->mni", phi, x0)[:, :, self._rows].reshape(M, -1)  # as solve's phi @ x0
        big = 1e30  # daqp's "no bound"
        upper = np.concatenate([np.broadcast_to(fixed["u_hi"], (M, d)), fixed["hi"] - free], axis=1).clip(-big, big)
        lower = np.concatenate([np.broadcast_to(fixed["u_lo"], (M, d)), fixed["lo"] - free], axis=1).clip(-big, big)
        A, b = np.ascontiguousarray(A), np.ascontiguousarray(b)
        a, sense, solve = fixed["a"], fixed["sense"], self._daqp.solve
        for m in range(M):
            u, _, flag, _ = solve(A[m], b[m], a, upper[m], lower[m], sense)
            if flag >= 1:
                out[m] = u
                feasible[m] = True
        if feasible.any():
            self._warm[n_steps] = out[np.flatnonzero(feasible)[-1]].copy()
        return out, feasible

    def solve(self, A: np.ndarray, b: np.ndarray, x0: np.ndarray, n_steps: int) -> np.ndarray:
        """Controls (d,) for one start x0 (n_x,). Raises RuntimeError when the bounds are infeasible."""
        solver, fixed = self._setup(n_steps)
        phi, _ = self.dynamics.condensed(n_steps)
        d = n_steps * self.dynamics.n_u
        free = (phi @ x0)[:, self._rows].reshape(-1)
        if self.solver == "daqp":
            big = 1e30  # daqp's "no bound"
            upper = np.concatenate([fixed["u_hi"], fixed["hi"] - free]).clip(-big, big)
            lower = np.concatenate([fixed["u_lo"], fixed["lo"] - free]).clip(-big, big)
            u, _, flag, _ = self._daqp.solve(
                np.ascontiguousarray(A), np.ascontiguousarray(b), fixed["a"], upper, lower, fixed["sense"]
            )
            ok, status = flag >= 1, f"daqp exit flag {flag}"
        else:
            sol = solver(
                h=self._casadi.DM(A),
                g=b,
                a=fixed["a"],
                lba=fixed["lo"] - free,
                uba=fixed["hi"] - free,
                lbx=fixed["lbx"],
                ubx=fixed["ubx"],
                x0=self._warm.get(n_steps, np.zeros(d)),
            )
            stats = solver.stats()
            ok, status = stats.get("success", True), stats.get("return_status")
            u = np.asarray(sol["x"]).ravel()
        if not ok:
            raise RuntimeError(
                f"QP solver {self.solver!r} failed for start {x0} ({status}); the bounds may be infeasible from this start"
            )
        u = np.asarray(u, dtype=float).ravel()
        self._warm[n_steps] = u
        return u


class ConstrainedLQPredictor:
    """MPC with box bounds on states and controls for quadratic features: one convex QP per start.

    The QP is condensed (variables: the stacked controls U); state bounds become linear constraints through
    ``X = Phi x_0 + Gamma U`` (`BoxQP`). Both this and `LQPredictor` give the same answer where no bound is
    active.

    Parameters
    ----------
    dynamics, features : as for `LQPredictor`
    bounds : Bounds
    solver : str
        ``"daqp"`` (default) or ``"casadi:<conic plugin>"`` (see `BoxQP`).
    """

    def __init__(self, dynamics: LinearDynamics, features: FeatureSet, bounds: Bounds, solver: str = "daqp"):
        self.dynamics = dynamics
        self.features = features
        self.bounds = bounds
        self._lq = LQPredictor(dynamics, features)
        self._qp = BoxQP(dynamics, bounds, solver)

    def controls(self, x0: np.ndarray, theta: np.ndarray, n_steps: int) -> np.ndarray:
        """Optimal bounded controls, shape (M, N, n_u); solved one start at a time."""
        x0 = _check_starts(x0, self.dynamics)
        n_steps = _check_horizon(n_steps)
        theta = self.features.weights(theta)
        cost = self._lq.cost(n_steps)
        out = np.empty((x0.shape[0], cost.dim))
        for m in range(x0.shape[0]):
            A, b = cost.terms(x0[m : m + 1], theta if theta.ndim == 1 else theta[m])
            out[m] = self._qp.solve(A, b[0], x0[m], n_steps)
        return out.reshape(x0.shape[0], n_steps, self.dynamics.n_u)

    def predict(self, x0: np.ndarray, theta: np.ndarray, n_steps: int) -> np.ndarray:
        x0 = _check_starts(x0, self.dynamics)
        return self.dynamics.rollout(x0, self.controls(x0, theta, n_steps))


_BATCHED_HALVINGS_MAX_ROWS = 16  #: line search: up to this many rows get all six halvings in one call
#: SequentialMPC: batches of at least this many starts take their unconstrained Newton steps by the Riccati
#: recursion (`_OuterExpansion.riccati`, O(N) per start but ~40 numpy calls per stage); smaller ones by dense
#: solves (measured crossover on the roundabout model, cold starts, N = 40: 50-100 starts; warm-started calls
#: stay dense, see `SequentialMPC`)
RICCATI_MIN_ROWS = 96
#: up to this many starts, `_OuterExpansion.newton_steps` runs its definiteness test and the exact steps in one
#: recursion over both (stacked); larger batches run them one after the other
_STACKED_RICCATI_MAX_ROWS = 256
#: SequentialMPC: larger batches of starts are planned this many at a time (PIRL-select's bank on five INTERACTION
#: files asks for ~500,000 plans at once: their dense Newton models alone would take ~2.5 GB per copy)
MAX_BATCH_ROWS = 8192


class _Rollouts:
    """``LinearDynamics.rollout`` as two matrix products with the condensed matrices flattened once per horizon
    (the einsum form costs several times more for the small batches of a receding-horizon step)."""

    def __init__(self, dynamics: LinearDynamics):
        self.dynamics = dynamics
        self._mats: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, x0: np.ndarray, U: np.ndarray) -> np.ndarray:
        """States (M, N + 1, n_x) from starts x0 (M, n_x) and controls U (M, N, n_u)."""
        M, N = U.shape[:2]
        if N not in self._mats:
            phi, gamma = self.dynamics.condensed(N)
            n_x = self.dynamics.n_x
            self._mats[N] = (np.ascontiguousarray(phi.reshape(N * n_x, n_x).T),
                             np.ascontiguousarray(gamma.reshape(N * n_x, -1).T))
        phi_t, gamma_t = self._mats[N]
        X = np.empty((M, N + 1, self.dynamics.n_x))
        X[:, 0] = x0
        X[:, 1:] = (x0 @ phi_t + U.reshape(M, -1) @ gamma_t).reshape(M, N, -1)
        return X


def _solve_pd(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solutions x (M, d) of A_m x_m = b_m for positive definite A (M, d, d) and b (M, d).

    One LAPACK ``dposv`` (Cholesky) per matrix: for the MPC's 30-40 unknowns this costs less than numpy's
    batched LU solve (measured 1.6 vs 2.1 ms for 108 matrices of 30 x 30, 0.08 vs 0.18 ms for 15). A matrix
    that is not positive definite after all is solved by LU (`numpy.linalg.solve`)."""
    from scipy.linalg import lapack

    out = np.empty(b.shape)
    posv = lapack.dposv
    for m in range(A.shape[0]):
        _, x, info = posv(A[m], b[m], lower=1)
        out[m] = x if info == 0 else np.linalg.solve(A[m], b[m])
    return out


def _pd_rows(H: np.ndarray) -> np.ndarray:
    """Mask (M,) of the matrices of a stack (M, d, d) that are not positive definite (Cholesky fails).

    One batched LAPACK call: numpy's Cholesky gufunc fills a matrix it cannot factor with NaN and only then
    raises, so it is called without the raise; numpy versions without that gufunc fall back to
    `pirl_sim.irl._cholesky_rows` (one factorisation per matrix after a failure).
    """
    try:
        from numpy.linalg import _umath_linalg

        with np.errstate(invalid="ignore", over="ignore", divide="ignore", under="ignore"):
            L = _umath_linalg.cholesky_lo(H, signature="d->d")
        return np.isnan(L[:, -1, -1]) | ~np.isfinite(L[:, -1, -1])
    except (ImportError, AttributeError, TypeError):  # pragma: no cover - other numpy builds
        from .irl import _cholesky_rows

        return _cholesky_rows(H)[1]


class _OuterExpansion:
    """Second-order model of the cost ``theta . f`` in the stacked controls, assembled by one matrix product (the
    Newton model of `SequentialMPC`; derivation: "The cost model and its features" page, The MPC).

    Parameters
    ----------
    dynamics : LinearDynamics
    features : FeatureSet          its reference feature is quadratic (the margin of the exact-Hessian test)
    n_steps : int                  horizon N [steps]
    """

    def __init__(self, dynamics: LinearDynamics, features: FeatureSet, n_steps: int):
        self.dynamics, self.features, self.N = dynamics, features, int(n_steps)
        n_x, n_u, N = dynamics.n_x, dynamics.n_u, self.N
        self.d, self.q = N * n_u, n_x + n_u
        _, gamma = dynamics.condensed(N)
        self.G = np.ascontiguousarray(gamma.reshape(N, n_x, self.d))  # d x_n / dU, n = 1..N
        self.Gflat = self.G.reshape(N * n_x, self.d)
        B = np.zeros((N, self.q, self.d))
        B[:, :n_x] = self.G
        for c in range(n_u):
            B[np.arange(N), n_x + c, np.arange(N) * n_u + c] = 1.0
        self.B = B
        self.quad = [k for k, f in enumerate(features.features) if f.quadratic]
        self.nonquad = [k for k, f in enumerate(features.features) if not f.quadratic]
        self.scale = np.array([1.0 / N if f.reduction == "mean" else 1.0 for f in features.features])
        ref = features.reference_index
        if ref not in self.quad:
            raise ValueError("the outer-product expansion needs a quadratic reference feature")
        self.ref_pos = self.quad.index(ref)
        # constant Hessians of the quadratic features (exact, from FeatureSet.derivatives at U = 0)
        zeros = np.zeros((1, N, n_u))
        der = features.derivatives(dynamics, dynamics.rollout(np.zeros((1, n_x)), zeros), zeros)
        self.Hq = np.ascontiguousarray(der.hess[0, self.quad].reshape(len(self.quad), self.d * self.d))
        H_ref = der.hess[0, ref]
        #: the reference feature's Hessian diagonal (d,) when it is diagonal, else None
        self.ref_diagonal = np.diag(H_ref).copy() if not np.any(H_ref - np.diag(np.diag(H_ref))) else None
        self._pairs: dict[tuple[int, int], np.ndarray] = {}
        self._stacks: dict[tuple, np.ndarray] = {}
        # constant stage Hessians of the quadratic features, 2 scale J^T J over (x_n, u_{n-1}): (K_q, N q^2)
        q = self.q
        Sq = np.zeros((len(self.quad), N, q, q))
        x0s, u0s = np.zeros((1, N, n_x)), np.zeros((1, N, n_u))
        for i, k in enumerate(self.quad):
            res = features.features[k].residual(x0s, u0s)
            p_ = res.jac_x.shape[-2]
            J = np.concatenate([np.broadcast_to(res.jac_x, (1, N, p_, n_x))[0],
                                np.broadcast_to(res.jac_u, (1, N, p_, n_u))[0]], axis=-1)  # (N, p, q)
            Sq[i] = 2.0 * self.scale[k] * np.einsum("npa,npb->nab", J, J)
        self.Sq = np.ascontiguousarray(Sq.reshape(len(self.quad), N * q * q))
        self.Sq_ref = Sq[self.ref_pos]
        self.ref_stage_index = ref
        self._maps = None

    def _pair(self, a: int, b: int) -> np.ndarray:
        """Outer products B_n,a B_n,b^T (+ the transpose for a != b), shape (N, d^2)."""
        if (a, b) not in self._pairs:
            O = np.einsum("ni,nj->nij", self.B[:, a], self.B[:, b])
            if a != b:
                O = O + np.swapaxes(O, 1, 2)
            self._pairs[(a, b)] = O.reshape(self.N, self.d * self.d)
        return self._pairs[(a, b)]

    def _stack(self, pairs: tuple[tuple[int, int], ...]) -> np.ndarray:
        """The right-hand matrix (P N + K_q, d^2) for the given pairs."""
        if pairs not in self._stacks:
            self._stacks[pairs] = np.ascontiguousarray(np.concatenate([self._pair(a, b) for a, b in pairs] + [self.Hq]))
        return self._stacks[pairs]

    def terms(self, X: np.ndarray, U: np.ndarray, theta: np.ndarray):
        """Per-feature values (M, K), the cost gradient (M, d), and the stage coefficients of the Hessians.

        X (M, N + 1, n_x) states, U (M, N, n_u) controls, theta (M, K) weights (>= 0). The coefficients are
        two mappings pair (a, b) -> (M, N), a <= b over the stage basis: ``jj`` sums theta_k scale_k 2 J^T J of
        the non-quadratic features, ``ww`` their theta_k scale_k 2 r . d2r (state block)."""
        values, sigma, jj, ww = self.stage_terms(X, U, theta)
        return values, self.chain(sigma), jj, ww

    def chain(self, sigma: np.ndarray) -> np.ndarray:
        """The gradient in U (M, d) of stage gradients ``sigma`` (M, N, q) in (x_n, u_{n-1})."""
        M, N, n_x = sigma.shape[0], self.N, self.dynamics.n_x
        return np.ascontiguousarray(sigma[:, :, :n_x]).reshape(M, N * n_x) @ self.Gflat + sigma[:, :, n_x:].reshape(M, self.d)

    def stage_terms(self, X: np.ndarray, U: np.ndarray, theta: np.ndarray, per_feature: bool = False):
        """As `terms`, with the cost gradient per stage: ``sigma`` (M, N, q), the gradient of theta . f in
        (x_n, u_{n-1}) for n = 1..N (`chain` maps it to U). One pass over the features, one product at the end.
        ``per_feature``: ``sigma`` (M, K, N, q) holds each feature's own stage gradient (unweighted) instead."""
        M = U.shape[0]
        N, n_x, n_u = self.N, self.dynamics.n_x, self.dynamics.n_u
        x, u = X[:, 1:, :], U
        values = np.empty((M, self.features.n_features))
        sigma = np.zeros((M, self.features.n_features, N, self.q) if per_feature else (M, N, self.q))
        jj: dict[tuple[int, int], np.ndarray] = {}
        ww: dict[tuple[int, int], np.ndarray] = {}

        def add(out, key, value):
            out[key] = value if key not in out else out[key] + value

        for k, feat in enumerate(self.features.features):
            res = feat.residual(x, u)
            r, Jx, Ju = res.r, res.jac_x, res.jac_u
            scale = self.scale[k]
            values[:, k] = scale * np.sum(r**2, axis=(1, 2))
            w = (2.0 * scale) * theta[:, k, None]  # (M, 1)
            # (M, N, p, 1): 2 scale theta_k r, or 2 scale r for the feature's own gradient
            wr = ((2.0 * scale) * r if per_feature else w[:, :, None] * r)[..., None]
            target = sigma[:, k] if per_feature else sigma
            # the columns of J = [Jx, Ju] (over the stage basis) that are non-zero somewhere (as the residual
            # states them, or found)
            nz_x = (np.asarray(res.x_support, dtype=int) if res.x_support is not None
                    else np.flatnonzero(np.any(Jx, axis=tuple(range(Jx.ndim - 1)))))
            nz_u = np.flatnonzero(np.any(Ju, axis=tuple(range(Ju.ndim - 1))))
            if res.x_support is not None and len(nz_x):
                target[:, :, nz_x] += np.sum(wr * Jx[..., nz_x], axis=2)
            elif len(nz_x):
                target[:, :, :n_x] += np.sum(wr * Jx, axis=2)
            if len(nz_u):
                target[:, :, n_x:] += np.sum(wr * Ju, axis=2)
            if feat.quadratic:
                continue
            p = r.shape[2]
            cols = [(a, np.broadcast_to(Jx[..., a], (M, N, p))) for a in nz_x]
            cols += [(n_x + c, np.broadcast_to(Ju[..., c], (M, N, p))) for c in nz_u]
            for i, (a, Ja) in enumerate(cols):
                for bb, Jb in cols[i:]:
                    prod = Ja[..., 0] * Jb[..., 0] if p == 1 else np.einsum("mnp,mnp->mn", Ja, Jb)
                    add(jj, (int(a), int(bb)), w * prod)
            if res.hess_scale is not None and res.hess_x is None:  # h_ab = hess_scale Jx_a Jx_b (no n_x x n_x array)
                for i, a in enumerate(nz_x):
                    for bb in nz_x[i:]:
                        h = res.hess_scale * Jx[..., a] * Jx[..., bb]
                        add(ww, (int(a), int(bb)), w * (r[..., 0] * h[..., 0] if p == 1 else np.einsum("mnp,mnp->mn", r, h)))
            elif res.hess_x is not None:
                hx = res.hess_x
                nz = np.any(hx, axis=tuple(range(hx.ndim - 2)))  # (n_x, n_x)
                for a, bb in zip(*np.nonzero(np.triu(nz))):
                    h = hx[..., a, bb]
                    add(ww, (int(a), int(bb)), w * (r[..., 0] * h[..., 0] if p == 1 else np.einsum("mnp,mnp->mn", r, h)))
        return values, sigma, jj, ww

    def stage_hessians(self, theta: np.ndarray, jj: dict, ww: dict | None, ref_share: float) -> np.ndarray:
        """Stage Hessians S (M, N, q, q) of the cost in (x_n, u_{n-1}): the coefficients of `terms` (``ww``
        None: Gauss-Newton) and the quadratic features' constant stage Hessians, the reference feature's
        weighted by ``ref_share``; the cost Hessian in U is ``sum_n B_n^T S_n B_n`` (`hessians`)."""
        tq = theta[:, self.quad].copy()
        tq[:, self.ref_pos] *= ref_share
        M, q = theta.shape[0], self.q
        S = (tq @ self.Sq).reshape(M, self.N, q, q)
        for coef in (jj, ww or {}):
            for (a, b), c in coef.items():
                S[:, :, a, b] += c
                if a != b:
                    S[:, :, b, a] += c
        return S

    def riccati(self, S: np.ndarray, sigma: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """Newton steps by a Riccati recursion over the stages, O(N) per start instead of a dense d x d solve.

        Minimises ``1/2 dU^T H dU + g . dU`` with H = sum_n B_n^T S_n B_n and g = `chain` (sigma) for stage Hessians
        S (M, N, q, q) and gradients sigma (M, N, q); sigma None only tests definiteness ("The cost model and its
        features" page, The MPC).

        Returns
        -------
        ok : array (M,) of bool                  H is positive definite (every Q_uu is)
        step : array (M, N, n_u) or None         -H^-1 g where ok (other rows hold no meaningful values)
        """
        M, N = S.shape[:2]
        n_x, n_u, q = self.dynamics.n_x, self.dynamics.n_u, self.q
        Tc, TPc, F, FP = self._riccati_maps
        nxx, nux = n_x * n_x, n_u * n_x
        SQ = (S.reshape(M * N, q * q) @ Tc).reshape(M, N, -1)  # F' S_n F for every stage: [xx | ux | uu]
        SG = None if sigma is None else (sigma.reshape(M * N, q) @ F).reshape(M, N, q)  # F' sigma_n
        P = np.zeros((M, nxx))
        p = np.zeros((M, n_x))
        pivots = np.empty((N, M)) if n_u == 1 else None
        ok = np.ones(M, dtype=bool)
        gains = []
        with np.errstate(all="ignore"):
            for n in range(N - 1, -1, -1):
                Q = SQ[:, n] + P @ TPc
                Qux = Q[:, nxx:nxx + nux]
                if n_u == 1:
                    quu = Q[:, nxx + nux]
                    pivots[n] = quu  # type: ignore[index]
                    neg_inv = -1.0 / quu
                    K = Qux * neg_inv[:, None]  # (M, n_x)
                    P = Q[:, :nxx] + (Qux[:, :, None] * K[:, None, :]).reshape(M, nxx)
                    if SG is not None:
                        qv = SG[:, n] + p @ FP
                        kk = qv[:, n_x:] * neg_inv[:, None]  # (M, 1)
                        p = qv[:, :n_x] + Qux * kk
                        gains.append((K, kk))
                else:
                    Quu = Q[:, nxx + nux:].reshape(M, n_u, n_u)
                    Qux = Qux.reshape(M, n_u, n_x)
                    ok &= ~_pd_rows(Quu)
                    Quu = np.where(ok[:, None, None], Quu, np.eye(n_u))
                    K = -np.linalg.solve(Quu, Qux)  # (M, n_u, n_x)
                    QxuT = np.swapaxes(Qux, 1, 2)
                    P = Q[:, :nxx] + (QxuT @ K).reshape(M, nxx)
                    if SG is not None:
                        qv = SG[:, n] + p @ FP
                        kk = -np.linalg.solve(Quu, qv[:, n_x:, None])[..., 0]
                        p = qv[:, :n_x] + (QxuT @ kk[..., None])[..., 0]
                        gains.append((K, kk))
            if pivots is not None:
                ok = (pivots > 0.0).all(axis=0)  # type: ignore[assignment]
            if SG is None:
                return ok, None
            A_t, B_t = self.dynamics.A.T, self.dynamics.B.T
            step = np.empty((M, N, n_u))
            dx = np.zeros((M, n_x))
            for n, (K, kk) in enumerate(reversed(gains)):
                if n_u == 1:
                    du = np.einsum("mi,mi->m", K, dx)[:, None] + kk
                else:
                    du = (K @ dx[:, :, None])[..., 0] + kk
                step[:, n] = du
                dx = dx @ A_t + du @ B_t
        return ok, step

    @property
    def _riccati_maps(self):
        """Constant maps of the recursion. With the stage map F = [[A, B], [0, I]] (q, q) from
        (x_{n-1}, u_{n-1}) to (x_n, u_{n-1}), vec(F' S F) = vec(S) (F (x) F): Tc (q^2, n_x^2 + n_u n_x + n_u^2)
        keeps the columns of the state block, the control-state block and the control block of F' S F (it is
        symmetric), TPc the rows of Tc that a state-block matrix P feeds; F, and FP its state rows (n_x, q)."""
        if self._maps is None:
            n_x, n_u, q = self.dynamics.n_x, self.dynamics.n_u, self.q
            F = np.zeros((q, q))
            F[:n_x, :n_x], F[:n_x, n_x:], F[n_x:, n_x:] = self.dynamics.A, self.dynamics.B, np.eye(n_u)
            T = np.kron(F, F)
            xx = [a * q + b for a in range(n_x) for b in range(n_x)]
            ux = [a * q + b for a in range(n_x, q) for b in range(n_x)]
            uu = [a * q + b for a in range(n_x, q) for b in range(n_x, q)]
            Tc = T[:, xx + ux + uu]
            self._maps = (np.ascontiguousarray(Tc), np.ascontiguousarray(Tc[xx]), F, np.ascontiguousarray(F[:n_x]))
        return self._maps

    def newton_steps(self, X: np.ndarray, U: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Newton steps (M, N, n_u) of the cost at U and the cost (M,) there, by `riccati`: the same steps as
        `SequentialMPC._model` and a dense solve (the exact Hessian where it stays at least half as curved as
        the reference term alone, the Gauss-Newton one elsewhere), to rounding."""
        values, sigma, jj, ww = self.stage_terms(X, U, theta)
        M = U.shape[0]
        S = self.stage_hessians(theta, jj, ww, 0.5)  # the test matrices: exact, half the reference term
        margin = 0.5 * theta[:, self.ref_stage_index, None, None, None] * self.Sq_ref
        gauss_newton = lambda rows: self.stage_hessians(theta[rows], {key: c[rows] for key, c in jj.items()},
                                                        None, 1.0)
        if M <= _STACKED_RICCATI_MAX_ROWS:
            # one recursion over the test and the exact matrices together (each numpy call's fixed cost
            # dominates at this size); Gauss-Newton steps for the rows that fail the test, in a second one
            ok, step = self.riccati(np.concatenate([S, S + margin]), np.concatenate([sigma, sigma]))
            step = step[M:]  # type: ignore[index]
            bad = np.flatnonzero(~ok[:M])
            if len(bad):
                step[bad] = self.riccati(gauss_newton(bad), sigma[bad])[1]
        else:
            exact, _ = self.riccati(S, None)
            S += margin
            bad = np.flatnonzero(~exact)
            if len(bad):  # Gauss-Newton where the exact Hessian is not safely positive definite
                S[bad] = gauss_newton(bad)
            _, step = self.riccati(S, sigma)
        return step, np.einsum("mk,mk->m", theta, values)  # type: ignore[return-value]

    def hessians(self, theta: np.ndarray, jj: dict, ww: dict | None, ref_share: float,
                 rows: np.ndarray | None = None) -> np.ndarray:
        """Cost Hessians (M, d, d) from the coefficients of `terms` (``ww`` None: Gauss-Newton) and the quadratic
        features' Hessians, the reference feature's weighted by ``ref_share``; ``rows`` selects starts."""
        sel = (lambda c: c) if rows is None else (lambda c: c[rows])
        coef = {key: sel(c) for key, c in jj.items()}
        for key, c in (ww or {}).items():
            coef[key] = sel(c) if key not in coef else coef[key] + sel(c)
        pairs = tuple(sorted(coef))
        tq = sel(theta)[:, self.quad]  # their Hessians carry their scale already
        tq[:, self.ref_pos] *= ref_share
        stacked = np.concatenate([coef[key] for key in pairs] + [tq], axis=1)
        return (stacked @ self._stack(pairs)).reshape(stacked.shape[0], self.d, self.d)


class SequentialMPC:
    """MPC for features that are not quadratic in the controls (e.g. a desired speed that depends on position).

    Batched Newton steps on the exact cost; starts that break a bound are re-solved by bounded QPs (`BoxQP`), and
    an infeasible one keeps its unconstrained solution (``n_infeasible``). The scheme: "The cost model and its
    features" page, The MPC.

    Parameters
    ----------
    dynamics, features, bounds : LinearDynamics, FeatureSet, Bounds or None
    n_iter, tol : int, float         most Newton iterations; stop when no control moves more than ``tol``
    n_qp_iter, qp_tol : int, float   most bounded QPs per start; stop when no control moves more than ``qp_tol``
    solver : str                     QP solver of the bounded QPs (`BoxQP`)
    assembly : {"outer", "stagewise"}   Hessians from tabulated stage outer products, or `FeatureSet.derivatives`
    riccati_rows : int or None       cold-started batches of at least this many starts use a Riccati recursion
    max_rows : int                   larger batches of starts are planned in batches of this many (the kept Newton
                                     models take (max_rows, N n_u, N n_u) floats; the plans are those of one batch)
    """

    def __init__(
        self,
        dynamics,
        features,
        bounds: Bounds | None = None,
        *,
        n_iter: int = 10,
        n_qp_iter: int = 4,
        tol: float = 1e-6,
        qp_tol: float = 1e-2,
        solver: str = "daqp",
        assembly: str = "outer",
        riccati_rows: int | None = RICCATI_MIN_ROWS,
        max_rows: int = MAX_BATCH_ROWS,
    ):
        if not is_positive_int(max_rows):
            raise ValueError(f"max_rows must be a positive integer, got {max_rows!r}")
        self.max_rows = int(max_rows)
        if assembly not in ("outer", "stagewise"):
            raise ValueError(f"assembly must be 'outer' or 'stagewise', got {assembly!r}")
        if riccati_rows is not None and not is_positive_int(riccati_rows):
            raise ValueError(f"riccati_rows must be a positive integer or None, got {riccati_rows!r}")
        self.riccati_rows = None if riccati_rows is None else int(riccati_rows)
        self.assembly = assembly
        self._expansions: dict[int, _OuterExpansion | None] = {}
        self._rollout = _Rollouts(dynamics) if assembly == "outer" else dynamics.rollout
        self.tol = float(tol)
        self.qp_tol = float(qp_tol)
        for name, value in (("n_iter", n_iter), ("n_qp_iter", n_qp_iter)):
            if not is_positive_int(value):
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        self.n_qp_iter = int(n_qp_iter)
        self.dynamics = dynamics
        self.features = features
        self.bounds = bounds
        self.n_iter = int(n_iter)
        self._qp = BoxQP(dynamics, bounds, solver) if bounds is not None else None
        self.n_qp = 0
        self.n_infeasible = 0

    def _cost(self, x0, U, theta):
        return np.einsum("mk,mk->m", theta, self.features.values(self._rollout(x0, U), U))

    def _expansion(self, n_steps: int) -> _OuterExpansion | None:
        if self.assembly != "outer":
            return None
        if n_steps not in self._expansions:
            ref = self.features.features[self.features.reference_index]
            self._expansions[n_steps] = (_OuterExpansion(self.dynamics, self.features, n_steps)
                                         if ref.quadratic else None)
        return self._expansions[n_steps]

    def _model(self, x0, U, theta):
        """Newton model at U: A (M, d, d) positive definite and b with the model 1/2 U'AU + b'U, and the cost
        (M,) at U.

        The exact Hessian where it is safely positive definite (quadratic convergence), the Gauss-Newton one
        elsewhere (positive semi-definite, and definite as soon as the control-effort feature has weight).
        """
        exp = self._expansion(U.shape[1])
        if exp is None:
            return self._model_stagewise(x0, U, theta)
        X = self._rollout(x0, U)
        values, g, jj, ww = exp.terms(X, U, theta)
        # exact Hessian only where it stays at least half as curved as the control-effort term alone
        # (as in `_model_stagewise`): the test matrix A - margin is assembled first, then the margin added
        A = exp.hessians(theta, jj, ww, 0.5)
        M, d = A.shape[:2]
        bad = _pd_rows(A)
        half_ref = 0.5 * theta[:, self.features.reference_index]
        if exp.ref_diagonal is not None:  # a control-effort Hessian is diagonal: add it on the diagonal only
            A.reshape(M, d * d)[:, ::d + 1] += np.multiply.outer(half_ref, exp.ref_diagonal)
        else:
            A += np.multiply.outer(half_ref, exp.Hq[exp.ref_pos]).reshape(M, d, d)
        if bad.any():
            A[bad] = exp.hessians(theta, jj, None, 1.0, rows=bad)
        u = U.reshape(M, -1)
        return A, g - np.einsum("mij,mj->mi", A, u), np.einsum("mk,mk->m", theta, values)

    def _model_stagewise(self, x0, U, theta):
        """`_model` through `FeatureSet.derivatives` (``assembly="stagewise"``, the previous path).

        The exact Hessian where it is safely positive definite (quadratic convergence), the Gauss-Newton one
        elsewhere (positive semi-definite, and definite as soon as the control-effort feature has weight).
        """
        from .irl import _cholesky_rows

        X = self.dynamics.rollout(x0, U)
        der = self.features.derivatives(self.dynamics, X, U)
        g = (theta[:, None, :] @ der.grad)[:, 0]
        M, K, d, _ = der.hess.shape
        A = (theta[:, None, :] @ der.hess.reshape(M, K, d * d)).reshape(M, d, d)
        # exact Hessian only where it stays at least half as curved as the control-effort term alone;
        # near-singular exact Hessians give huge Newton steps
        ref = self.features.reference_index
        margin = 0.5 * theta[:, ref, None, None] * np.broadcast_to(der.hess[:, ref], A.shape)
        _, bad = _cholesky_rows(A - margin)
        if bad.any():
            gn = self.features.derivatives(self.dynamics, X[bad], U[bad], gauss_newton=True)
            A[bad] = np.einsum("mk,mkij->mij", theta[bad], gn.hess)
        u = U.reshape(U.shape[0], -1)
        return A, g - np.einsum("mij,mj->mi", A, u), np.einsum("mk,mk->m", theta, der.values)

    def controls(self, x0: np.ndarray, theta: np.ndarray, n_steps: int, init: np.ndarray | None = None) -> np.ndarray:
        """Controls (M, N, n_u) minimising theta . f from each start x0 (M, n_x).

        ``init`` (M, N, n_u) warm-starts the iteration, e.g. with the previous plan shifted by one step.
        """
        x0 = _check_starts(x0, self.dynamics)
        n_steps = _check_horizon(n_steps)
        theta = self.features.weights(theta)
        if np.any(theta < 0):
            raise ValueError(f"weights must be >= 0, got {theta}")
        M = x0.shape[0]
        theta = np.broadcast_to(theta, (M, self.features.n_features))
        if init is None:
            U = np.zeros((M, n_steps, self.dynamics.n_u))
        else:
            U = np.array(init, dtype=float)
            if U.shape != (M, n_steps, self.dynamics.n_u) or not np.all(np.isfinite(U)):
                raise ValueError(f"init must be finite with shape {(M, n_steps, self.dynamics.n_u)}, got {U.shape}")
        if M > self.max_rows:  # independent starts: in batches, so the kept Newton models stay bounded in memory
            return np.concatenate([self.controls(x0[lo:lo + self.max_rows], theta[lo:lo + self.max_rows], n_steps,
                                                 None if init is None else U[lo:lo + self.max_rows])
                                   for lo in range(0, M, self.max_rows)])
        if self._qp is not None:
            x0 = self._qp.clip_start(x0)
        todo = np.arange(M)
        on_bounds = np.zeros(M, dtype=bool)
        if init is not None and self._qp is not None:
            # a warm start that sits on a bound keeps its active set: straight to the bounded QPs
            on_bounds = self._qp.touches(x0, U)
            todo = todo[~on_bounds]
        # Newton models at the current controls, kept per start until its controls change: the first
        # expansion serves the first Newton step and the bounded QPs of the starts that begin on a bound
        d = n_steps * self.dynamics.n_u
        cost = np.empty(M)
        fresh = np.zeros(M, dtype=bool)
        # "A" (M, d, d) and "b" (M, d): the kept models, allocated when first needed
        at = {}  # type: ignore[var-annotated]

        def model(rows):
            stale = rows[~fresh[rows]]
            if len(stale):
                A_new, b_new, cost[stale] = self._model(x0[stale], U[stale], theta[stale])
                if len(stale) == M and not at:  # every start, in order: keep these arrays themselves
                    at["A"], at["b"] = A_new, b_new
                else:
                    if not at:
                        at["A"], at["b"] = np.empty((M, d, d)), np.empty((M, d))
                    at["A"][stale], at["b"][stale] = A_new, b_new
                fresh[stale] = True
                if len(stale) == len(rows):  # all new: no second gather
                    return A_new, b_new
            return at["A"][rows], at["b"][rows]

        exp = self._expansion(n_steps)

        # the Riccati recursion pays off over several Newton iterations of a large batch (cold starts); a
        # warm-started batch takes one or two steps and its bounded QPs need the dense models anyway
        riccati = exp is not None and self.riccati_rows is not None and init is None

        def newton(rows):
            """Full Newton steps (len(rows), N, n_u) at the current controls; sets their costs."""
            if riccati and len(rows) >= self.riccati_rows:
                step, cost[rows] = exp.newton_steps(self._rollout(x0[rows], U[rows]), U[rows], theta[rows])
                return step
            A, b = model(rows)
            return -_solve_pd(A, b).reshape((len(rows),) + U.shape[1:]) - U[rows]

        if not riccati or len(todo) < self.riccati_rows:  # type: ignore[operator]
            model(np.arange(M))
        for _ in range(self.n_iter):
            if not len(todo):
                break
            full = newton(todo)
            # backtracking: halve the Newton step where it does not lower the cost (at most 6 times). The full
            # steps are evaluated first; where that is worse, the halvings are evaluated one at a time for the
            # rows still worse, or, for a few rows (where each call's fixed cost dominates), all six in one
            # batched call, taking the longest step that is not worse (the same choice)
            alpha = np.ones(len(todo))
            trial = U[todo] + full
            trial_cost = self._cost(x0[todo], trial, theta[todo])
            limit = cost[todo] + 1e-12 * np.abs(cost[todo])
            worse = np.flatnonzero(trial_cost > limit)
            if 0 < len(worse) <= _BATCHED_HALVINGS_MAX_ROWS:
                halves = 0.5 ** np.arange(1, 7)  # (6,)
                rows = todo[worse]
                cand = U[rows][:, None] + halves[None, :, None, None] * full[worse][:, None]  # (W, 6, N, n_u)
                cand_cost = self._cost(np.repeat(x0[rows], 6, axis=0), cand.reshape((-1,) + U.shape[1:]),
                                       np.repeat(theta[rows], 6, axis=0)).reshape(len(rows), 6)
                ok = ~(cand_cost > limit[worse, None])
                first = np.where(ok.any(axis=1), ok.argmax(axis=1), 5)  # the last halving when none is better
                pick = np.arange(len(rows))
                alpha[worse] = halves[first]
                trial[worse] = cand[pick, first]
                trial_cost[worse] = cand_cost[pick, first]
            else:
                for _half in range(6):
                    if not len(worse):
                        break
                    alpha[worse] /= 2.0
                    rows = todo[worse]
                    trial[worse] = U[rows] + alpha[worse, None, None] * full[worse]
                    trial_cost[worse] = self._cost(x0[rows], trial[worse], theta[rows])
                    worse = worse[trial_cost[worse] > limit[worse]]
            accept = ~(trial_cost > limit)
            step = np.where(accept, alpha * np.max(np.abs(full), axis=(1, 2)), 0.0)
            U[todo[accept]] = trial[accept]
            fresh[todo[accept]] = False
            cost[todo[accept]] = trial_cost[accept]
            todo = todo[step > self.tol]
            if not len(todo):
                break
        if self._qp is None:
            return U
        bad = np.flatnonzero((self._qp.violation(x0, U) > 1e-9) | on_bounds)
        for _ in range(self.n_qp_iter):
            if not len(bad):
                break
            A, b = model(bad)  # one batched expansion for all of them
            sol, feasible = self._qp.solve_many(A, b, x0[bad], n_steps)  # one QP per start
            self.n_qp += int(feasible.sum())
            self.n_infeasible += int((~feasible).sum())
            rows = bad[feasible]
            new = sol[feasible].reshape((len(rows),) + U.shape[1:])
            moved = np.zeros(len(bad))
            moved[feasible] = np.max(np.abs(new - U[rows]), axis=(1, 2), initial=0.0)
            U[rows] = new
            fresh[rows] = False
            bad = bad[moved > self.qp_tol]
        return U

    def predict(self, x0: np.ndarray, theta: np.ndarray, n_steps: int, init: np.ndarray | None = None) -> np.ndarray:
        """Predicted states (M, N + 1, n_x); row 0 is the (possibly bound-clipped) start."""
        x0 = _check_starts(x0, self.dynamics)
        if self._qp is not None:
            x0 = self._qp.clip_start(x0)
        return self.dynamics.rollout(x0, self.controls(x0, theta, n_steps, init))
