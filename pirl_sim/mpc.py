"""Model-predictive prediction under a learned linear cost.

For quadratic features the cost of a start x_0 and stacked controls U (length d = N n_u) is exactly

    C(U) = theta . f = 1/2 U^T A(theta) U + b(theta, x_0) . U + const,
    A = sum_k theta_k H_k,  b = sum_k theta_k (W_k x_0 + c_k),

so the unconstrained optimum is U* = -A^-1 b (`LQPredictor`, batched over starts and weights), and bounds on
states and controls make it a convex QP solved through casadi's ``conic`` interface (`ConstrainedLQPredictor`,
daqp by default, warm-started from the previous solution). Both agree where no bound is active.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from .dynamics import LinearDynamics
from .features import FeatureSet

__all__ = ["QuadraticCost", "LQPredictor", "ConstrainedLQPredictor", "SequentialMPC", "BoxQP", "Bounds"]


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


def _check_horizon(n_steps) -> int:
    if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)):
        raise TypeError(f"horizon must be an integer number of steps, got {n_steps!r}")
    if n_steps < 1:
        raise ValueError(f"horizon must be >= 1 step, got {n_steps}")
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
    """Condensed QP over the stacked controls U with box bounds on states and controls, via casadi ``conic``.

    ``min 1/2 U^T A U + b . U  s.t.  lo_x <= x_k(U) <= hi_x (bounded entries), lo_u <= u_k <= hi_u``,
    with ``x_k = Phi_k x_0 + Gamma_k U``. One solver per horizon, warm-started from its previous solution.
    """

    def __init__(self, dynamics: LinearDynamics, bounds: Bounds, solver: str = "daqp"):
        import casadi  # heavy: imported on use

        self._casadi = casadi
        self.dynamics = dynamics
        self.solver = solver
        self._x_lo, self._x_hi, self._u_lo, self._u_hi = bounds.resolve(dynamics)
        if not casadi.has_conic(solver):
            raise ValueError(f"casadi has no QP solver plugin {solver!r}")
        self._rows = np.flatnonzero(np.isfinite(self._x_lo) | np.isfinite(self._x_hi))
        self._solvers: dict[int, tuple] = {}
        self._warm: dict[int, np.ndarray] = {}

    def _setup(self, n_steps: int):
        if n_steps not in self._solvers:
            ca = self._casadi
            d = n_steps * self.dynamics.n_u
            _, gamma = self.dynamics.condensed(n_steps)
            A = gamma[:, self._rows, :, :].reshape(n_steps * len(self._rows), d)
            opts: dict = {"error_on_fail": False}
            if self.solver == "qpoases":
                opts["printLevel"] = "none"
            elif self.solver == "osqp":
                opts["osqp"] = {"verbose": False, "eps_abs": 1e-9, "eps_rel": 1e-9}
            sparsity = {"h": ca.DM.ones(d, d).sparsity(), "a": ca.DM(np.ones_like(A)).sparsity()}
            self._solvers[n_steps] = (ca.conic("mpc", self.solver, sparsity, opts), A)
        return self._solvers[n_steps]

    def violation(self, x0: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Largest bound violation of each row of a batch, shape (M,): 0 when feasible."""
        X = self.dynamics.rollout(x0, U)[:, 1:]
        viol = np.maximum(self._x_lo - X, 0.0).max(axis=(1, 2)) if np.isfinite(self._x_lo).any() else 0.0
        viol = np.maximum(viol, np.maximum(X - self._x_hi, 0.0).max(axis=(1, 2)))
        viol = np.maximum(viol, np.maximum(self._u_lo - U, 0.0).max(axis=(1, 2)))
        return np.maximum(viol, np.maximum(U - self._u_hi, 0.0).max(axis=(1, 2)))

    def clip_start(self, x0: np.ndarray) -> np.ndarray:
        """Start states moved inside the state bounds (an estimate from noisy data can sit outside)."""
        return np.clip(x0, self._x_lo, self._x_hi)

    def solve(self, A: np.ndarray, b: np.ndarray, x0: np.ndarray, n_steps: int) -> np.ndarray:
        """Controls (d,) for one start x0 (n_x,). Raises RuntimeError when the bounds are infeasible."""
        solver, Acon = self._setup(n_steps)
        phi, _ = self.dynamics.condensed(n_steps)
        d = n_steps * self.dynamics.n_u
        free = (phi @ x0)[:, self._rows].reshape(-1)
        sol = solver(
            h=A,
            g=b,
            a=Acon,
            lba=np.tile(self._x_lo[self._rows], n_steps) - free,
            uba=np.tile(self._x_hi[self._rows], n_steps) - free,
            lbx=np.tile(self._u_lo, n_steps),
            ubx=np.tile(self._u_hi, n_steps),
            x0=self._warm.get(n_steps, np.zeros(d)),
        )
        stats = solver.stats()
        if not stats.get("success", True):
            raise RuntimeError(
                f"QP solver {self.solver!r} failed for start {x0} ({stats.get('return_status')}); "
                "the bounds may be infeasible from this start"
            )
        u = np.asarray(sol["x"]).ravel()
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
        A casadi conic plugin (``"daqp"`` default, ``"qpoases"``, ``"osqp"``, ...).
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


