"""Compiled (numba) per-step work of the PIRL drivers: the warm-started MPC re-plan and the projection onto
the routes, for :class:`~pirl_sim.scenarios.drivers.PirlDrivers`.

:class:`CompiledDriverMPC` computes what :meth:`pirl_sim.mpc.SequentialMPC.controls` computes for the paper's
roundabout model on a :class:`~pirl_sim.scenarios.drivers.RouteSet`, and for the model of drivers who interact (the
paper's features, ``headway`` and ``yielding`` on the states of ``pirl_sim.dynamics.following(dt, obstacles=2)``:
the gaps are eliminated, the obstacles driving at constant speed), one driver at a time in compiled loops (the
Newton steps by a Riccati recursion, O(N) per driver; the bounded QPs with `pirl_sim.mpc.BoxQP`). Plans equal the
numpy path's to floating-point rounding (``tests/scenarios/test_driver_kernel.py``) and are deterministic run to run.
numba is imported only when a kernel is built (:func:`numba_available`); compiled code is cached in
``__pycache__`` beside the module, so only the first use on a machine pays the compilation.

What is computed exactly as the numpy MPC does is listed in the documentation's "Simulators and data" page.
"""

from __future__ import annotations

import importlib.util

import numpy as np

__all__ = ["numba_available", "CompiledDriverMPC", "KernelUnsupported"]

_FEATURES = ("speed_dev", "acc_sq", "jerk_sq")
_OBSTACLE_FEATURES = ("headway", "yielding")  # one per obstacle pair of `pirl_sim.dynamics.following`, in order

_KERNELS: dict | None = None


class KernelUnsupported(ValueError):
    """The model is not the one the compiled kernel implements (use the numpy path)."""


def numba_available() -> bool:
    """Whether numba can be imported (the ``sumo`` extra installs it)."""
    return importlib.util.find_spec("numba") is not None


def _kernels() -> dict:
    """The compiled functions (numba imported and the functions compiled, or loaded from the cache, once)."""
    global _KERNELS
    if _KERNELS is None:
        _KERNELS = _build()
    return _KERNELS


def _build() -> dict:
    from . import _driver_jit as j

    return {"newton_batch": j.newton_batch, "dense_model": j.dense_model, "project": j.project}


