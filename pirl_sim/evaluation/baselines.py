"""Kinematic baselines as pseudo-learners of the sweep: constant velocity and constant acceleration.

`ConstantVelocity` (``cv``) and `ConstantAcceleration` (``ca``, stopping at v = 0) follow the learners' contract
as far as a sweep cell uses it (``fit`` returns self and sets ``model_``, a `KinematicModel`; ``infer_weights``
gives NaN), so ``learners = ["cv", "ca", "tirl", ...]`` in a sweep config puts their MED and FDE beside the
learners'. `PlaneVelocity` (``cv-xy``), `Hindsight` (``hindsight``) and `Direct` (``direct``) name methods that
the ``recorded`` scenario (`pirl_sim.experiments.recorded`) computes itself; their ``fit`` raises ValueError.
`BASELINES` maps the sweep names to the classes.

What each baseline predicts is explained in the documentation's "Sweeps" page (the config).
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator

from pirl_sim.dynamics import constant_acceleration

__all__ = ["BASELINES", "ConstantVelocity", "ConstantAcceleration", "PlaneVelocity", "Hindsight", "Direct",
           "KinematicModel"]

_POSITION_NAMES = ("s [m]", "p [m]")


class KinematicModel:
    """A driver model whose predictions ignore the weights: constant velocity or acceleration (module doc).

    Positions, features and dynamics are those of the wrapped model, so predictions are scored alike.
    """

    def __init__(self, model, kind: str) -> None:
        if kind not in ("cv", "ca"):
            raise ValueError(f"kind must be 'cv' or 'ca', got {kind!r}")
        names = tuple(model.dynamics.state_names)
        position = [i for i, n in enumerate(names) if n in _POSITION_NAMES]
        if not position or "v [m/s]" not in names:
            raise ValueError(f"a kinematic baseline needs a position and a speed in the state, got {names}")
        if kind == "ca" and "a [m/s^2]" not in names:
            raise ValueError(f"the constant-acceleration baseline needs an acceleration in the state, got {names}")
        self.model, self.kind = model, kind
        self.features, self.dynamics = model.features, model.dynamics
        self._s, self._v = position[0], names.index("v [m/s]")
        self._a = names.index("a [m/s^2]") if "a [m/s^2]" in names else None

    def positions(self, states: np.ndarray) -> np.ndarray:
        return self.model.positions(states)

    def predict_states(self, x0: np.ndarray, theta, horizon: int) -> np.ndarray:
        """States (M, horizon + 1, n_x) from starts (M, n_x); ``theta`` is ignored."""
        x0 = np.atleast_2d(np.asarray(x0, dtype=float))
        t = self.dynamics.dt * np.arange(horizon + 1)[None, :]  # [s], row 0 is the start
        s0, v0 = x0[:, self._s, None], x0[:, self._v, None]
        out = np.repeat(x0[:, None, :], horizon + 1, axis=1)
        if self.kind == "cv":
            out[:, :, self._s] = s0 + v0 * t
            if self._a is not None:
                out[:, 1:, self._a] = 0.0
            return out
        s, v, a = constant_acceleration(s0, v0, x0[:, self._a, None], t)
        out[:, :, self._s], out[:, :, self._v], out[:, 1:, self._a] = s, v, a[:, 1:]
        return out


class _Baseline(BaseEstimator):
    kind = ""

    def __init__(self, model=None, window=None, windows="first") -> None:
        self.model = model
        self.window = window
        self.windows = windows

    def _check_common(self) -> None:
        """Nothing to check: the baselines have no parameters of their own."""

    def fit(self, trajectories=None, y=None):
        if self.model is None:
            raise ValueError(f"{type(self).__name__} needs the scenario's model")
        if self.kind not in ("cv", "ca"):
            raise ValueError(f"{self.kind!r} is a method of the 'recorded' scenario only (pirl_sim.experiments.recorded)")
        self.model_ = KinematicModel(self.model, self.kind)
        return self

    def infer_weights(self, histories) -> np.ndarray:
        """No weights: NaN, shape (M, K)."""
        histories = [histories] if hasattr(histories, "states") else list(histories)
        return np.full((len(histories), self.model_.features.n_features), np.nan)


class ConstantVelocity(_Baseline):
    """Constant velocity (module doc)."""

    kind = "cv"


class ConstantAcceleration(_Baseline):
    """Constant acceleration, stopping at v = 0 (module doc)."""

    kind = "ca"


class PlaneVelocity(_Baseline):
    """Constant velocity in the plane (module doc; the ``recorded`` scenario's)."""

    kind = "cv-xy"
    scenarios = ("recorded", "replay")  #: where it runs (checked when a sweep config is built)


class Hindsight(_Baseline):
    """The cost fitted on each window's own future (module doc; the ``recorded`` scenario's)."""

    kind = "hindsight"
    scenarios = ("recorded", "replay")


class Direct(_Baseline):
    """The arc lengths ahead regressed on the history and the place (module doc; the ``recorded`` scenario's)."""

    kind = "direct"
    scenarios = ("recorded", "replay")


#: sweep name -> class (the learners of `pirl_sim.learners.LEARNERS` are the others)
BASELINES = {"cv": ConstantVelocity, "ca": ConstantAcceleration, "cv-xy": PlaneVelocity, "hindsight": Hindsight,
             "direct": Direct}
