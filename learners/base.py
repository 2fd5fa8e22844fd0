"""The learner contract shared by TIRL, PIRL-GMM, PIRL-kNN and PIRL-DPGMM.

scikit-learn conventions: ``__init__`` only stores its arguments, ``fit(trajectories)`` validates and returns
``self``, learned state ends in ``_``, using an unfitted learner raises ``NotFittedError``. Online,
``infer_weights(history)`` gives the normalised weights (reference feature = 1) that explain a (partial)
trajectory and ``predict(history, horizon)`` rolls the MPC forward from its last state under them; both, and
``predict_states`` and ``score``, take one `Trajectory` or a sequence of them.

The inputs are trajectories, not a feature matrix: ``n_features_in_`` is the number K of cost features and
``feature_names_in_`` their names. ``fit(histories, futures)`` and ``score(histories, futures)`` (minus the MED
[m]) let ``GridSearchCV`` run on lists of trajectories. ``window=None`` describes a trajectory by the features of
the whole of it; ``window=T`` by those of its last T steps (training trajectories: all their T-step windows).

See the documentation's "The learners" page.
"""

from __future__ import annotations

from typing import Sequence

import math
import warnings

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.preprocessing import StandardScaler
from sklearn.utils.validation import check_is_fitted

from pirl_sim.irl import IRLResult, LogNormalPrior, attach_gauss_newton, fit_weights
from pirl_sim.metrics import med
from pirl_sim.model import DriverModel, synthetic_model
from pirl_sim.mpc import MAX_HORIZON
from pirl_sim.receding import fit_receding
from pirl_sim.trajectory import Trajectory
from pirl_sim.validation import is_positive_int

__all__ = ["BaseLearner", "FEATURE_TRANSFORMS"]

FEATURE_TRANSFORMS = ("log", "none")
LIKELIHOODS = ("trajectory", "receding")
IRL_HESSIANS = ("auto", "exact", "gauss_newton")
WINDOW_MODES = ("sliding", "first")
_LOG_FLOOR = 1e-12  # features are sums of squares: floor before the log so that exact zeros stay finite


def check_log_bounds(value) -> tuple[float, float]:
    """``log_bounds`` as (low, high) floats; ValueError naming it and the allowed form unless it is a pair of
    finite numbers with low < high (e.g. ``(-20.0, 20.0)``)."""
    ok = (not isinstance(value, (str, bytes, dict)) and hasattr(value, "__len__") and len(value) == 2
          and all(not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating)) and math.isfinite(v)
                  for v in value))
    if not ok or not value[0] < value[1]:
        raise ValueError(f"log_bounds must be a pair (low, high) of finite numbers with low < high, the box on the "
                         f"IRL's log-weights, e.g. (-20.0, 20.0); got {value!r}")
    return float(value[0]), float(value[1])


def check_horizon(horizon) -> int:
    """``horizon`` as an int; ValueError unless it is a whole number of steps from 1 to `MAX_HORIZON`."""
    if not is_positive_int(horizon):
        raise ValueError(f"horizon must be a positive number of steps, got {horizon!r}")
    if horizon > MAX_HORIZON:
        raise ValueError(f"horizon must be at most {MAX_HORIZON} steps (MAX_HORIZON: the MPC's matrices grow with "
                         f"the square of the horizon), got {horizon!r}")
    return int(horizon)


