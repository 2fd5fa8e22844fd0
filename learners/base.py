"""The learner contract shared by TIRL, PIRL-GMM, PIRL-kNN and PIRL-DPGMM.

scikit-learn conventions: ``__init__`` only stores its arguments, ``fit(trajectories)`` validates and returns
``self``, learned state ends in ``_``, using an unfitted learner raises ``NotFittedError``.

Online use: ``infer_weights(history)`` gives the normalised weights (reference feature = 1, see
`pirl_sim.features.FeatureSet.normalize`) that explain a (partial) trajectory, and ``predict(history, horizon)``
rolls the MPC forward from the last state of the history under those weights.

Feature windows. With ``window=None`` a trajectory is described by the features of the whole of it (the
paper's protocol). With ``window=T`` a history is described by the features of its last T steps, and training
trajectories by all their windows of T steps (every ``stride`` steps), so that look-ups compare like with like.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.preprocessing import StandardScaler
from sklearn.utils.validation import check_is_fitted

from pirl_sim.irl import IRLResult, LogNormalPrior, attach_gauss_newton, fit_weights
from pirl_sim.model import DriverModel, synthetic_model
from pirl_sim.receding import fit_receding
from pirl_sim.trajectory import Trajectory
from pirl_sim.validation import is_positive_int

__all__ = ["BaseLearner", "FEATURE_TRANSFORMS"]

FEATURE_TRANSFORMS = ("log", "none")
LIKELIHOODS = ("trajectory", "receding")
IRL_HESSIANS = ("auto", "exact", "gauss_newton")
WINDOW_MODES = ("sliding", "first")
_LOG_FLOOR = 1e-12  # features are sums of squares: floor before the log so that exact zeros stay finite


class BaseLearner(BaseEstimator):
    """Shared machinery; subclasses implement ``_fit`` and ``_infer``.

    Common parameters
    -----------------
    model : DriverModel or None
        Dynamics, features and predictor. None: the paper's synthetic point-mass LQR model.
    window : int or None
        Feature window in steps (see module doc).
    stride : int
        Step between training windows.
    windows : {"sliding", "first"}
        Which training windows: every ``stride`` steps, or only the first ``window`` steps of each trajectory
        (for problems whose histories always start at the beginning of an episode, like the synthetic one).
    feature_transform : {"log", "none"}
        Feature space for clustering and look-ups, always standardised afterwards.
    log_bounds : (float, float)
        Box on the IRL's log-weights (see `pirl_sim.irl`).
    likelihood : {"trajectory", "receding"}
        The IRL's model of a demonstration. "trajectory": the paper's, one open-loop optimum of a cost over
        the whole demonstration (Laplace approximation, `pirl_sim.irl`). "receding": a driver who re-plans
        every step, each step's control the first of the MPC's plan over ``horizon`` steps plus noise
        (`pirl_sim.receding`; per-step masks in the ``step_mask`` metadata are honoured). Its fitted
        ``irl_result_`` also has ``sigma`` (residual noise per group).
    horizon : int or None
        The drivers' MPC horizon [steps]; required with ``likelihood="receding"``.
    step_stride : int
        With ``likelihood="receding"``: score every ``step_stride``-th recorded step.
    irl_hessian : {"auto", "exact", "gauss_newton"}
        With ``likelihood="trajectory"``: the cost Hessian inside the Laplace likelihood (`pirl_sim.irl.fit_weights`):
        "auto" (default) fits with the exact one and refits with the Gauss-Newton one the groups whose exact
        Hessian was indefinite at the solution or that did not converge.
    irl_max_iter : int
        Newton iterations of the IRL (`pirl_sim.irl.fit_weights` ``max_iter``; its Gauss-Newton refit may take
        5x). Short, smooth segments can need more than the default 100: on DR_USA_Roundabout_EP, 2 of 10,624
        next-steps segments of PIRL-kNN took 850-1,250 iterations.
    """

    # ------------------------------------------------------------------ validation helpers
    def _model(self) -> DriverModel:
        model = self.model if self.model is not None else synthetic_model()
        if not isinstance(model, DriverModel):
            raise TypeError(f"model must be a pirl_sim.DriverModel or None, got {type(model).__name__}")
        return model

    def _check_common(self) -> None:
        if self.window is not None:
            if not is_positive_int(self.window):
                raise ValueError(f"window must be a positive number of steps or None, got {self.window!r}")
        if not is_positive_int(self.stride):
            raise ValueError(f"stride must be a positive number of steps, got {self.stride!r}")
        if self.windows not in WINDOW_MODES:
            raise ValueError(f"windows must be one of {WINDOW_MODES}, got {self.windows!r}")
        if self.feature_transform not in FEATURE_TRANSFORMS:
            raise ValueError(f"feature_transform must be one of {FEATURE_TRANSFORMS}, got {self.feature_transform!r}")
        if self.likelihood not in LIKELIHOODS:
            raise ValueError(f"likelihood must be one of {LIKELIHOODS}, got {self.likelihood!r}")
        if self.likelihood == "receding" and not is_positive_int(self.horizon):
            raise ValueError(f"likelihood='receding' needs horizon, the drivers' MPC horizon as a positive number "
                             f"of steps; got horizon={self.horizon!r}")
        if self.irl_hessian not in IRL_HESSIANS:
            raise ValueError(f"irl_hessian must be one of {IRL_HESSIANS}, got {self.irl_hessian!r}")
        if not is_positive_int(self.step_stride):
            raise ValueError(f"step_stride must be a positive number of steps, got {self.step_stride!r}")
        if not is_positive_int(self.irl_max_iter):
            raise ValueError(f"irl_max_iter must be a positive number of iterations, got {self.irl_max_iter!r}")

    # ------------------------------------------------------------------ windows and feature space
    def _training_windows(self, trajectories: list[Trajectory]) -> tuple[list[Trajectory], np.ndarray]:
        """Samples used for look-ups and their owning trajectory index."""
        if self.window is None:
            return trajectories, np.arange(len(trajectories))
        samples, owners = [], []
        for i, t in enumerate(trajectories):
            last = 0 if self.windows == "first" else t.n_steps - self.window
            for start in range(0, min(last, t.n_steps - self.window) + 1, self.stride):
                samples.append(t.window(start, start + self.window))
                owners.append(i)
        if not samples:
            shortest = min(t.n_steps for t in trajectories)
            raise ValueError(f"window={self.window} steps is longer than every training trajectory (shortest {shortest})")
        return samples, np.asarray(owners)

    def _query_windows(self, histories: list[Trajectory]) -> list[Trajectory]:
        if self.window is None:
            return histories
        for i, h in enumerate(histories):
            if h.n_steps < self.window:
                raise ValueError(
                    f"history {i} has {h.n_steps} steps, shorter than the feature window of {self.window} steps"
                )
        return [h.window(h.n_steps - self.window) for h in histories]


    def _raw_to_space(self, values: np.ndarray) -> np.ndarray:
        if self.feature_transform == "log":
            return np.log(np.maximum(values, _LOG_FLOOR))
        return values

    def _fit_space(self, values: np.ndarray) -> np.ndarray:
        z = self._raw_to_space(values)
        self.scaler_ = StandardScaler().fit(z)
        return self.scaler_.transform(z)

    def _to_space(self, values: np.ndarray) -> np.ndarray:
        return self.scaler_.transform(self._raw_to_space(values))

    # ------------------------------------------------------------------ IRL helper
    def _irl(
        self, model: DriverModel, samples: list[Trajectory], labels: np.ndarray, n_groups: int, prior=None
    ) -> IRLResult:
        if self.likelihood == "receding":
            if prior is not None:
                raise ValueError("a prior on the weights is not available with likelihood='receding'")
            return fit_receding(model, samples, labels, horizon=int(self.horizon), n_groups=n_groups,
                                stride=int(self.step_stride), log_bounds=self.log_bounds)
        hessian = self.irl_hessian
        blocks = model.laplace_blocks(samples)
        if hessian != "exact":
            blocks = attach_gauss_newton(blocks, model.features, model.dynamics, model.check(samples))
        return fit_weights(
            [b for b, _ in blocks],
            [labels[idx] for _, idx in blocks],
            model.features,
            n_groups=n_groups,
            prior=prior,
            log_bounds=self.log_bounds,
            hessian=hessian,
            max_iter=int(self.irl_max_iter),
        )

    # ------------------------------------------------------------------ public API
    def fit(self, trajectories: Sequence[Trajectory], y=None) -> "BaseLearner":
        """Learn from demonstrations; returns self."""
        self._check_common()
        model = self._model()
        trajectories = model.check(trajectories)
        self.model_ = model
        self.n_features_in_ = model.features.n_features
        self.feature_names_in_ = np.array(model.features.names, dtype=object)
        self._fit(model, trajectories)
        return self

    def _as_histories(self, histories) -> tuple[list[Trajectory], bool]:
        single = isinstance(histories, Trajectory)
        return self.model_.check([histories] if single else histories), single

    def infer_weights(self, histories: Trajectory | Sequence[Trajectory]) -> np.ndarray:
        """Normalised weights explaining each history: (K,) for one history, (M, K) for a sequence."""
        check_is_fitted(self)
        histories, single = self._as_histories(histories)
        theta = self._infer(histories)
        return theta[0] if single else theta

    def predict_states(self, histories: Trajectory | Sequence[Trajectory], horizon: int) -> np.ndarray:
        """Predicted states after each history: (horizon + 1, n_x) or (M, horizon + 1, n_x); row 0 is the
        last state of the history."""
        check_is_fitted(self)
        histories, single = self._as_histories(histories)
        theta = self._infer(histories)
        x0 = np.stack([h.states[-1] for h in histories])
        states = self.model_.predict_states(x0, theta, horizon)
        return states[0] if single else states

    def predict_futures(self, histories: Trajectory | Sequence[Trajectory], horizon: int, n_futures: int | None = None,
                        random_state=None) -> tuple[np.ndarray, np.ndarray]:
        """K predicted futures of each history with their probabilities (issue 14 item 3, multi-modal prediction).

        This base version has a single future, the point prediction of `predict_states`, with probability 1
        (K = 1 whatever ``n_futures`` asks: a learner with one cost per history has nothing else to offer, e.g.
        TIRL); the probabilistic learners override it (PIRL-GMM/DPGMM: one future per style or weights drawn from
        the style mixture; PIRL-kNN: neighbours drawn by their votes).

        Parameters
        ----------
        histories : Trajectory or sequence of M Trajectory
        horizon : int           predicted steps, >= 1
        n_futures : int or None  K, the number of futures asked for (>= 1); None: the learner's own choice
        random_state : None, int or numpy.random.Generator
            Seed of the draws of the learners that draw (`numpy.random.default_rng`); unused here.

        Returns
        -------
        states : array (M, K, horizon + 1, n_x), or (K, horizon + 1, n_x) for one history
            Row 0 of every future is the last state of its history.
        proba : array (M, K) or (K,)     probability of each future; rows sum to 1
        """
        self._check_futures_args(horizon, n_futures)
        states = self.predict_states(histories, horizon)
        return states[..., None, :, :], np.ones(states.shape[:-2] + (1,))

    @staticmethod
    def _check_futures_args(horizon, n_futures) -> None:
        if not is_positive_int(horizon):
            raise ValueError(f"horizon must be a positive number of steps, got {horizon!r}")
        if n_futures is not None and not is_positive_int(n_futures):
            raise ValueError(f"n_futures (K, the number of predicted futures) must be an integer >= 1 or None, "
                             f"got {n_futures!r}")

    def predict(self, history: Trajectory, horizon: int) -> Trajectory:
        """The predicted future of one history as a `Trajectory` (metadata: the weights used)."""
        if not isinstance(history, Trajectory):
            raise TypeError(f"history must be a Trajectory, got {type(history).__name__}")
        theta = self.infer_weights(history)
        states = self.model_.predict_states(history.states[-1][None], theta, horizon)[0]
        controls = self.model_.dynamics.controls_from_states(states)
        return Trajectory(states, controls, history.dt, {"theta": theta, "predicted_by": type(self).__name__})

    # ------------------------------------------------------------------ files
    def save(self, path) -> "Path":
        """Write the fitted learner to a versioned ``.npz`` file that needs no pickle to read
        (`pirl_sim.learners.model_io`); returns the path written."""
        from .model_io import save_learner

        return save_learner(self, path)

    @staticmethod
    def load(path) -> "BaseLearner":
        """A learner written by `save` (of any learner class); ValueError for a file of another format version."""
        from .model_io import load_learner

        return load_learner(path)

    # subclasses
    def _fit(self, model: DriverModel, trajectories: list[Trajectory]) -> None:  # pragma: no cover
        raise NotImplementedError

    def _infer(self, histories: list[Trajectory]) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError


def population_prior(
    result: IRLResult, reference_index: int, log_bounds: tuple[float, float], min_std: float = 0.1
) -> LogNormalPrior:
    """A Gaussian prior on the IRL coordinates (log beta, log normalised weights) fitted to the
    per-demonstration estimates that are not at a bound; a coordinate with fewer than two interior estimates
    gets a flat-ish prior (centred, as wide as the bounds)."""
    K = result.theta.shape[1]
    ref = reference_index
    w = np.log(result.normalized)
    w[:, ref] = np.log(result.beta)
    mean, std = np.zeros(K), np.ones(K)
    for k in range(K):
        ok = ~result.at_bound[:, k]
        if ok.sum() < 2:
            # a coordinate that sits at a bound for (almost) everyone gets no prior pull: wide and centred
            mean[k], std[k] = 0.0, float(log_bounds[1] - log_bounds[0])
            continue
        mean[k] = float(np.mean(w[ok, k]))
        std[k] = max(float(np.std(w[ok, k])), min_std)
    return LogNormalPrior(mean, std)