class SequentialMPC:
    """MPC for features that are not quadratic in the controls (e.g. a desired speed that depends on position).

    Sequential scheme: starting from zero controls, the cost is expanded to second order around the current
    trajectory (exact Hessian, shifted where it is not positive definite), the quadratic model is minimised,
    and the step repeated until the controls move less than ``tol`` or ``n_iter`` steps were taken. Unconstrained steps are
    batched closed-form solves over all starts; with `Bounds`, the starts whose unconstrained solution breaks a
    bound are re-solved as ``n_qp_iter`` bounded QPs (`BoxQP`, casadi ``conic``), linearised first at the
    unconstrained optimum (one QP is enough where the bounds move s little; raise it for more accuracy). Starts outside the state
    bounds are first moved inside them (`BoxQP.clip_start`); if the bounded QP is still infeasible the
    unconstrained solution is kept and counted in ``n_infeasible``.

    Parameters
    ----------
    dynamics : LinearDynamics
    features : FeatureSet
    bounds : Bounds or None
    n_iter : int     most unconstrained Newton iterations
    tol : float      stop when no control moves more than this [control units]
    n_qp_iter : int  bounded QP iterations for starts whose unconstrained solution breaks a bound
    solver : str     casadi conic plugin for the bounded QPs
    """

    def __init__(
        self,
        dynamics,
        features,
        bounds: Bounds | None = None,
        *,
        n_iter: int = 10,
        n_qp_iter: int = 1,
        tol: float = 1e-8,
        solver: str = "daqp",
    ):
        self.tol = float(tol)
        for name, value in (("n_iter", n_iter), ("n_qp_iter", n_qp_iter)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        self.n_qp_iter = int(n_qp_iter)
        self.dynamics = dynamics
        self.features = features
        self.bounds = bounds
        self.n_iter = int(n_iter)
        self._qp = BoxQP(dynamics, bounds, solver) if bounds is not None else None
        self.n_qp = 0
        self.n_infeasible = 0

    def _model(self, x0, U, theta):
        """Newton model at U: A (M, d, d) positive definite and b with the model 1/2 U'AU + b'U.

        The exact Hessian is used where it is positive definite (quadratic convergence); elsewhere it is
        shifted until it is (`pirl_sim.irl.shift_to_pd`).
        """
        from .irl import shift_to_pd

        X = self.dynamics.rollout(x0, U)
        der = self.features.derivatives(self.dynamics, X, U)
        g = np.einsum("mk,mkd->md", theta, der.grad)
        A = np.einsum("mk,mkij->mij", theta, der.hess)
        _, A, _, _ = shift_to_pd(np.ascontiguousarray(A), 1e-9)
        u = U.reshape(U.shape[0], -1)
        return A, g - np.einsum("mij,mj->mi", A, u)

    def controls(self, x0: np.ndarray, theta: np.ndarray, n_steps: int) -> np.ndarray:
        """Controls (M, N, n_u) minimising theta . f from each start x0 (M, n_x)."""
        x0 = _check_starts(x0, self.dynamics)
        n_steps = _check_horizon(n_steps)
        theta = self.features.weights(theta)
        if np.any(theta < 0):
            raise ValueError(f"weights must be >= 0, got {theta}")
        M = x0.shape[0]
        theta = np.broadcast_to(theta, (M, self.features.n_features))
        if self._qp is not None:
            x0 = self._qp.clip_start(x0)
        U = np.zeros((M, n_steps, self.dynamics.n_u))
        todo = np.arange(M)
        for _ in range(self.n_iter):
            A, b = self._model(x0[todo], U[todo], theta[todo])
            new = -np.linalg.solve(A, b[..., None])[..., 0].reshape((len(todo),) + U.shape[1:])
            step = np.max(np.abs(new - U[todo]), axis=(1, 2))
            U[todo] = new
            todo = todo[step > self.tol]
            if not len(todo):
                break
        if self._qp is None:
            return U
        bad = np.flatnonzero(self._qp.violation(x0, U) > 1e-9)
        ok = np.ones(len(bad), dtype=bool)
        for _ in range(self.n_qp_iter):
            if not ok.any():
                break
            rows = bad[ok]
            A, b = self._model(x0[rows], U[rows], theta[rows])  # one batched linearisation for all of them
            for j, m in enumerate(rows):
                try:
                    U[m] = self._qp.solve(A[j], b[j], x0[m], n_steps).reshape(U.shape[1:])
                    self.n_qp += 1
                except RuntimeError:
                    self.n_infeasible += 1
                    ok[np.flatnonzero(bad == m)[0]] = False
        return U

    def predict(self, x0: np.ndarray, theta: np.ndarray, n_steps: int) -> np.ndarray:
        """Predicted states (M, N + 1, n_x); row 0 is the (possibly bound-clipped) start."""
        x0 = _check_starts(x0, self.dynamics)
        if self._qp is not None:
            x0 = self._qp.clip_start(x0)
        return self.dynamics.rollout(x0, self.controls(x0, theta, n_steps))
