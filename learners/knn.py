"""PIRL-kNN: one cost per demonstration offline, inverse-distance k-nearest-neighbour regression online.

Offline, continuous-domain IRL runs on every training demonstration at once (batched Newton, `pirl_sim.irl`).
Online, the k training samples nearest to a history in the standardised feature space vote with weights
1 / distance (the paper's Algorithm 3), on log weights by default (``average="linear"``: the weights).
Options: ``prior="population"`` (MAP refits under a log-normal prior), ``weighting="likelihood"`` (votes by
p(history | theta_i)), ``target="next"`` (costs fitted to what followed each training window; look-up keys from
the last states, ``state_features``, ``state_lags``, ``lookup_ahead``; ``segment_start``), ``aggregate`` =
``"weights"``, ``"futures"`` (the neighbours' futures averaged) or ``"selected"`` (a learned choice among a bank
of costs, `pirl_sim.learners.selector`).

The options and what they are for are explained in the documentation's "The learners" page.
"""

from __future__ import annotations

import copy

import numpy as np
from sklearn.neighbors import NearestNeighbors
from sklearn.preprocessing import StandardScaler

from pirl_sim.dynamics import constant_acceleration_positions
from pirl_sim.trajectory import Trajectory
from pirl_sim.validation import is_positive_int, number

from .base import population_prior
from .model_io import SavableLearner
from .selector import ErrorRegression, FutureRegression, cost_bank, mixture_weights, rollout_errors, softmin

__all__ = ["PIRLKNN", "knn_average", "inverse_distance_votes", "steer_segment", "history_keys", "place_keys"]

AVERAGES = ("log", "linear")
PRIORS = (None, "population")
WEIGHTINGS = ("distance", "likelihood")
TARGETS = ("demo", "next")
AGGREGATES = ("weights", "futures", "selected")
MIXTURES = ("futures", "selected")  #: aggregates whose prediction is a mixture of several costs' futures
SELECTORS = ("forecast", "errors")  #: how ``aggregate="selected"`` learns its choice of costs
SEGMENT_STARTS = ("track", "history")
#: how ``segment_start="history"`` re-starts a next-steps segment (`pirl_sim.dynamics.LinearDynamics.steer`):
#: weights on the position [1/m^2] and speed [s^2/m^2] along the path, ridge on the controls (jerk, [s^6/m^2])
STEER = {"weights": (1.0, 1.0), "ridge": 1e-2}
#: held-out training windows (evenly spaced) on which several ``ahead_weights`` are compared
AHEAD_VALIDATION = 1000
#: ``aggregate="selected"``: training windows (evenly spaced) on which the bank costs' errors are learned, and
#: boosting iterations of each bank cost's error regression
SELECTION_WINDOWS = 4000
SELECTOR_ITER = 100
#: ``selector="forecast"``: the forecast (`FutureRegression`) regresses this many principal components of the
#: next-steps residuals (None: every step), each by a boosted ensemble of FORECAST_ITER iterations at
#: FORECAST_LEARNING_RATE. On DR_USA_Roundabout_FT (5 files, split seeds 0 and 1, 15 steps) 4 components at 100
#: iterations and 0.1 fit in ~1/7 of the time with PIRL-select's MED ~0.003 m higher (within its standard error
#: over seeds); the default keeps every step
FORECAST_COMPONENTS = None
FORECAST_ITER = 200
FORECAST_LEARNING_RATE = 0.05


