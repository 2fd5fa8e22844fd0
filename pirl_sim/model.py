"""`DriverModel`: the dynamics, the named features and the predictor that learners share.

Learners see trajectories and a DriverModel, never a simulator. The model turns trajectories into feature
values (for clustering and neighbour look-ups), into Laplace blocks (for the IRL), and turns a start state and
weights into a predicted future (MPC).
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .dynamics import LinearDynamics, point_mass
from .features import FeatureSet, lqr_features
from .irl import LaplaceBlock
from .mpc import Bounds, ConstrainedLQPredictor, LQPredictor
from .trajectory import Trajectory, stack_trajectories

__all__ = ["DriverModel", "check_trajectories", "synthetic_model"]


def check_trajectories(trajectories, dynamics: LinearDynamics | None = None, *, min_steps: int = 1) -> list[Trajectory]:
    """Validate a non-empty sequence of `Trajectory` compatible with ``dynamics``; returns it as a list."""
    if isinstance(trajectories, Trajectory):
        raise TypeError("expected a sequence of Trajectory objects, got a single Trajectory; wrap it in a list")
    try:
        trajectories = list(trajectories)
    except TypeError:
        raise TypeError(f"expected a sequence of Trajectory objects, got {type(trajectories).__name__}") from None
    if not trajectories:
        raise ValueError("expected at least one trajectory, got an empty sequence")
    for i, t in enumerate(trajectories):
        if not isinstance(t, Trajectory):
            raise TypeError(f"element {i} is a {type(t).__name__}, expected a pirl_sim.Trajectory")
        if t.n_steps < min_steps:
            raise ValueError(f"trajectory {i} has {t.n_steps} steps; at least {min_steps} are needed")
        if dynamics is not None:
            if t.n_x != dynamics.n_x or t.n_u != dynamics.n_u:
                raise ValueError(
                    f"trajectory {i} has n_x={t.n_x}, n_u={t.n_u}; the model's dynamics need "
                    f"n_x={dynamics.n_x} {dynamics.state_names}, n_u={dynamics.n_u} {dynamics.control_names}"
                )
            if not math.isclose(t.dt, dynamics.dt, rel_tol=1e-9):
                raise ValueError(f"trajectory {i} has dt={t.dt} s; the model's dynamics use dt={dynamics.dt} s")
    return trajectories


@dataclass(frozen=True)
class DriverModel:
    """Dynamics + features (+ optional bounds) of a noisily rational driver.

    Parameters
    ----------
    dynamics : LinearDynamics
    features : FeatureSet
    bounds : Bounds, optional
        When given, predictions solve the bounded QP (casadi); otherwise the closed-form LQ solution.
    """

    dynamics: LinearDynamics
    features: FeatureSet
    bounds: Bounds | None = None
    _predictors: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.dynamics, LinearDynamics):
            raise TypeError(f"dynamics must be a LinearDynamics, got {type(self.dynamics).__name__}")
        if not isinstance(self.features, FeatureSet):
            raise TypeError(f"features must be a FeatureSet, got {type(self.features).__name__}")

    def __getstate__(self) -> dict:
        """Pickled without the predictor cache (a constrained predictor holds its QP solver's module, which does
        not pickle); the predictor is rebuilt on first use."""
        state = dict(self.__dict__)
        state["_predictors"] = {}
        return state

    @property
    def feature_names(self) -> tuple[str, ...]:
        return self.features.names

    def check(self, trajectories, *, min_steps: int = 1) -> list[Trajectory]:
        return check_trajectories(trajectories, self.dynamics, min_steps=min_steps)

    def feature_values(self, trajectories: Sequence[Trajectory]) -> np.ndarray:
        """Feature values, shape (M, K)."""
        return self.features.trajectory_values(self.check(trajectories))

    def laplace_blocks(self, trajectories: Sequence[Trajectory]) -> list[tuple[LaplaceBlock, np.ndarray]]:
        """Laplace blocks of equal-length groups, each with the indices of its trajectories."""
        trajectories = self.check(trajectories)
        lengths = np.array([t.n_steps for t in trajectories])
        out = []
        for n in np.unique(lengths):
            idx = np.flatnonzero(lengths == n)
            states, controls, _ = stack_trajectories([trajectories[i] for i in idx])
            der = self.features.derivatives(self.dynamics, states, controls)
            out.append((LaplaceBlock.from_derivatives(der, self.features.reference_index), idx))
        return out

    def predictor(self):
        key = "constrained" if self.bounds is not None else "lq"
        if key not in self._predictors:
            if self.bounds is not None:
                self._predictors[key] = ConstrainedLQPredictor(self.dynamics, self.features, self.bounds)
            else:
                self._predictors[key] = LQPredictor(self.dynamics, self.features)
        return self._predictors[key]

    def predict_states(self, x0: np.ndarray, theta: np.ndarray, horizon: int) -> np.ndarray:
        """Predicted states (M, horizon + 1, n_x) from starts (M, n_x) under weights (K,) or (M, K)."""
        return self.predictor().predict(x0, theta, horizon)

    def positions(self, states: np.ndarray) -> np.ndarray:
        """Positions [m] of states (..., n_x) as (..., P), for distance metrics."""
        return np.asarray(states)[..., list(self.dynamics.position_index)]


def synthetic_model(dt: float = 0.1) -> DriverModel:
    """The paper's synthetic problem: 1-D point mass with LQR features (state_sq, control_sq)."""
    return DriverModel(point_mass(dt), lqr_features())
