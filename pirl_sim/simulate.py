"""Closed-loop drivers: every step each driver re-plans with its MPC under its own (possibly changing) weights.

This is how simulated drivers behave in the scenarios (SUMO, highway-env) and how a style switch is produced:
``theta`` may differ per step. Control noise makes the drivers noisily rational between re-plans.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .model import DriverModel
from .mpc import SequentialMPC
from .trajectory import Trajectory
from .validation import is_positive_int

__all__ = ["simulate_receding_horizon"]


def simulate_receding_horizon(
    model: DriverModel,
    x0: np.ndarray,
    theta: np.ndarray | Callable[[int], np.ndarray],
    n_steps: int,
    horizon: int,
    *,
    rng: np.random.Generator | None = None,
    control_noise: float = 0.0,
    metadata: dict | None = None,
) -> list[Trajectory]:
    """Simulate M drivers for ``n_steps`` steps, each applying the first control of its MPC plan (metadata
    ``theta_schedule`` (n_steps, K) of each trajectory: the weights in force).

    Parameters
    ----------
    model : DriverModel
    x0 : array (M, n_x)
    theta : array (K,), (M, K), (n_steps, M, K), or callable ``step -> (M, K)``   normalised weights in force
    n_steps, horizon : int     simulated steps; MPC horizon [steps]
    rng : numpy.random.Generator   required when control_noise > 0
    control_noise : float      standard deviation of Gaussian noise on each applied control [control units]
    metadata : dict, optional  added to every trajectory's metadata
    """
    x = np.atleast_2d(np.asarray(x0, dtype=float))
    M = x.shape[0]
    if not is_positive_int(n_steps):
        raise ValueError(f"n_steps must be a positive integer, got {n_steps!r}")
    if control_noise < 0 or not np.isfinite(control_noise):
        raise ValueError(f"control_noise must be >= 0, got {control_noise!r}")
    if control_noise > 0 and not isinstance(rng, np.random.Generator):
        raise TypeError("control_noise > 0 needs rng, a numpy.random.Generator")
    K = model.features.n_features
    if callable(theta):
        schedule = np.stack([np.broadcast_to(model.features.weights(theta(k)), (M, K)) for k in range(n_steps)])
    else:
        arr = model.features.weights(theta)
        schedule = np.broadcast_to(arr if arr.ndim == 3 else np.broadcast_to(arr, (M, K)), (n_steps, M, K))
    predictor = model.predictor()
    dyn = model.dynamics
    states = np.empty((M, n_steps + 1, dyn.n_x))
    controls = np.empty((M, n_steps, dyn.n_u))
    states[:, 0] = x
    warm = isinstance(predictor, SequentialMPC)
    plan = None
    for k in range(n_steps):
        if warm and plan is not None:  # warm start: the previous plan shifted by one step
            init = np.concatenate([plan[:, 1:], plan[:, -1:]], axis=1)
            plan = predictor.controls(x, schedule[k], horizon, init=init)
        else:
            plan = predictor.controls(x, schedule[k], horizon)
        u = plan[:, 0]
        if control_noise > 0:
            u = u + control_noise * rng.standard_normal(u.shape)  # type: ignore[union-attr]
        x = x @ dyn.A.T + u @ dyn.B.T
        controls[:, k] = u
        states[:, k + 1] = x
    meta = dict(metadata or {})
    return [
        Trajectory(states[m], controls[m], dyn.dt, {**meta, "theta_schedule": np.array(schedule[:, m])}) for m in range(M)
    ]
