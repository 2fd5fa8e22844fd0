"""Linear discrete-time dynamics x_{k+1} = A x_k + B u_k, and their condensed (stacked) form.

The condensed form writes all future states as an affine function of the stacked controls,
``X = Phi x_0 + Gamma U``, which is what the IRL derivatives and the MPC use.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np

__all__ = ["LinearDynamics", "point_mass", "longitudinal", "following", "constant_acceleration",
           "constant_acceleration_positions"]


@dataclass(frozen=True)
class LinearDynamics:
    """x_{k+1} = A x_k + B u_k, sampled every ``dt`` seconds.

    Parameters
    ----------
    A : array, shape (n_x, n_x)
    B : array, shape (n_x, n_u)
    dt : float
        Sampling period [s].
    state_names, control_names : tuple of str
        Names with units, e.g. ``("s [m]", "v [m/s]")``; their count fixes n_x and n_u.
    position_index : tuple of int
        Indices of the state entries that are positions [m] (used by distance metrics).
    """

    A: np.ndarray
    B: np.ndarray
    dt: float
    state_names: tuple[str, ...]
    control_names: tuple[str, ...]
    position_index: tuple[int, ...] = (0,)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        A = np.array(self.A, dtype=float)
        B = np.array(self.B, dtype=float)
        n_x, n_u = len(self.state_names), len(self.control_names)
        if A.shape != (n_x, n_x):
            raise ValueError(f"A must have shape ({n_x}, {n_x}) for states {self.state_names}, got {A.shape}")
        if B.shape != (n_x, n_u):
            raise ValueError(f"B must have shape ({n_x}, {n_u}) for controls {self.control_names}, got {B.shape}")
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
            raise ValueError("A and B must be finite")
        if not np.isfinite(self.dt) or self.dt <= 0:
            raise ValueError(f"dt must be a positive number of seconds, got {self.dt!r}")
        for i in self.position_index:
            if not 0 <= i < n_x:
                raise ValueError(f"position_index {i} is not a state index (0..{n_x - 1})")
        A.setflags(write=False)
        B.setflags(write=False)
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "dt", float(self.dt))

    @property
    def n_x(self) -> int:
        return self.A.shape[0]

    @property
    def n_u(self) -> int:
        return self.B.shape[1]

    def condensed(self, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
        """Stacked prediction matrices for states x_1 .. x_N.

        Returns
        -------
        Phi : array, shape (N, n_x, n_x)
            ``x_i = Phi[i-1] x_0 + sum_j Gamma[i-1, :, j, :] u_j``.
        Gamma : array, shape (N, n_x, N, n_u)
            Lower block-triangular in (i, j).
        """
        n_steps = int(n_steps)
        if n_steps < 1:
            raise ValueError(f"n_steps must be >= 1, got {n_steps}")
        if n_steps not in self._cache:
            n_x, n_u = self.n_x, self.n_u
            powers = np.empty((n_steps + 1, n_x, n_x))
            powers[0] = np.eye(n_x)
            for k in range(1, n_steps + 1):
                powers[k] = self.A @ powers[k - 1]
            AB = powers[:n_steps] @ self.B  # AB[k] = A^k B, shape (N, n_x, n_u)
            gamma = np.zeros((n_steps, n_x, n_steps, n_u))
            for i in range(n_steps):  # x_{i+1} depends on u_0..u_i through A^{i-j} B
                gamma[i, :, : i + 1, :] = np.moveaxis(AB[i::-1], 0, 1)
            phi = powers[1:]
            phi.setflags(write=False)
            gamma.setflags(write=False)
            self._cache[n_steps] = (phi, gamma)
        return self._cache[n_steps]

    def rollout(self, x0: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """Simulate forward.

        Parameters
        ----------
        x0 : array, shape (..., n_x)
        controls : array, shape (..., N, n_u)

        Returns
        -------
        states : array, shape (..., N + 1, n_x), including x0.
        """
        x0 = np.asarray(x0, dtype=float)
        controls = np.asarray(controls, dtype=float)
        if x0.shape[-1] != self.n_x or controls.ndim < 2 or controls.shape[-1] != self.n_u:
            raise ValueError(
                f"expected x0 (..., {self.n_x}) and controls (..., N, {self.n_u}), got {x0.shape} and {controls.shape}"
            )
        phi, gamma = self.condensed(controls.shape[-2])
        future = np.einsum("iab,...b->...ia", phi, x0) + np.einsum("iajc,...jc->...ia", gamma, controls)
        return np.concatenate([x0[..., None, :], future], axis=-2)

    def steer(self, x0: np.ndarray, targets: np.ndarray, weights, ridge: float = 1e-2) -> tuple[np.ndarray, np.ndarray]:
        """Controls that carry the fixed start ``x0`` as near as they can to target states (least squares).

        Minimises ``sum_k sum_i weights[i] (x_k,i - targets[k-1, i])^2 + ridge sum_k |u_k|^2`` over k = 1 .. N, e.g.
        to re-start a recorded segment (`pirl_sim.learners.PIRLKNN`'s ``segment_start``).

        Parameters
        ----------
        x0, targets : array (n_x,), (N, n_x)    the start, kept exactly; states x_1 .. x_N to follow (weight 0: ignored)
        weights, ridge : array (n_x,), float    >= 0 per state entry (one > 0), and > 0 on the controls [1 / unit^2]

        Returns
        -------
        states, controls : array (N + 1, n_x), (N, n_u)   from ``x0``; ValueError for bad shapes, values or weights
        """
        x0 = np.asarray(x0, dtype=float)
        targets = np.asarray(targets, dtype=float)
        w = np.asarray(weights, dtype=float)
        if x0.shape != (self.n_x,) or targets.ndim != 2 or targets.shape[1] != self.n_x or len(targets) < 1:
            raise ValueError(f"expected x0 ({self.n_x},) and targets (N >= 1, {self.n_x}), got {x0.shape} and "
                             f"{targets.shape}")
        if w.shape != (self.n_x,) or not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
            raise ValueError(f"weights must be {self.n_x} finite values >= 0, at least one > 0, got {weights!r}")
        if isinstance(ridge, bool) or not np.isfinite(ridge) or ridge <= 0:
            raise ValueError(f"ridge must be a finite number > 0, got {ridge!r}")
        used = w > 0
        if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(targets[:, used]))):
            raise ValueError("x0 and the weighted entries of targets must be finite")
        n, n_u = len(targets), self.n_u
        phi, gamma = self.condensed(n)
        G = gamma[:, used].transpose(1, 0, 2, 3).reshape(-1, n * n_u)  # (entries x steps, controls)
        r = (targets[:, used] - phi[:, used] @ x0).T.ravel()
        sw = np.repeat(np.sqrt(w[used]), n)
        G, r = G * sw[:, None], r * sw
        U = np.linalg.solve(G.T @ G + ridge * np.eye(n * n_u), G.T @ r).reshape(n, n_u)
        return self.rollout(x0, U), U

    def residual(self, states: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """x_{k+1} - (A x_k + B u_k), shape (..., N, n_x): zero for a consistent trajectory."""
        states = np.asarray(states, dtype=float)
        controls = np.asarray(controls, dtype=float)
        return states[..., 1:, :] - states[..., :-1, :] @ self.A.T - controls @ self.B.T

    def controls_from_states(self, states: np.ndarray) -> np.ndarray:
        """Least-squares controls that best explain consecutive states, shape (..., N, n_u).

        Exact (the inverse of `rollout`) whenever the states were produced by these dynamics.
        """
        states = np.asarray(states, dtype=float)
        drift = states[..., 1:, :] - states[..., :-1, :] @ self.A.T
        pinv_B = np.linalg.pinv(self.B)
        return drift @ pinv_B.T


def point_mass(dt: float = 0.1) -> LinearDynamics:
    """The paper's synthetic model: 1-D point mass, state (p [m], v [m/s]), control acceleration [m/s^2].

    ``A = [[1, dt], [0, 1]]``, ``B = [0, dt]^T`` exactly as in the paper's equation.
    """
    return LinearDynamics(
        A=np.array([[1.0, dt], [0.0, 1.0]]),
        B=np.array([[0.0], [dt]]),
        dt=dt,
        state_names=("p [m]", "v [m/s]"),
        control_names=("a [m/s^2]",),
        position_index=(0,),
    )


def longitudinal(dt: float = 0.2) -> LinearDynamics:
    """Longitudinal motion along a path: state (s [m], v [m/s], a [m/s^2]), control jerk [m/s^3].

    Exact zero-order-hold discretisation of the triple integrator.
    """
    return LinearDynamics(
        A=np.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]]),
        B=np.array([[dt**3 / 6], [dt**2 / 2], [dt]]),
        dt=dt,
        state_names=("s [m]", "v [m/s]", "a [m/s^2]"),
        control_names=("j [m/s^3]",),
        position_index=(0,),
    )



def following(dt: float = 0.2, obstacles: int = 1) -> LinearDynamics:
    """`longitudinal` motion behind a vehicle ahead: state (s [m], v [m/s], a [m/s^2], g [m], v_L [m/s]),
    control jerk [m/s^3].

    ``g`` is the bumper-to-bumper gap to the vehicle ahead and ``v_L`` its speed, which the dynamics hold
    constant (the vehicle ahead drives on at constant velocity over a prediction; recorded trajectories carry
    its recorded gap and speed instead). The gap shrinks by what the car drives:
    ``g_{k+1} = g_k + dt v_L - (s_{k+1} - s_k)``, so the controls reach it exactly as they reach s.
    ``obstacles=2`` appends a second such pair, (g_y [m], v_y [m/s]): the obstacle a car yields to at a
    conflict point (`pirl_sim.scenarios.yielding`).
    """
    if obstacles not in (1, 2):
        raise ValueError(f"obstacles must be 1 or 2, got {obstacles!r}")
    lon = longitudinal(dt)
    n = 3 + 2 * obstacles
    A = np.zeros((n, n))
    A[:3, :3] = lon.A
    B = np.zeros((n, 1))
    B[:3] = lon.B
    for g in range(3, n, 2):
        A[g, :3] = -(lon.A[0] - np.array([1.0, 0.0, 0.0]))  # minus the increment of s
        A[g, g] = 1.0
        A[g, g + 1] = dt
        A[g + 1, g + 1] = 1.0
        B[g] = -lon.B[0]
    names = (*lon.state_names, "g [m]", "v_L [m/s]") + (("g_y [m]", "v_y [m/s]") if obstacles == 2 else ())
    return LinearDynamics(A=A, B=B, dt=dt, state_names=names, control_names=lon.control_names, position_index=(0,))


def constant_acceleration(s0: np.ndarray, v0: np.ndarray, a0: np.ndarray, t: np.ndarray):
    """Positions, speeds and accelerations at times ``t`` (1, T) [s] of starts (M, 1) at position ``s0`` [m],
    speed ``v0`` [m/s] (negative taken as 0) and acceleration ``a0`` [m/s^2] held until a braking start stops
    (it does not reverse): three arrays (M, T). ``a0 = 0`` is constant speed."""
    v0 = np.maximum(v0, 0.0)
    t_stop = np.where(a0 < 0, v0 / np.where(a0 < 0, -a0, 1.0), np.inf)  # [s] when braking reaches v = 0
    tc = np.minimum(t, t_stop)
    return s0 + v0 * tc + 0.5 * a0 * tc**2, v0 + a0 * tc, np.where(t < t_stop, a0, 0.0)


def constant_acceleration_positions(dynamics: LinearDynamics, x0: np.ndarray, steps: int) -> np.ndarray:
    """Positions (M, steps) [m] over the ``steps`` steps after starts ``x0`` (M, n_x) of ``dynamics`` whose first
    component is the position: `constant_acceleration` from the components named "v [m/s]" and "a [m/s^2]"
    (constant speed without an acceleration, held without a speed)."""
    names = tuple(dynamics.state_names)
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    zero = np.zeros((len(x0), 1))
    v = x0[:, [names.index("v [m/s]")]] if "v [m/s]" in names else zero
    a = x0[:, [names.index("a [m/s^2]")]] if "a [m/s^2]" in names else zero
    return constant_acceleration(x0[:, :1], v, a, dynamics.dt * np.arange(1, steps + 1)[None])[0]
