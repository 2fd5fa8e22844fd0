"""TIRL: one cost for every demonstration (continuous-domain IRL of Levine & Koltun 2012)."""

from __future__ import annotations

import numpy as np

from .model_io import SavableLearner

__all__ = ["TIRL"]


class TIRL(SavableLearner):
    """Traditional IRL: a single weight vector maximises the Laplace likelihood of all demonstrations.

    Attributes
    ----------
    theta_ : array (K,)        normalised weights (reference feature = 1)
    beta_ : float              fitted scale (rationality; with ``likelihood="receding"``: 1 / sigma^2)
    irl_result_ : IRLResult or RecedingResult

    Parameters as `BaseLearner` (``likelihood="receding"`` with ``horizon`` for drivers who re-plan).
    """

    def __init__(self, model=None, *, window=None, stride=1, windows="sliding", feature_transform="log",
                 log_bounds=(-20.0, 20.0), likelihood="trajectory", horizon=None, step_stride=1,
                 irl_hessian="auto", irl_max_iter=100):
        self.model = model
        self.window = window
        self.stride = stride
        self.windows = windows
        self.feature_transform = feature_transform
        self.log_bounds = log_bounds
        self.likelihood = likelihood
        self.horizon = horizon
        self.step_stride = step_stride
        self.irl_hessian = irl_hessian
        self.irl_max_iter = irl_max_iter

    def _fit(self, model, trajectories):
        res = self._irl(model, trajectories, np.zeros(len(trajectories), dtype=int), 1)
        self.irl_result_ = res
        self.theta_ = res.normalized[0]
        self.beta_ = float(res.beta[0])

    def _infer(self, histories):
        self._query_windows(histories)  # same validation as the other learners
        return np.tile(self.theta_, (len(histories), 1))
