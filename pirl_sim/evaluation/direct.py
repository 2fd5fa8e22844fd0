"""A reference without a cost: the next seconds along the path regressed on the history and the place.

`DirectRegression` predicts how far a car drives along its path over the next ``horizon`` steps as constant
acceleration from its estimated state plus a learned correction, one gradient-boosted regression tree ensemble
(`sklearn.ensemble.HistGradientBoostingRegressor`) per step ahead, on PIRL-kNN's next-segment look-up keys and
the place (the path's position and heading at the history's end). It is no model of drivers' costs and no PIRL
learner: the replay (`pirl_sim.experiments.recorded`, method ``direct``, ``pirl-sim replay --direct``) reports
it beside the learners as a measure of how much the history and the map tell about the next seconds.

The regression is explained in the documentation's "Replay of recorded driving" page (the direct regression).
"""

from __future__ import annotations

import numpy as np

from pirl_sim.dynamics import constant_acceleration_positions
from pirl_sim.validation import is_positive_int

__all__ = ["DirectRegression", "DIRECT"]

DIRECT = "direct regression (no cost)"  #: the replay's row label


class DirectRegression:
    """Arc lengths over the next steps regressed on the history and the place (module doc; fitted: ``regression_``,
    one `~pirl_sim.learners.selector.FutureRegression` per step ahead, and ``n_samples_`` training windows).

    Parameters
    ----------
    model : PathDriverModel        the scene's model: dynamics (s, v, a), path and desired speed's curvature
    window, horizon : int          history length and predicted steps [steps]
    lags : tuple of int            steps before the history's end at which v and a are keys (each <= window)
    ahead : tuple of float         distances [m] beyond the history's end at which |curvature| is a key
    stride : int                   every stride-th training window
    online : bool                  training histories estimated from their own observations, or smoothed states
    max_iter, learning_rate : int, float   boosting iterations and rate of each step's ensemble
    random_state : int             seed of the ensembles (same data, same bytes)
    """

    def __init__(self, model, window: int, horizon: int, *, lags=(0, 2, 5), ahead=(0.0, 10.0, 20.0, 30.0, 45.0),
                 stride: int = 2, online: bool = True, max_iter: int = 200, learning_rate: float = 0.05,
                 random_state: int = 0) -> None:
        for name, v in (("window", window), ("horizon", horizon), ("stride", stride), ("max_iter", max_iter)):
            if not is_positive_int(v):
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        lags = tuple(lags)
        if not lags or any(isinstance(x, bool) or not isinstance(x, (int, np.integer)) or not 0 <= x <= window
                           for x in lags):
            raise ValueError(f"lags must be whole numbers of steps in [0, window={window}], got {lags!r}")
        ahead = tuple(float(x) for x in ahead)
        if any(not np.isfinite(x) or x < 0 for x in ahead):
            raise ValueError(f"ahead must be finite distances >= 0 m, got {ahead!r}")
        if not (np.isfinite(learning_rate) and 0 < learning_rate <= 1):
            raise ValueError(f"learning_rate must be in (0, 1], got {learning_rate!r}")
        if not callable(getattr(model, "curvature", None)) or not hasattr(model, "path"):
            raise TypeError(f"DirectRegression needs a model along a path (PathDriverModel), got "
                            f"{type(model).__name__}")
        self.model, self.window, self.horizon = model, int(window), int(horizon)
        self.lags, self.ahead, self.stride, self.online = lags, ahead, int(stride), bool(online)
        self.max_iter, self.learning_rate, self.random_state = int(max_iter), float(learning_rate), int(random_state)

    def keys(self, histories) -> np.ndarray:
        """Keys (M, 2 len(lags) + len(ahead) + 4) of histories (each with at least max(lags) + 1 states):
        v and a [m/s, m/s^2] at each lag, |curvature| [1/m] ahead, the path's point [m] and unit heading at
        the history's end."""
        from pirl_sim.learners.knn import history_keys, place_keys

        return np.hstack([history_keys(self.model, histories, (1, 2), self.lags, self.ahead),
                          place_keys(self.model, histories)])

    def _base(self, histories) -> np.ndarray:
        x0 = np.stack([h.states[-1] for h in histories])
        return constant_acceleration_positions(self.model.dynamics, x0, self.horizon)

    def fit(self, trajectories) -> "DirectRegression":
        """Fit on training tracks (`pirl_sim.trajectory.Trajectory` of the model's states).

        Raises
        ------
        ValueError
            No track has window + horizon steps, or fewer windows than 2.
        """
        from pirl_sim.learners.selector import FutureRegression

        T, F = self.window, self.horizon
        hist, truth = [], []
        for t in trajectories:
            for start in range(0, t.n_steps - T - F + 1, self.stride):
                hist.append(t.history_window(start, start + T) if self.online else t.window(start, start + T))
                truth.append(t.states[start + T + 1 : start + T + F + 1, 0])
        if len(hist) < 2:
            raise ValueError(f"DirectRegression needs at least 2 training windows of window + horizon = {T + F} "
                             f"steps, got {len(hist)}")
        self.regression_ = FutureRegression(self.max_iter, self.learning_rate, self.random_state).fit(
            self.keys(hist), self._base(hist), np.stack(truth))
        self.n_samples_ = len(hist)
        return self

    def predict_s(self, histories) -> np.ndarray:
        """Arc lengths (M, horizon) [m] over the steps after each history's end."""
        if not hasattr(self, "regression_"):
            raise ValueError("DirectRegression is not fitted: call fit(trajectories) first")
        return self.regression_.predict(self.keys(histories), self._base(histories))