class PIRLKNN(SavableLearner):
    """PIRL with a k-nearest-neighbour prior over per-demonstration costs ("The learners" page: PIRL-kNN, PIRL-select;
    "In detail: learners.knn" lists every parameter and attribute, one line each, and says what each option is for).

    Parameters
    ----------
    n_neighbors, average, prior, weighting : int, str   k (at most the training samples); how the costs are combined
    target, target_steps, state_features, state_lags, lookup_features, lookup_history, segment_start : see the page.
    lookup_ahead, ahead_weights : tuple of float   distances ahead [m] of the road's curvature in the look-up; weights
    aggregate, selector, n_candidates, temperature : see the page (``"selected"``: `pirl_sim.learners.selector`).
    model, window, stride, feature_transform, log_bounds, irl_max_iter : see `BaseLearner`.

    Attributes
    ----------
    demo_theta_, sample_theta_ : array (M, K), (S, K)   weights of each demonstration (or segment), each look-up sample
    """

    def __init__(
        self,
        model=None,
        *,
        n_neighbors=1,
        average="log",
        prior=None,
        window=None,
        stride=1,
        windows="sliding",
        feature_transform="log",
        log_bounds=(-20.0, 20.0),
        likelihood="trajectory",
        horizon=None,
        step_stride=1,
        irl_hessian="auto",
        weighting="distance",
        target="demo",
        target_steps=None,
        state_features=(),
        state_lags=(0,),
        lookup_features=True,
        aggregate="weights",
        lookup_history=False,
        segment_start="track",
        lookup_ahead=(),
        ahead_weights=(1.0,),
        selector="forecast",
        n_candidates=32,
        temperature=0.05,
        irl_max_iter=100,
    ):
        self.model = model
        self.n_neighbors = n_neighbors
        self.average = average
        self.prior = prior
        self.weighting = weighting
        self.window = window
        self.stride = stride
        self.windows = windows
        self.feature_transform = feature_transform
        self.log_bounds = log_bounds
        self.likelihood = likelihood
        self.horizon = horizon
        self.step_stride = step_stride
        self.irl_hessian = irl_hessian
        self.target = target
        self.target_steps = target_steps
        self.state_features = state_features
        self.state_lags = state_lags
        self.lookup_features = lookup_features
        self.aggregate = aggregate
        self.lookup_history = lookup_history
        self.segment_start = segment_start
        self.lookup_ahead = lookup_ahead
        self.ahead_weights = ahead_weights
        self.selector = selector
        self.n_candidates = n_candidates
        self.temperature = temperature
        self.irl_max_iter = irl_max_iter

    def _check_target(self, model) -> tuple[int, ...]:
        """Validate target, target_steps, state_features, aggregate; returns the state indices."""
        if self.target not in TARGETS:
            raise ValueError(f"target must be one of {TARGETS}, got {self.target!r}")
        if self.aggregate not in AGGREGATES:
            raise ValueError(f"aggregate must be one of {AGGREGATES}, got {self.aggregate!r}")
        if self.target == "next":
            if self.window is None:
                raise ValueError("target='next' needs window, the history length in steps: the next steps "
                                 "follow each window")
            if not is_positive_int(self.target_steps):
                raise ValueError(f"target='next' needs target_steps, a positive number of steps, got "
                                 f"{self.target_steps!r}")
            if self.weighting == "likelihood":
                raise ValueError("weighting='likelihood' scores a history under its neighbours' costs of whole "
                                 "demonstrations; with target='next' use weighting='distance'")
        if self.aggregate == "selected":
            if self.target != "next":
                raise ValueError("aggregate='selected' chooses among costs of what followed training windows: it "
                                 "needs target='next'")
            if not is_positive_int(self.n_candidates):
                raise ValueError(f"n_candidates must be a positive integer (costs in the bank), got "
                                 f"{self.n_candidates!r}")
            if self.selector not in SELECTORS:
                raise ValueError(f"selector must be one of {SELECTORS}, got {self.selector!r}")
            number("temperature", self.temperature, low=0.0, allow_equal=False)
        try:
            idx = tuple(int(i) for i in self.state_features)
        except (TypeError, ValueError):
            raise TypeError(f"state_features must be a sequence of state indices, got {self.state_features!r}") from None
        n_x = model.dynamics.n_x
        if any(isinstance(i, bool) or int(i) != i or not 0 <= int(i) < n_x for i in self.state_features):
            raise ValueError(f"state_features must be indices into the state, 0 to {n_x - 1}, got "
                             f"{self.state_features!r}")
        try:
            lags = tuple(self.state_lags)
        except TypeError:
            raise TypeError(f"state_lags must be a sequence of steps, got {self.state_lags!r}") from None
        if not lags or any(isinstance(i, bool) or not isinstance(i, (int, np.integer)) or i < 0 for i in lags):
            raise ValueError(f"state_lags must be whole numbers of steps >= 0 (0: the last state), got "
                             f"{self.state_lags!r}")
        if not isinstance(self.lookup_features, (bool, np.bool_)):
            raise TypeError(f"lookup_features must be True or False, got {self.lookup_features!r}")
        if not isinstance(self.lookup_history, (bool, np.bool_)):
            raise TypeError(f"lookup_history must be True or False, got {self.lookup_history!r}")
        if self.lookup_history and self.target != "next":
            raise ValueError("lookup_history=True applies to target='next' only")
        if self.segment_start not in SEGMENT_STARTS:
            raise ValueError(f"segment_start must be one of {SEGMENT_STARTS}, got {self.segment_start!r}")
        if self.segment_start == "history" and not (self.target == "next" and self.lookup_history):
            raise ValueError("segment_start='history' starts each next-steps segment from its history's own "
                             "estimate: it needs target='next' and lookup_history=True")
        if self.segment_start == "history" and n_x < 2:
            raise ValueError(f"segment_start='history' follows positions and speeds (state entries 0 and 1); this "
                             f"model has {n_x} state entries")
        ahead = _nonnegative_numbers("lookup_ahead", self.lookup_ahead, "distances [m]", "finite distances >= 0 m")
        aw = _nonnegative_numbers("ahead_weights", self.ahead_weights, "weights",
                                  "distinct finite weights >= 0, at least one", distinct=True)
        if len(aw) > 1 and ahead and self.target != "next":
            raise ValueError("several ahead_weights are chosen on the training windows' next steps: they need "
                             "target='next'")
        if ahead and not callable(getattr(model, "curvature", None)):
            raise ValueError(f"lookup_ahead needs a model along a path with a curvature (PathDriverModel), got "
                             f"{type(model).__name__}")
        if not self.lookup_features and not idx and not ahead:
            raise ValueError("lookup_features=False looks up by state_features alone (and lookup_ahead); give "
                             "some, e.g. state_features=(1, 2)")
        return idx

    def _lookup_values(self, model, windows) -> np.ndarray:
        """Look-up coordinates before standardising: transformed features (unless ``lookup_features`` is
        False), the chosen state entries at each lag before the window's end, then the road's |curvature| at
        ``lookup_ahead`` metres beyond the window's end."""
        parts = [self._raw_to_space(model.feature_values(windows))] if self.lookup_features else []
        lags = [int(lag) for lag in self.state_lags]
        if self.state_idx_:
            short = [j for j, w in enumerate(windows) if w.n_steps < max(lags)]
            if short:
                raise ValueError(f"state_lags reach {max(lags)} steps back, but window {short[0]} has "
                                 f"{windows[short[0]].n_steps} steps")
        parts.append(history_keys(model, windows, self.state_idx_, lags, self.lookup_ahead))
        return np.hstack(parts)

    def _next_pairs(self, model, trajectories) -> tuple[list, list, np.ndarray, np.ndarray]:
        """(history windows, the ``target_steps`` steps after each, every ``stride`` steps; with
        ``segment_start="history"`` each segment re-started from its history's last state), the recorded
        track of each pair (int labels: metadata ``file`` and ``track_id``, else the trajectory) and the
        track's positions over each segment's steps (P, target_steps)."""
        T, F = int(self.window), int(self.target_steps)
        hist, nxt, tracks, truth = [], [], [], []
        for i, t in enumerate(trajectories):
            track = (str(t.metadata.get("file")), str(t.metadata.get("track_id", f"#{i}")))
            for start in range(0, t.n_steps - T - F + 1, int(self.stride)):
                h = t.history_window(start, start + T) if self.lookup_history else t.window(start, start + T)
                seg = t.window(start + T, start + T + F)
                truth.append(seg.states[1:, 0])
                if self.segment_start == "history":
                    seg = steer_segment(model.dynamics, h.states[-1], seg)
                hist.append(h)
                nxt.append(seg)
                tracks.append(track)
        if not hist:
            longest = max(t.n_steps for t in trajectories)
            raise ValueError(f"target='next': no training trajectory has window + target_steps = {T + F} steps "
                             f"(longest {longest})")
        ids: dict = {}
        labels = np.array([ids.setdefault(track, len(ids)) for track in tracks])
        return hist, nxt, labels, np.stack(truth)

    def _next_truth(self, trajectories) -> np.ndarray:
        """The positions over the next ``target_steps`` steps (P, target_steps) of every window `_next_pairs`
        takes from ``trajectories``, in its order, without estimating the histories; (0, target_steps) if none."""
        T, F = int(self.window), int(self.target_steps)
        rows = [t.states[start + T + 1 : start + T + F + 1, 0]
                for t in trajectories for start in range(0, t.n_steps - T - F + 1, int(self.stride))]
        return np.stack(rows) if rows else np.empty((0, F))

    def _check_params(self, model) -> None:
        super()._check_params(model)
        if not is_positive_int(self.n_neighbors):
            raise ValueError(f"n_neighbors must be a positive integer, got {self.n_neighbors!r}")
        if self.average not in AVERAGES:
            raise ValueError(f"average must be one of {AVERAGES}, got {self.average!r}")
        if self.prior not in PRIORS:
            raise ValueError(f"prior must be one of {PRIORS}, got {self.prior!r}")
        if self.weighting not in WEIGHTINGS:
            raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {self.weighting!r}")
        self._check_target(model)

    def _fit(self, model, trajectories):
        k = self.n_neighbors  # the parameters are checked by fit (`_check_params`)
        self.state_idx_ = self._check_target(model)
        if self.target == "next":  # each next-steps segment a demonstration
            samples, trajectories, groups, truth = self._next_pairs(model, trajectories)
            owners = np.arange(len(samples))
        else:
            samples, owners = self._training_windows(trajectories)
        if k > len(samples):
            raise ValueError(
                f"n_neighbors={k} is larger than the number of training samples ({len(samples)} from "
                f"{len(trajectories)} trajectories)"
            )
        labels = np.arange(len(trajectories))
        res = self._irl(model, trajectories, labels, len(trajectories))
        ref = model.features.reference_index
        if self.prior == "population":
            self.prior_ = population_prior(res, ref, self.log_bounds)
            res = self._irl(model, trajectories, labels, len(trajectories), prior=self.prior_)
        self.irl_result_ = res
        others = [i for i in range(res.theta.shape[1]) if i != ref]
        self.n_weights_at_bound_ = int(np.any(res.at_bound[:, others], axis=1).sum()) if others else 0
        self.n_scale_at_bound_ = int(res.at_bound[:, ref].sum())
        self.demo_theta_ = res.normalized
        self.sample_theta_ = res.normalized[owners]
        self.sample_owner_ = owners
        values = self._lookup_values(model, samples)
        self.scaler_ = StandardScaler().fit(values)
        self.lookup_z_ = self.scaler_.transform(values)
        if len(self._ahead_weights()) > 1:  # held-out training windows to choose the road's weight
            pick = np.unique(np.linspace(0, len(samples) - 1, min(AHEAD_VALIDATION, len(samples))).astype(int))
            self.ahead_validation_ = {"pick": pick, "groups": groups, "truth": truth[pick],
                                      "x0": np.stack([samples[i].states[-1] for i in pick])}
        if self.target == "next":  # what a selector learns from, kept for `with_aggregate` (not saved)
            self._next_data = {"x0": np.stack([h.states[-1] for h in samples]),
                               "place": place_keys(model, samples), "truth": truth}
        self._index(int(k))
        if self.aggregate == "selected":
            self._fit_selector(self._next_data)
        if self.weighting == "likelihood":
            self.control_rms_ = float(np.sqrt(np.mean(np.concatenate([np.square(t.controls).ravel()
                                                                       for t in trajectories]))))
            first = self.window is not None and self.windows == "first"
            self.episode_steps_ = int(min(t.n_steps for t in trajectories)) if first else None

    def _fit_selector(self, data: dict) -> None:
        """The bank of costs and the regression its choice is learned from (``selector``, module doc): the
        positions over the next steps ``data["truth"]`` (P, F) [m] of every training window, or the bank's
        errors on up to `SELECTION_WINDOWS` evenly spaced ones, each rolled out from its history's last state
        ``data["x0"]`` (P, n_x); ``data["place"]``: the windows' `place_keys`."""
        self.bank_ = cost_bank(np.log(self.demo_theta_), int(self.n_candidates))
        keys = np.hstack([self.lookup_z_, data["place"]])
        x0, truth = data["x0"], data["truth"]
        if self.selector == "forecast":
            base = constant_acceleration_positions(self.model_.dynamics, x0, truth.shape[1])
            self.selector_ = FutureRegression(FORECAST_ITER, FORECAST_LEARNING_RATE,
                                              n_components=FORECAST_COMPONENTS).fit(keys, base, truth)
            return
        pick = np.unique(np.linspace(0, len(x0) - 1, min(SELECTION_WINDOWS, len(x0))).astype(int))
        self.bank_errors_ = rollout_errors(self.model_, x0[pick], self.demo_theta_[self.bank_], truth[pick])
        self.selector_ = ErrorRegression(SELECTOR_ITER).fit(keys[pick], self.bank_errors_)  # type: ignore[assignment]

    def _selection(self, histories, x0: np.ndarray, bank_states: np.ndarray | None = None) -> np.ndarray:
        """The bank's probabilities (M, C) for each history (``aggregate="selected"``) with last states ``x0``
        (M, n_x); ``bank_states``: the bank's futures (M, C, target_steps + 1, n_x) from x0, if already rolled
        out."""
        keys = np.hstack([self._lookup(histories), place_keys(self.model_, self._query_windows(histories))])
        if self.selector == "errors":
            return softmin(self.selector_.predict(keys), self.temperature)  # type: ignore[call-arg]
        F = int(self.target_steps)
        if bank_states is None:
            bank_states = self._bank_futures(x0, F)
        forecast = self.selector_.predict(keys, constant_acceleration_positions(self.model_.dynamics, x0, F))
        return mixture_weights(bank_states[:, :, 1:, 0], forecast)

    def _bank_futures(self, x0: np.ndarray, horizon: int) -> np.ndarray:
        """Every bank cost's future (M, C, horizon + 1, n_x) from each start x0 (M, n_x)."""
        return self._futures(x0, np.broadcast_to(self.bank_, (len(x0), len(self.bank_))), horizon)

    def with_neighbors(self, n_neighbors: int) -> PIRLKNN:
        """This fitted learner with another number of neighbours k, without refitting its IRL.

        The copy shares everything but the nearest-neighbour index (and the choice among several ``ahead_weights``,
        which depends on k): its predictions equal a fit with ``n_neighbors``, so a sweep over k fits once.

        Parameters
        ----------
        n_neighbors : int, at most the number of look-up samples

        Returns
        -------
        learner : PIRLKNN     a shallow copy (fitted arrays shared, not copied); this learner is not changed
        """
        from sklearn.base import clone
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self, "neighbors_")
        if not is_positive_int(n_neighbors):
            raise ValueError(f"n_neighbors must be a positive integer, got {n_neighbors!r}")
        Z = self.neighbors_._fit_X  # the look-up samples in the learner's (standardised) feature space
        if n_neighbors > len(Z):
            raise ValueError(f"n_neighbors={n_neighbors} is larger than the number of training samples ({len(Z)})")
        out = copy.copy(self)
        out.n_neighbors = n_neighbors
        if hasattr(self, "lookup_z_"):
            out._index(int(n_neighbors))  # the road's weight is chosen for this k, as a fit does
        else:  # fitted before the road's weight existed
            out.neighbors_ = clone(self.neighbors_).set_params(n_neighbors=int(n_neighbors)).fit(Z)
        return out

    #: the parameters `with_aggregate` may change: none of them enters the IRL
    HEAD_PARAMS = ("n_neighbors", "aggregate", "selector", "n_candidates", "temperature")

    def with_aggregate(self, trajectories, **params) -> PIRLKNN:
        """This fitted learner with other `HEAD_PARAMS` (e.g. ``aggregate="selected"`` after ``"futures"``), finished on
        the same training ``trajectories`` as `fit` finishes, without refitting its IRL.

        The copy gets its own index, road-ahead weight and, with ``aggregate="selected"``, bank and selector, so its
        predictions are those of a fit with the parameters. ValueError for a parameter outside `HEAD_PARAMS`, a value
        `fit` would reject, or other ``trajectories`` than this learner was fitted on.

        Returns
        -------
        learner : PIRLKNN     a shallow copy (fitted arrays shared); this learner is not changed
        """
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self, "neighbors_")
        other = sorted(set(params) - set(self.HEAD_PARAMS))
        if other:
            raise ValueError(f"with_aggregate changes only {self.HEAD_PARAMS}; {other} enter the IRL: fit anew")
        out = copy.copy(self)
        for name, value in params.items():
            setattr(out, name, value)
        out._check_params(self.model_)
        for name in ("bank_", "selector_", "bank_errors_"):
            out.__dict__.pop(name, None)
        data = None
        if self.target == "next":
            # the fit's histories (estimated anew from each one's observations) are reused when these
            # trajectories give the fit's next-steps positions; other trajectories are read afresh
            kept = getattr(self, "_next_data", None)
            truth = self._next_truth(trajectories)
            if kept is not None and truth.shape == kept["truth"].shape and np.array_equal(truth, kept["truth"]):
                data = kept
            else:
                samples, _, _, truth = out._next_pairs(self.model_, trajectories)
                data = {"x0": np.stack([h.states[-1] for h in samples]), "place": place_keys(self.model_, samples),
                        "truth": truth}
            out._next_data = data
            n_samples = len(data["truth"])
        else:
            n_samples = len(out._training_windows(trajectories)[0])
        if n_samples != len(self.sample_owner_):
            raise ValueError(f"the trajectories give {n_samples} look-up samples, the fit had "
                             f"{len(self.sample_owner_)}: pass the trajectories this learner was fitted on")
        if int(out.n_neighbors) > n_samples:
            raise ValueError(f"n_neighbors={out.n_neighbors} is larger than the number of training samples "
                             f"({n_samples})")
        out._index(int(out.n_neighbors))
        if out.aggregate == "selected":
            out._fit_selector(data)  # type: ignore[arg-type]
        return out

    def _ahead_weights(self) -> tuple[float, ...]:
        return tuple(float(w) for w in self.ahead_weights) if len(self.lookup_ahead) else (1.0,)

    def _index(self, k: int) -> None:
        """The look-up index over ``lookup_z_`` with the road-ahead block weighted: the one candidate of
        ``ahead_weights``, or the one whose look-up predicts the held-out training windows best
        (`ahead_scores_`)."""
        weights = self._ahead_weights()
        n_ahead = len(self.lookup_ahead)
        Z = self.lookup_z_

        def scaled(w: float) -> np.ndarray:
            scale = np.ones(Z.shape[1])
            if n_ahead:
                scale[-n_ahead:] = w
            return scale

        if self.aggregate == "selected":  # the selector's trees see every key; a key's scale does not matter
            weights = (1.0,)
        if len(weights) > 1:
            self.ahead_scores_ = {w: self._held_out_error(Z * scaled(w), k) for w in weights}
            chosen = min(weights, key=lambda w: (self.ahead_scores_[w], w))
        else:
            chosen = weights[0]
        self.ahead_weight_ = chosen
        self.key_scale_ = scaled(chosen)
        self.neighbors_ = NearestNeighbors(n_neighbors=k).fit(Z * self.key_scale_)

    def _held_out_error(self, Z: np.ndarray, k: int) -> float:
        """Mean |error| [m] of the look-up's prediction of the position along the path over the next steps of
        the held-out training windows (`ahead_validation_`), each predicted from its history's last state by
        its k nearest windows of *other* tracks, as `predict_states` predicts."""
        val = self.ahead_validation_
        groups, pick = val["groups"], val["pick"]
        n_query = min(len(Z), k + int(np.bincount(groups).max()))
        dist, idx = NearestNeighbors(n_neighbors=n_query).fit(Z).kneighbors(Z[pick])
        other = groups[idx] != groups[pick][:, None]
        if (other.sum(axis=1) < k).any():
            raise ValueError(f"ahead_weights: fewer than k={k} training windows of other tracks to validate with")
        order = np.argsort(~other, axis=1, kind="stable")[:, :k]  # the k nearest of other tracks
        dist, idx = np.take_along_axis(dist, order, 1), np.take_along_axis(idx, order, 1)
        F = val["truth"].shape[1]
        if self.aggregate == "futures":
            futures = self._futures(val["x0"], self.sample_owner_[idx], F)
            s_pred = np.einsum("mk,mkf->mf", inverse_distance_votes(dist), np.ascontiguousarray(futures[:, :, 1:, 0]))
        else:
            theta = knn_average(dist, self.sample_theta_[idx], self.average)
            s_pred = self.model_.predict_states(val["x0"], theta, F)[:, 1:, 0]
        return float(np.abs(s_pred - val["truth"]).mean())

    def _lookup(self, histories) -> np.ndarray:
        z = self.scaler_.transform(self._lookup_values(self.model_, self._query_windows(histories)))
        return z * getattr(self, "key_scale_", 1.0)

    def _infer(self, histories):
        if self.aggregate == "selected":  # the most probable bank cost
            x0 = np.stack([h.states[-1] for h in histories])
            return self.demo_theta_[self.bank_[self._selection(histories, x0).argmax(axis=1)]]
        dist, idx = self.neighbors_.kneighbors(self._lookup(histories))
        if self.weighting == "likelihood":
            return self._likelihood_average(histories, idx)
        return knn_average(dist, self.sample_theta_[idx], self.average)

    def predict_futures(self, histories, horizon: int, n_futures: int | None = None,
                        random_state=None) -> tuple[np.ndarray, np.ndarray]:
        """K predicted futures of each history with their probabilities: neighbours drawn by their votes.

        ``n_futures=None``: one future per neighbouring demonstration (or bank cost), in order of vote; ``n_futures=K``:
        min(K, k) drawn without replacement by vote (Gumbel top-K), each under its weights ``demo_theta_``, padded at
        probability 0 ("The learners" page, In detail: learners.knn).

        Parameters
        ----------
        histories, horizon, n_futures, random_state : see `~pirl_sim.learners.base.BaseLearner.predict_futures`.

        Returns
        -------
        states : array (M, K, horizon + 1, n_x), or (K, horizon + 1, n_x) for one history
        proba : array (M, K) or (K,)
        """
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self)
        self._check_futures_args(horizon, n_futures)
        histories, single = self._as_histories(histories)
        x0 = np.stack([h.states[-1] for h in histories])
        bank_states = None
        if self.aggregate == "selected":  # the bank's costs, with their learned probabilities
            if self.selector == "forecast" and horizon == int(self.target_steps):  # roll the bank out once
                bank_states = self._bank_futures(x0, horizon)
            votes = self._selection(histories, x0, bank_states)
            owners = np.broadcast_to(self.bank_, votes.shape)
        else:
            dist, idx = self.neighbors_.kneighbors(self._lookup(histories))
            votes = (self._likelihood_votes(histories, idx) if self.weighting == "likelihood"
                     else inverse_distance_votes(dist))
            owners = self.sample_owner_[idx]  # (M, k)
        k = owners.shape[1]
        M = len(histories)
        K = k if n_futures is None else min(int(n_futures), k)
        rng = None if n_futures is None else np.random.default_rng(random_state)
        chosen = np.empty((M, K), dtype=int)
        proba = np.empty((M, K))
        for m in range(M):
            demos, inverse = np.unique(owners[m], return_inverse=True)
            v = np.bincount(inverse, weights=votes[m], minlength=len(demos))
            with np.errstate(divide="ignore"):
                keys = np.log(v)  # -inf for a zero vote: drawn last
            if rng is not None:
                keys = keys + rng.gumbel(size=keys.shape)
            order = np.argsort(-keys, kind="stable")[:K]  # highest key first; a positive vote comes first
            pad = K - len(order)  # fewer distinct demonstrations than K: repeats of the first at probability 0
            chosen[m] = np.concatenate([demos[order], np.full(pad, demos[order[0]])])
            pv = np.concatenate([v[order], np.zeros(pad)])
            proba[m] = pv / pv.sum()
        if bank_states is not None:  # the chosen bank costs' futures, already rolled out (bank_ is sorted)
            states = np.take_along_axis(bank_states, np.searchsorted(self.bank_, chosen)[:, :, None, None], axis=1)
        else:
            states = self._futures(x0, chosen, horizon)
        return (states[0], proba[0]) if single else (states, proba)

    def _futures(self, x0: np.ndarray, demos: np.ndarray, horizon: int) -> np.ndarray:
        """The MPC's futures (M, K, horizon + 1, n_x) from the starts x0 (M, n_x), each under the weights
        ``demo_theta_`` of the demonstrations ``demos`` (M, K) of its row."""
        M, K = demos.shape
        flat = self.model_.predict_states(np.repeat(x0, K, axis=0), self.demo_theta_[demos.ravel()], horizon)
        return flat.reshape((M, K) + flat.shape[1:])

    def predict_states(self, histories, horizon: int) -> np.ndarray:
        """Predicted states after each history, (M, horizon + 1, n_x) or (horizon + 1, n_x): with
        ``aggregate="weights"`` the MPC under the averaged weights (`BaseLearner.predict_states`), with
        ``"futures"`` the vote-weighted mean of the neighbours' futures (`predict_futures`)."""
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self)
        if self.aggregate == "weights":
            return super().predict_states(histories, horizon)
        states, proba = self.predict_futures(histories, horizon)
        if states.ndim == 3:
            return np.einsum("k,k...->...", proba, states)
        return np.einsum("mk,mk...->m...", proba, states)

    def _likelihood_votes(self, histories, idx: np.ndarray) -> np.ndarray:
        """Neighbour votes ∝ p(history | theta_owner), rows summing to 1, (M, k)."""
        from .weight_space import paired_log_likelihoods

        M, k = idx.shape
        owner = self.sample_owner_[idx].ravel()
        res = self.irl_result_
        gn = getattr(res, "gauss_newton", None)
        sigma = getattr(res, "sigma", None)
        ll = paired_log_likelihoods(
            self.model_, [histories[i] for i in np.repeat(np.arange(M), k)], likelihood=self.likelihood,
            theta=res.theta[owner], normalized=res.normalized[owner], gauss_newton=None if gn is None else gn[owner],
            sigma=None if sigma is None else sigma[owner], noise_floor_controls=np.array([[self.control_rms_]]),
            horizon=self.horizon, step_stride=self.step_stride, episode_steps=self.episode_steps_).reshape(M, k)
        w = np.exp(ll - ll.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        return w

    def _likelihood_average(self, histories, idx: np.ndarray) -> np.ndarray:
        """Neighbour weights ∝ p(history | theta_owner), averaged as ``average`` says, (M, K)."""
        w = self._likelihood_votes(histories, idx)
        theta = self.sample_theta_[idx]
        if self.average == "log":
            return np.exp(np.einsum("mk,mkd->md", w, np.log(theta)))
        return np.einsum("mk,mkd->md", w, theta)


def history_keys(model, windows, state_idx, lags, ahead) -> np.ndarray:
    """Keys of windows by how they ended, (M, len(lags) * len(state_idx) + len(ahead)): the state entries
    ``state_idx`` at each of ``lags`` [steps] before each window's end (lag by lag), then the road's |curvature|
    [1/m] (``model.curvature``, e.g. `pirl_sim.driving.PathDriverModel.curvature`) ``ahead`` metres beyond the
    window's end. The kinematic part of PIRL-kNN's look-up and of the replay's direct regression."""
    idx = list(state_idx)
    parts = [np.stack([np.concatenate([w.states[-1 - lag, idx] for lag in lags]) for w in windows])
             if idx else np.empty((len(windows), 0))]
    ahead = np.asarray(ahead, dtype=float)
    if ahead.size:
        s_end = np.array([w.states[-1, 0] for w in windows])
        parts.append(model.curvature(s_end[:, None] + ahead))
    return np.hstack(parts)


def place_keys(model, windows) -> np.ndarray:
    """Where windows end, (M, 4): the model's reference path's point [m] at each window's last arc length and its
    unit heading there; (M, 0) for a model without a path. The place part of PIRL-select's keys and of the
    replay's direct regression."""
    path = getattr(model, "path", None)
    if path is None:
        return np.empty((len(windows), 0))
    s_end = np.array([w.states[-1, 0] for w in windows])
    zero = np.zeros_like(s_end)
    p0 = path.to_cartesian(s_end, zero)
    step = path.to_cartesian(s_end + 1.0, zero) - p0
    return np.hstack([p0, step / np.maximum(np.linalg.norm(step, axis=1, keepdims=True), 1e-9)])


def _nonnegative_numbers(name: str, values, items: str, allowed: str, *, distinct: bool = False) -> tuple[float, ...]:
    """``values`` as a tuple of finite floats >= 0 (non-empty and without repeats with ``distinct``); TypeError
    unless a sequence of numbers, ValueError naming ``name`` and ``allowed`` otherwise."""
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a sequence of {items}, got {values!r}") from None
    if (any(isinstance(v, bool) for v in values) or not all(np.isfinite(v) and v >= 0 for v in out)
            or (distinct and (not out or len(set(out)) != len(out)))):
        raise ValueError(f"{name} must be {allowed}, got {values!r}")
    return out


def steer_segment(dynamics, x0: np.ndarray, segment: Trajectory) -> Trajectory:
    """``segment`` re-started from the state ``x0`` (n_x,): the trajectory of ``dynamics`` from ``x0`` whose
    controls follow the segment's positions and speeds (state entries 0 and 1) best, weighted as `STEER` says
    (`pirl_sim.dynamics.LinearDynamics.steer`); same length, dt and metadata."""
    weights = np.zeros(dynamics.n_x)
    weights[:2] = STEER["weights"]
    states, controls = dynamics.steer(x0, segment.states[1:], weights, STEER["ridge"])
    return Trajectory(states, controls, segment.dt, segment.metadata)


def knn_average(dist: np.ndarray, theta: np.ndarray, average: str = "log", exact_tol: float = 1e-12) -> np.ndarray:
    """Inverse-distance weighted mean of neighbour weights.

    Parameters
    ----------
    dist : array (M, k)      distances to the neighbours
    theta : array (M, k, K)  their (positive) weights
    average : {"log", "linear"}

    Returns
    -------
    array (M, K). Rows with an exact match (distance <= exact_tol) average the exact matches only.
    """
    w = inverse_distance_votes(dist, exact_tol)
    if average == "log":
        return np.exp(np.einsum("mk,mkd->md", w, np.log(theta)))
    return np.einsum("mk,mkd->md", w, theta)


def inverse_distance_votes(dist: np.ndarray, exact_tol: float = 1e-12) -> np.ndarray:
    """The paper's neighbour votes, (M, k) rows summing to 1: 1 / distance, or, in a row with exact matches
    (distance <= exact_tol), equal votes for the exact matches and none for the others."""
    exact = dist <= exact_tol
    w = np.where(exact.any(axis=1, keepdims=True), exact.astype(float), 1.0 / np.maximum(dist, exact_tol))
    return w / w.sum(axis=1, keepdims=True)