class CompiledDriverMPC:
    """`SequentialMPC.controls` and `RouteSet.project` of the PIRL drivers, compiled (see the module doc).

    ImportError without numba; the numpy path covers every model.

    Parameters
    ----------
    model : RouteSetDriverModel    the paper's roundabout model on a route set, or the interacting one
                                   (`route_set_model` with ``interacting``); else `KernelUnsupported`
    mpc : SequentialMPC            the model's predictor: its iteration limits, tolerances, bounds and QP solver
                                   are used, and its ``n_qp`` / ``n_infeasible`` counters kept up
    """

    def __init__(self, model, mpc):
        from pirl_sim.driving import HeadwayResidual, SpeedDeviationResidual
        from pirl_sim.dynamics import following
        from pirl_sim.features import SquaredControlResidual, SquaredStateResidual

        from .route_set import RouteSetProfile

        feats = model.features
        dyn = model.dynamics
        names = tuple(feats.names)
        n_ob = len(names) - 3
        if (names[:3] != _FEATURES or names[3:] not in ((), _OBSTACLE_FEATURES)
                or feats.reference != "jerk_sq"):
            raise KernelUnsupported(f"the compiled MPC implements the features {_FEATURES}, optionally followed by "
                                    f"{_OBSTACLE_FEATURES} (reference jerk_sq), got {names} (reference "
                                    f"{feats.reference})")
        f0, f1, f2 = feats.features[:3]
        ok = (isinstance(f0.residual, SpeedDeviationResidual) and isinstance(f0.residual.profile, RouteSetProfile)
              and isinstance(f1.residual, SquaredStateResidual) and tuple(f1.residual.index or ()) == (2,)
              and isinstance(f2.residual, SquaredControlResidual)
              and all(f.reduction == "mean" for f in feats.features)
              and not f0.quadratic and f1.quadratic and f2.quadratic)
        if not ok:
            raise KernelUnsupported("the compiled MPC implements speed_dev on a RouteSetProfile, acc_sq = mean a^2 "
                                    "and jerk_sq = mean j^2 only")
        if dyn.n_x != 3 + 2 * n_ob or dyn.n_u != 1:
            raise KernelUnsupported(f"the compiled MPC needs states (s, v, a){' and two obstacles' if n_ob else ''} "
                                    f"and one control, got n_x = {dyn.n_x}, n_u = {dyn.n_u}")
        hp = []
        for j, f in enumerate(feats.features[3:]):
            res = f.residual
            if not (isinstance(res, HeadwayResidual) and res.gap_index == 3 + 2 * j and f.reduction == "mean"
                    and not f.quadratic):
                raise KernelUnsupported(f"the compiled MPC implements {f.name} as the mean HeadwayResidual with "
                                        f"gap_index {3 + 2 * j} only")
            hp.append((res.standstill, res.time_gap, res.softness))
        if n_ob:
            ref = following(dyn.dt, obstacles=n_ob)
            if not (np.array_equal(dyn.A, ref.A) and np.array_equal(dyn.B, ref.B)):
                raise KernelUnsupported("the compiled MPC needs the dynamics pirl_sim.dynamics.following(dt, "
                                        f"obstacles={n_ob})")
        if mpc._qp is None or mpc.assembly != "outer":
            raise KernelUnsupported("the compiled MPC needs bounds and the 'outer' assembly of SequentialMPC")
        if mpc.dynamics is not dyn or mpc.features is not feats:
            raise KernelUnsupported("mpc must be the model's own predictor")
        self._k = _kernels()
        self.mpc = mpc
        profile = f0.residual.profile
        self.routes = profile.routes
        xb, cf = self.routes._kappa
        self._xb, self._cf = np.array(xb, dtype=float, order="C"), np.array(cf.T, dtype=float, order="C")
        self._inv_a4 = 1.0 / profile.a_lat**4
        self._vmax_m8 = profile.v_max**-8.0
        self.n_obstacles = n_ob  #: obstacles per driver: 0 (the paper's model) or 2 (drivers who interact)
        self._hp = np.array(hp, dtype=float).reshape(n_ob, 3)
        self._dt = float(dyn.dt)
        self._Ad = np.array(dyn.A[:3, :3], dtype=float, order="C")
        self._Bd = np.array(dyn.B[:3, 0], dtype=float, order="C")
        qp = mpc._qp
        self._xlo, self._xhi = np.array(qp._x_lo, dtype=float), np.array(qp._x_hi, dtype=float)
        if np.isfinite(self._xlo[3:]).any() or np.isfinite(self._xhi[3:]).any():
            raise KernelUnsupported("the compiled MPC bounds (s, v, a) only, not the obstacles' states")
        self._xlo3, self._xhi3 = self._xlo[:3].copy(), self._xhi[:3].copy()
        self._ulo, self._uhi = float(qp._u_lo[0]), float(qp._u_hi[0])
        T = self.routes._tables
        self._tab = tuple(np.array(T[key], dtype=dtype, order="C") for key, dtype in (
            ("base", np.int64), ("n", np.int64), ("inv_step", float), ("step", float), ("length", float),
            ("rows", float)))
        self.n_newton = 0  #: Newton steps taken so far (all drivers)
        # compile (or load from numba's cache) now rather than inside the first simulation step
        n_x, n_th = 3 + 2 * n_ob, 3 + n_ob
        self.controls(np.zeros((0, n_x)), np.ones((0, n_th)), 1, np.zeros((0, 1, 1)))
        self.model(np.zeros(n_x), np.ones(n_th), np.zeros(1))
        self.project(np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros(0))

    # -- the MPC ------------------------------------------------------------------------------------

    def controls(self, x0: np.ndarray, theta: np.ndarray, n_steps: int, init: np.ndarray) -> np.ndarray:
        """Controls (M, N, 1) [m/s^3] as `SequentialMPC.controls` (warm-started from ``init``).

        ValueError for arrays of other shapes, non-finite starts or warm starts, or negative weights.

        Parameters
        ----------
        x0 : array (M, n_x)      starts (s [m] on the global axis, v [m/s], a [m/s^2]; with obstacles also
                                 (g [m], v_L [m/s]) per obstacle), moved inside the state bounds
        theta : array (M, K)     weights (speed_dev, acc_sq, jerk_sq[, headway, yielding]), >= 0, jerk_sq > 0
        n_steps : int            horizon N [steps], >= 1
        init : array (M, N, 1)   warm starts [m/s^3], finite
        """
        from pirl_sim.mpc import _check_horizon

        n_steps = _check_horizon(n_steps)
        x0 = np.array(x0, dtype=float, ndmin=2)
        M, n_ob = x0.shape[0], self.n_obstacles
        n_x, n_th = 3 + 2 * n_ob, 3 + n_ob
        if x0.shape != (M, n_x) or not np.all(np.isfinite(x0)):
            raise ValueError(f"start states must be finite with shape (M, {n_x}), got shape {x0.shape}")
        theta = np.ascontiguousarray(np.broadcast_to(np.asarray(theta, dtype=float), (M, n_th)))
        if not np.all(np.isfinite(theta)) or np.any(theta < 0) or np.any(theta[:, 2] <= 0):
            raise ValueError("weights must be finite and >= 0, the jerk_sq weight > 0")
        U = np.array(init, dtype=float)
        if U.shape != (M, n_steps, 1) or not np.all(np.isfinite(U)):
            raise ValueError(f"init must be finite with shape {(M, n_steps, 1)}, got {U.shape}")
        x0 = np.ascontiguousarray(np.clip(x0, self._xlo, self._xhi))
        U2 = U.reshape(M, n_steps)
        on_bounds = np.zeros(M, dtype=np.bool_)
        bad = np.zeros(M, dtype=np.bool_)
        counts = np.zeros(1, dtype=np.int64)
        k = self._k
        k["newton_batch"](np.ascontiguousarray(x0[:, :3]), theta, self._obstacles(x0), self._hp, U2, self._Ad,
                          self._Bd, self._xb, self._cf, self._inv_a4, self._vmax_m8, self._xlo3, self._xhi3,
                          self._ulo, self._uhi, self.mpc.n_iter, self.mpc.tol, on_bounds, bad, counts)
        self.n_newton += int(counts[0])
        rows = np.flatnonzero(bad)
        if len(rows):
            self._bounded(x0, theta, U2, rows, n_steps)
        return U

    def _obstacles(self, x0: np.ndarray) -> np.ndarray:
        """Per start of x0 (M, n_x): (c0 = g + s [m], dt v_L [m]) of each obstacle (M, J, 2), the gap at stage n
        being c0 + n dt v_L - s_n (see :mod:`._driver_jit`)."""
        M, J = x0.shape[0], self.n_obstacles
        ob = np.empty((M, J, 2))
        for j in range(J):
            ob[:, j, 0] = x0[:, 3 + 2 * j] + x0[:, 0]
            ob[:, j, 1] = self._dt * x0[:, 4 + 2 * j]
        return ob

    def model(self, x0: np.ndarray, theta: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The dense Newton model at U of one start: H (N, N) and b (N,) with the model 1/2 U'HU + b'U
        (`SequentialMPC._model`); x0 (n_x,), theta (K,), U (N,)."""
        N = len(U)
        H, b = np.empty((N, N)), np.empty(N)
        x0 = np.ascontiguousarray(x0, dtype=float)
        self._k["dense_model"](np.ascontiguousarray(x0[:3]), np.ascontiguousarray(theta, dtype=float),
                               self._obstacles(x0[None])[0], self._hp, np.ascontiguousarray(U, dtype=float),
                               self._Ad, self._Bd, self._xb, self._cf, self._inv_a4, self._vmax_m8, H, b)
        return H, b

    def _bounded(self, x0, theta, U, rows, n_steps):
        """The bounded QPs of `SequentialMPC.controls` for the rows that need them (U (M, N) in place)."""
        mpc, qp = self.mpc, self.mpc._qp
        for _ in range(mpc.n_qp_iter):
            if not len(rows):
                break
            moved = np.zeros(len(rows))
            for j, m in enumerate(rows):
                H, b = self.model(x0[m], theta[m], U[m])
                try:
                    new = qp.solve(H, b, x0[m], n_steps)
                    mpc.n_qp += 1
                except RuntimeError:
                    mpc.n_infeasible += 1
                    continue
                moved[j] = np.max(np.abs(new - U[m]))
                U[m] = new
            rows = rows[moved > mpc.qp_tol]

    # -- the projection -----------------------------------------------------------------------------

    def project(self, route_index, xy, s_guess, *, tol: float = 1e-7) -> np.ndarray:
        """`RouteSet.project` compiled: local arc lengths (M,) [m] of the foot points of xy (M, 2) [m] on
        their routes (M,), from starts s_guess (M,) [m] (NaN: found by the path's ``to_frenet`` first).

        Raises
        ------
        ValueError
            As `RouteSet.project`: mismatched lengths, or no convergence.
        """
        from .route_set import MIN_SLOPE as _MIN_SLOPE, NEWTON_MAX_ITER as _NEWTON_MAX_ITER

        r = np.ascontiguousarray(np.asarray(route_index, dtype=np.int64).reshape(-1))
        q = np.ascontiguousarray(np.asarray(xy, dtype=float).reshape(-1, 2))
        if len(r) != len(q):
            raise ValueError(f"got {len(r)} route indices for {len(q)} points")
        if len(r) and (r.min() < 0 or r.max() >= self.routes.n_routes):
            raise ValueError(f"route indices must lie in [0, {self.routes.n_routes}), got {r.min()}..{r.max()}")
        s = np.array(s_guess, dtype=float).reshape(-1)
        if len(s) != len(r):
            raise ValueError(f"got {len(s)} starting arc lengths for {len(r)} points")
        for k in np.flatnonzero(~np.isfinite(s)):
            s[k] = float(self.routes.paths[r[k]].to_frenet(q[k], extrapolate=True)[0])
        work = np.zeros(len(s))
        base, nrow, inv_step, step, length, rows = self._tab
        it = self._k["project"](r, q, s, base, nrow, inv_step, step, length, rows, float(tol), _NEWTON_MAX_ITER,
                                _MIN_SLOPE, work)
        if it < 0:
            k = -1 - it
            raise ValueError(f"point {q[k].tolist()} on route {self.routes.route_ids[r[k]]!r}: no foot point after "
                             f"{_NEWTON_MAX_ITER} Newton steps (last step {work[k]:.3g} m)")
        return s