class BaseLearner(BaseEstimator):
    """Shared machinery; subclasses implement ``_fit`` and ``_infer``. The parameters are common to every learner.

    Parameters
    ----------
    model : DriverModel or None           dynamics, features and predictor; None: the paper's synthetic point mass
    window, stride : int or None, int     feature window [steps] (module doc); step between training windows
    windows : {"sliding", "first"}        every ``stride`` steps, or only the first ``window`` steps of a trajectory
    feature_transform : {"log", "none"}   feature space of clustering and look-ups, standardised afterwards
    log_bounds : (float, float)           box on the IRL's log-weights (`pirl_sim.irl`)
    likelihood : {"trajectory", "receding"}   one open-loop plan (`pirl_sim.irl`) or re-planning (`pirl_sim.receding`)
    horizon, step_stride : int or None, int   ``"receding"``: the drivers' MPC horizon [steps] (required); step stride
    irl_hessian : {"auto", "exact", "gauss_newton"}   ``"trajectory"``: the cost Hessian (`pirl_sim.irl.fit_weights`)
    irl_max_iter : int                    Newton iterations of the IRL (its Gauss-Newton refit may take 5x)
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
        check_log_bounds(self.log_bounds)

    def _check_params(self, model: DriverModel) -> None:
        """Every check of the parameters that needs no data (what `fit` checks before it looks at the
        trajectories; `pirl_sim.learners.model_io` runs it on a learner read from a file). Subclasses add
        theirs."""
        self._check_common()

    def _check_data_scale(self, model: DriverModel, trajectories: list[Trajectory]) -> None:
        """ValueError when a training trajectory's features are not finite numbers (states or controls so large
        that their squares overflow float64): the IRL cannot weigh them."""
        with np.errstate(all="ignore"):
            values = model.feature_values(trajectories)
        bad = ~np.isfinite(values)
        if bad.any():
            i, k = (int(j) for j in np.argwhere(bad)[0])
            t = trajectories[i]
            size = max(float(np.max(np.abs(t.states))), float(np.max(np.abs(t.controls), initial=0.0)))
            raise ValueError(f"training trajectory {i}: feature {model.features.names[k]!r} overflows float64 "
                             f"(states or controls up to {size:.3g}); rescale the data (SI units: m, m/s, ...)")

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
        # numpy's overflow (and the invalid operations that follow it) become one warning that says what to do
        errors = []
        with np.errstate(over="call", invalid="call", call=lambda kind, flag: errors.append(kind)):
            res = self._irl_fit(model, samples, labels, n_groups, prior)
        if errors:
            with np.errstate(all="ignore"):
                top = np.max(np.abs(model.feature_values(samples)), axis=0)
            k = int(np.argmax(top))
            warnings.warn(f"{type(self).__name__}: floating-point overflow or invalid values in the IRL "
                          f"({len(errors)} operations): its weights are not reliable. The features reach {top[k]:.3g} "
                          f"({model.features.names[k]!r}); rescale the states and controls (SI units: m, m/s, ...) so "
                          "that the features' sums stay far below the float64 limit 1.8e308", UserWarning, stacklevel=3)
        return res

    def _irl_fit(self, model, samples, labels, n_groups, prior):
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
    def fit(self, trajectories: Sequence[Trajectory], y: Sequence[Trajectory] | None = None) -> "BaseLearner":
        """Learn from demonstrations; returns self.

        Parameters
        ----------
        trajectories : sequence of M Trajectory
            The demonstrations, or (with ``y``) their histories.
        y : sequence of M Trajectory or None
            The futures of the histories (scikit-learn's targets, as `score` takes them): demonstration i is
            ``trajectories[i]`` followed by ``y[i]``, whose first state must be the history's last. None: the
            trajectories are the demonstrations.
        """
        model = self._model()
        self._check_params(model)
        if y is not None:
            trajectories = _join(model.check(trajectories), model.check(y))
        trajectories = model.check(trajectories)
        self._check_data_scale(model, trajectories)
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
        check_horizon(horizon)
        histories, single = self._as_histories(histories)
        theta = self._infer(histories)
        x0 = np.stack([h.states[-1] for h in histories])
        states = self.model_.predict_states(x0, theta, horizon)
        return states[0] if single else states

    def predict_futures(self, histories: Trajectory | Sequence[Trajectory], horizon: int, n_futures: int | None = None,
                        random_state=None) -> tuple[np.ndarray, np.ndarray]:
        """K predicted futures of each history with their probabilities (multi-modal prediction): here one, the point
        prediction of `predict_states`, with probability 1 (K = 1); the probabilistic learners override it ("The
        learners" page, Multi-modal prediction).

        Parameters
        ----------
        histories : Trajectory or sequence of M Trajectory
        horizon : int                predicted steps, >= 1
        n_futures, random_state : int or None, seed   K >= 1 asked for (None: the learner's choice); seed of the draws

        Returns
        -------
        states, proba : array (M, K, horizon + 1, n_x), (M, K)   futures from the history's last state (row 0),
                                     and their probabilities (rows sum to 1); without M for one history
        """
        self._check_futures_args(horizon, n_futures)
        states = self.predict_states(histories, horizon)
        return states[..., None, :, :], np.ones(states.shape[:-2] + (1,))

    @staticmethod
    def _check_futures_args(horizon, n_futures) -> None:
        check_horizon(horizon)
        if n_futures is not None and not is_positive_int(n_futures):
            raise ValueError(f"n_futures (K, the number of predicted futures) must be an integer >= 1 or None, "
                             f"got {n_futures!r}")

    def predict(self, history: Trajectory | Sequence[Trajectory], horizon: int) -> Trajectory | list[Trajectory]:
        """The predicted future of a history as a `Trajectory` (metadata: the weights used), the MPC's from the
        history's last state under `infer_weights`' weights; for a sequence of histories, a list of them.

        Parameters
        ----------
        history : Trajectory or sequence of M Trajectory
        horizon : int   predicted steps, 1 to `pirl_sim.mpc.MAX_HORIZON`
        """
        check_horizon(horizon)
        if not isinstance(history, Trajectory):
            if isinstance(history, (str, bytes)) or not hasattr(history, "__len__"):
                raise TypeError(f"history must be a Trajectory or a sequence of them, got {type(history).__name__}")
            histories = list(history)
            if not all(isinstance(h, Trajectory) for h in histories):
                odd = next(type(h).__name__ for h in histories if not isinstance(h, Trajectory))
                raise TypeError(f"history must be a Trajectory or a sequence of them, got a sequence holding a {odd}")
            theta = self.infer_weights(histories)
            x0 = np.stack([h.states[-1] for h in histories])
            states = self.model_.predict_states(x0, theta, horizon)
            return [Trajectory(s, self.model_.dynamics.controls_from_states(s), h.dt,
                               {"theta": th, "predicted_by": type(self).__name__})
                    for h, s, th in zip(histories, states, theta)]
        theta = self.infer_weights(history)
        states = self.model_.predict_states(history.states[-1][None], theta, horizon)[0]
        controls = self.model_.dynamics.controls_from_states(states)
        return Trajectory(states, controls, history.dt, {"theta": theta, "predicted_by": type(self).__name__})

    def score(self, histories: Trajectory | Sequence[Trajectory], futures: Trajectory | Sequence[Trajectory]) -> float:
        """Negative mean Euclidean distance (MED) [m] between the predicted and the true positions of the futures
        (higher is better, scikit-learn's convention; 0 for perfect predictions).

        Each history's future is predicted by `predict_states` over as many steps as its true future has, from
        the history's last state; MED = (1/M) sum_i (1/N_i) sum_j |p_hat_ij - p_ij| over the N_i predicted
        positions (`pirl_sim.metrics.med`, the model's ``positions``).

        Parameters
        ----------
        histories : Trajectory or sequence of M Trajectory
        futures : Trajectory or sequence of M Trajectory   what followed each history (states[0] its last state)
        """
        check_is_fitted(self)
        histories, _ = self._as_histories(histories)
        futures = self.model_.check([futures] if isinstance(futures, Trajectory) else futures)
        if len(futures) != len(histories):
            raise ValueError(f"score needs one future per history, got {len(histories)} histories and "
                             f"{len(futures)} futures")
        lengths = np.array([f.n_steps for f in futures])
        predicted = [None] * len(futures)
        for n in np.unique(lengths):
            idx = np.flatnonzero(lengths == n)
            states = self.predict_states([histories[i] for i in idx], int(n))
            for j, i in enumerate(idx):
                predicted[i] = self.model_.positions(states[j, 1:])  # type: ignore[call-overload]
        return -med(predicted, [self.model_.positions(f.states[1:]) for f in futures])  # type: ignore[arg-type]

    # subclasses
    def _fit(self, model: DriverModel, trajectories: list[Trajectory]) -> None:  # pragma: no cover
        raise NotImplementedError

    def _infer(self, histories: list[Trajectory]) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError


def _join(histories: list[Trajectory], futures: list[Trajectory]) -> list[Trajectory]:
    """Each history followed by its future (metadata of the history)."""
    if len(histories) != len(futures):
        raise ValueError(f"fit with futures needs one future per history, got {len(histories)} histories and "
                         f"{len(futures)} futures")
    out = []
    for i, (h, f) in enumerate(zip(histories, futures)):
        if h.dt != f.dt or not np.allclose(f.states[0], h.states[-1], rtol=1e-9, atol=1e-9):
            raise ValueError(f"future {i} does not start where history {i} ends (its first state and dt must be "
                             f"the history's last state and dt)")
        meta = dict(h.metadata)
        if "step_mask" in h.metadata or "step_mask" in f.metadata:  # one flag per step: both parts' flags
            meta["step_mask"] = np.concatenate([np.asarray(t.metadata.get("step_mask", np.ones(t.n_steps, bool)))
                                                for t in (h, f)])
        out.append(Trajectory(np.concatenate([h.states, f.states[1:]]), np.concatenate([h.controls, f.controls]),
                              h.dt, meta))
    return out


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
