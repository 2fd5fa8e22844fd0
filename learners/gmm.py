"""PIRL-GMM and PIRL-DPGMM: cluster demonstrations, one cost per cluster.

The paper's Algorithm 1-2: an EM-fitted Gaussian mixture over (transformed, standardised) features groups the
demonstrations; continuous-domain IRL on each group gives that style's weights; online, a history takes the
weights of its most probable cluster. PIRL-DPGMM replaces the fixed k by a truncated Dirichlet-process mixture.
Components with fewer than ``min_cluster_size`` training samples are dropped.

``space="weights"`` clusters per-demonstration weight posteriors (`pirl_sim.learners.weight_space`) by extreme
deconvolution (`pirl_sim.deconvolution`), refits each cluster's cost jointly and runs ``refine`` passes of hard
EM over the IRL likelihoods (after Babeș-Vroman et al. 2011); PIRL-GMM's ``init="random"`` starts that hard EM
from random clusters. Style posterior (`predict_proba`): p(style j | history) ∝ pi_j p(history | theta_j).

The steps and their options are explained in the documentation's "The learners" page.
"""

from __future__ import annotations

import warnings

import numpy as np
from sklearn.mixture import BayesianGaussianMixture, GaussianMixture

from pirl_sim.deconvolution import dp_deconvolution, extreme_deconvolution
from pirl_sim.validation import is_positive_int

from .base import population_prior
from .model_io import SavableLearner
from .weight_space import demo_posteriors, style_log_likelihoods

__all__ = ["PIRLGMM", "PIRLDPGMM", "SPACES", "INITS", "WEIGHT_MIXTURES", "COVARIANCE_TYPES"]

SPACES = ("features", "weights")
INITS = ("deconvolution", "random")  #: PIRLGMM's starts in weight space (module doc)
WEIGHT_MIXTURES = ("dirichlet-process", "mml")  #: PIRLDPGMM's mixtures in weight space (module doc)
COVARIANCE_TYPES = ("full", "tied", "diag", "spherical")  #: as in `sklearn.mixture.GaussianMixture`
_SEED_RANGE = 2**32  # integer seeds of random_state are in [0, 2**32) (numpy's and scikit-learn's)


def _merge_rows(result, sub, rows: np.ndarray):
    """``result`` (an IRLResult of one group per demonstration) with the groups ``rows`` replaced by ``sub``'s."""
    from dataclasses import fields, replace

    changes = {}
    for f in fields(result):
        a, b = getattr(result, f.name), getattr(sub, f.name)
        if isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape[:1] == (len(a),) and a.ndim >= 1:
            merged = a.copy()
            merged[rows] = b
            changes[f.name] = merged
    changes["n_iter"] = result.n_iter + sub.n_iter
    changes["n_regularized"] = result.n_regularized + sub.n_regularized
    return replace(result, **changes)


class _MixtureLearner(SavableLearner):
    def _make_mixture(self, Z: np.ndarray):  # pragma: no cover - abstract
        raise NotImplementedError

    def _check_min_size(self) -> None:
        m = self.min_cluster_size
        if not is_positive_int(m):
            raise ValueError(f"min_cluster_size must be a positive integer, got {m!r}")

    def _check_params(self, model) -> None:
        super()._check_params(model)
        self._check_min_size()
        if self.space not in SPACES:
            raise ValueError(f"space must be one of {SPACES}, got {self.space!r}")
        if not is_positive_int(self.n_init):
            raise ValueError(f"n_init must be a positive integer (restarts), got {self.n_init!r}")
        if not isinstance(self.covariance_type, str) or self.covariance_type not in COVARIANCE_TYPES:
            raise ValueError(f"covariance_type must be one of {COVARIANCE_TYPES}, got {self.covariance_type!r}")
        seed = self.random_state
        if seed is not None and not isinstance(seed, np.random.RandomState) and (
                isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < _SEED_RANGE):
            raise ValueError(f"random_state must be None, an integer seed in [0, 2**32) or a numpy RandomState, got "
                             f"{seed!r}")
        if self.space == "weights":
            refine = self.refine
            if isinstance(refine, bool) or not isinstance(refine, (int, np.integer)) or refine < 0:
                raise ValueError(f"refine must be a non-negative integer, got {refine!r}")
            init = getattr(self, "init", "deconvolution")
            if init not in INITS:
                raise ValueError(f"init must be one of {INITS}, got {init!r}")

    def _fit(self, model, trajectories):
        self._check_min_size()
        if self.space not in SPACES:
            raise ValueError(f"space must be one of {SPACES}, got {self.space!r}")
        if self.space == "weights":
            return self._fit_weight_space(model, trajectories)
        self._cluster(model, trajectories)
        res = self._irl(model, trajectories, self.labels_, self.n_styles_)
        self.irl_result_ = res
        self.theta_ = res.normalized
        self.cluster_sizes_ = np.bincount(self.labels_, minlength=self.n_styles_)
        self.style_weights_ = self.mixture_.weights_[self.components_] / self.mixture_.weights_[self.components_].sum()
        self._set_noise_scale(trajectories)

    def cluster_labels(self, trajectories) -> np.ndarray:
        """The feature-space clustering of `fit` alone, without the IRL per cluster: one style label per
        trajectory (M,), the labels ``fit`` would give. For looking at clusters (figures); the learner is not
        fitted by it. Only for ``space="features"``."""
        self._check_common()
        self._check_min_size()
        if self.space != "features":
            raise ValueError(f"cluster_labels clusters in feature space; this learner has space={self.space!r}")
        model = self._model()
        trajectories = model.check(trajectories)
        self._cluster(model, trajectories)
        return self.labels_

    def _cluster(self, model, trajectories) -> None:
        """Feature-space EM, small components dropped, one majority label per trajectory (sets mixture_,
        components_, n_styles_, sample_labels_, labels_)."""
        samples, owners = self._training_windows(trajectories)
        Z = self._fit_space(model.feature_values(samples))
        mixture = self._make_mixture(Z)
        raw = mixture.predict(Z)
        sizes = np.bincount(raw, minlength=mixture.n_components)
        keep = sizes >= min(self.min_cluster_size, sizes.max())
        self.mixture_ = mixture
        self.components_ = np.flatnonzero(keep)  # mixture components kept, in style order
        dropped = (~keep) & (sizes > 0)
        if dropped.any():
            warnings.warn(
                f"{type(self).__name__}: dropped {int(dropped.sum())} mixture components with fewer than "
                f"{self.min_cluster_size} samples (sizes {sizes[dropped].tolist()}); their samples join the most "
                "probable remaining component",
                UserWarning,
                stacklevel=3,
            )
        # one label per training trajectory: the majority over its windows. The IRL runs on whole
        # trajectories: a window cut from the middle of an optimal trajectory is not optimal for the window's
        # own cost (the driver also cares about what follows), so windows would bias the weights. A component
        # that wins no trajectory's vote is dropped too (its windows go to the next most probable component).
        for _ in range(mixture.n_components):
            labels = self._assign(Z)
            counts = np.zeros((len(trajectories), len(self.components_)), dtype=int)
            np.add.at(counts, (owners, labels), 1)
            votes = counts.argmax(axis=1)
            present = np.unique(votes)
            if len(present) == len(self.components_):
                break
            self.components_ = self.components_[present]
        self.n_styles_ = len(self.components_)
        self.sample_labels_ = labels
        self.labels_ = votes

    # ------------------------------------------------------------------ weight space
    def _xd(self, X, S, rng):  # pragma: no cover - abstract
        raise NotImplementedError

    def _fit_weight_space(self, model, trajectories):
        refine = self.refine
        if isinstance(refine, bool) or not isinstance(refine, (int, np.integer)) or refine < 0:
            raise ValueError(f"refine must be a non-negative integer, got {refine!r}")
        init = getattr(self, "init", "deconvolution")
        if init not in INITS:
            raise ValueError(f"init must be one of {INITS}, got {init!r}")
        if init == "random":
            return self._fit_random_start(model, trajectories, int(refine))
        M = len(trajectories)
        demo = self._irl(model, trajectories, np.arange(M), M)
        prior, redo = None, None
        others = [k for k in range(model.features.n_features) if k != model.features.reference_index]
        if self.likelihood == "trajectory" and others and demo.at_bound[:, others].any():
            # a normalised weight at the box's bound: the likelihood's maximum lies beyond it and a Gaussian there
            # says nothing; refit those demonstrations as MAP under the population's log-normal prior (module doc)
            redo = np.any(demo.at_bound[:, others], axis=1)
            prior = population_prior(demo, model.features.reference_index, self.log_bounds)
            idx = np.flatnonzero(redo)
            sub = self._irl(model, [trajectories[i] for i in idx], np.arange(len(idx)), len(idx), prior=prior)
            demo = _merge_rows(demo, sub, idx)
        X, S = demo_posteriors(model, trajectories, demo, likelihood=self.likelihood, log_bounds=self.log_bounds,
                               horizon=self.horizon, step_stride=self.step_stride, prior=prior, prior_rows=redo)
        self.n_demos_with_prior_ = 0 if redo is None else int(redo.sum())
        self.demo_theta_ = demo.normalized
        self.demo_log_weights_ = X
        self.demo_log_covariances_ = S
        rng = np.random.default_rng(self.random_state)
        xd = self._xd(X, S, rng)
        proba = xd.predict_proba(X, S)
        keep = np.arange(xd.n_components)
        for _ in range(xd.n_components):  # drop components with too few members; theirs go to the next best
            labels = proba[:, keep].argmax(axis=1)
            sizes = np.bincount(labels, minlength=len(keep))
            ok = sizes >= min(self.min_cluster_size, sizes.max())
            if ok.all():
                break
            keep = keep[ok]
        dropped = xd.n_components - len(keep)
        if dropped:
            warnings.warn(
                f"{type(self).__name__}: dropped {dropped} weight-space components with fewer than "
                f"{self.min_cluster_size} demonstrations; their demonstrations join the most probable remaining one",
                UserWarning,
                stacklevel=3,
            )
        self.components_ = keep
        self.n_styles_ = len(keep)
        self.style_weights_ = xd.weights[keep] / xd.weights[keep].sum()
        self.style_log_means_ = xd.means[keep]
        self.style_log_covariances_ = xd.covariances[keep]
        self.xd_log_likelihood_ = xd.log_likelihood
        self.labels_ = labels  # weight space: one label per trajectory, no windows
        res = self._irl(model, trajectories, labels, self.n_styles_)
        self.irl_result_ = res
        self.theta_ = res.normalized
        self._set_noise_scale(trajectories)
        self._hard_em(model, trajectories, int(refine))
        self.cluster_sizes_ = np.bincount(self.labels_, minlength=self.n_styles_)

    def _hard_em(self, model, trajectories, passes: int) -> str:
        """Up to ``passes`` passes of hard EM over the IRL likelihoods from ``labels_`` (module doc); sets
        ``n_refined_``, the passes that changed labels. Returns why it stopped: "converged" (no label moved),
        "collapsed" (the next labels would leave a style with fewer than ``min_cluster_size`` demonstrations:
        not taken) or "passes" (all passes done, labels still moving)."""
        self.n_refined_ = 0
        self.em_collapse_sizes_ = None
        for _ in range(passes):
            new = self._posterior(self._style_log_likelihood(trajectories)).argmax(axis=1)
            sizes = np.bincount(new, minlength=self.n_styles_)
            if np.array_equal(new, self.labels_):
                return "converged"
            if sizes.min() < min(self.min_cluster_size, sizes.max()):
                self.em_collapse_sizes_ = sizes
                return "collapsed"
            res = self._irl(model, trajectories, new, self.n_styles_)
            self.labels_ = new
            self.irl_result_, self.theta_ = res, res.normalized
            self.style_weights_ = sizes / sizes.sum()
            self.n_refined_ += 1
        return "passes"

    def _fit_random_start(self, model, trajectories, passes: int) -> None:
        """``init="random"`` (module doc): Babeș-Vroman et al.'s EM from random equal-size clusters, ``n_init``
        restarts, the one with the highest classification log-likelihood sum_i log(pi_l p(tau_i | theta_l))
        (l: the demonstration's style) kept."""
        k = getattr(self, "n_components", None)
        if not is_positive_int(k):
            raise ValueError(f"init='random' needs a fixed number of styles: n_components must be a positive integer, "
                             f"got {k!r}")
        M = len(trajectories)
        if k > M:  # type: ignore[operator]
            raise ValueError(f"n_components={k} is larger than the number of training demonstrations ({M})")
        if not is_positive_int(self.n_init):
            raise ValueError(f"n_init must be a positive integer, got {self.n_init!r}")
        rng = np.random.default_rng(self.random_state)
        best, best_score = None, -np.inf
        names = ("labels_", "irl_result_", "theta_", "style_weights_", "n_refined_", "control_rms_", "episode_steps_",
                 "em_collapse_sizes_")
        for _ in range(int(self.n_init)):
            self.n_styles_ = int(k)  # type: ignore[arg-type]
            self.labels_ = rng.permutation(np.arange(M) % k)  # type: ignore[operator]
            res = self._irl(model, trajectories, self.labels_, self.n_styles_)
            self.irl_result_, self.theta_ = res, res.normalized
            self.style_weights_ = np.full(k, 1.0 / k)  # type: ignore[operator]
            self._set_noise_scale(trajectories)
            stop = self._hard_em(model, trajectories, passes)
            ll = self._style_log_likelihood(trajectories) + np.log(self.style_weights_)[None]
            score = float(ll[np.arange(M), self.labels_].sum())
            if score > best_score:
                best, best_score = {n: getattr(self, n) for n in names}, score
                best["stop"] = stop
        stop = best.pop("stop")  # type: ignore[union-attr]
        for n, v in best.items():  # type: ignore[union-attr]
            setattr(self, n, v)
        if stop == "collapsed" and passes:
            sizes = self.em_collapse_sizes_
            warnings.warn(
                f"{type(self).__name__}(init='random'): hard EM stopped after {self.n_refined_} of {passes} passes: "
                f"the next assignment would leave a style with fewer than {self.min_cluster_size} demonstrations "
                f"(sizes {None if sizes is None else sizes.tolist()}); the styles are the last partition kept",
                UserWarning, stacklevel=4)
        elif stop == "passes" and passes:
            warnings.warn(f"{type(self).__name__}(init='random'): labels still moving after {passes} passes of hard "
                          "EM (refine); more passes may change the styles", UserWarning, stacklevel=4)
        feats = model.features
        others = [j for j in range(feats.n_features) if j != feats.reference_index]
        self.components_ = np.arange(self.n_styles_)
        self.style_log_means_ = np.log(self.theta_[:, others])
        self.style_log_covariances_ = np.zeros((self.n_styles_, len(others), len(others)))  # no spread estimated
        self.classification_log_likelihood_ = best_score
        self.n_demos_with_prior_ = 0
        self.cluster_sizes_ = np.bincount(self.labels_, minlength=self.n_styles_)

    def _set_noise_scale(self, trajectories):
        """For `predict_proba`: the RMS of the training controls (floors the Cauchy scale of the receding
        likelihood) and, when histories are the first ``window`` steps of episodes (``windows="first"``), the
        episodes' length in steps (the shortest training trajectory)."""
        self.control_rms_ = float(np.sqrt(np.mean(np.concatenate([np.square(t.controls).ravel()
                                                                   for t in trajectories]))))
        first = self.window is not None and self.windows == "first"
        self.episode_steps_ = int(min(t.n_steps for t in trajectories)) if first else None

    # ------------------------------------------------------------------ styles of histories
    def style_log_likelihood(self, histories) -> np.ndarray:
        """log p(history | style j) under each style's fitted weights, (M, n_styles_) or (n_styles_,) [nats]."""
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self)
        histories, single = self._as_histories(histories)
        self._query_windows(histories)  # same validation as the look-ups
        out = self._style_log_likelihood(histories)
        return out[0] if single else out

    def _style_log_likelihood(self, histories) -> np.ndarray:
        missing = [n for n in ("control_rms_", "episode_steps_") if not hasattr(self, n)]
        if missing:  # a model file of format version 1 from before the style posterior, converted on reading
            raise ValueError(f"{type(self).__name__}: the style likelihoods need {', '.join(missing)} (the training "
                             "data's control scale and episode length), which this learner's model file does not "
                             "hold: it was written before predict_proba existed; refit the learner to use them")
        res = self.irl_result_
        out = style_log_likelihoods(
            self.model_, histories, likelihood=self.likelihood, theta=res.theta, normalized=res.normalized,
            gauss_newton=getattr(res, "gauss_newton", None), sigma=getattr(res, "sigma", None),
            noise_floor_controls=np.array([[self.control_rms_]]), horizon=self.horizon, step_stride=self.step_stride,
            episode_steps=self.episode_steps_)
        return out

    def predict_proba(self, histories) -> np.ndarray:
        """p(style | history) = pi_j p(history | theta_j) / sum_l pi_l p(history | theta_l): each style's likelihood
        of the whole history (the IRL's own likelihood at the style's fitted weights) and its mixture weight
        ``style_weights_``. Shape (M, n_styles_), or (n_styles_,) for one history; rows sum to 1."""
        ll = self.style_log_likelihood(histories)
        return self._posterior(ll)

    def predict_futures(self, histories, horizon: int, n_futures: int | None = None,
                        random_state=None) -> tuple[np.ndarray, np.ndarray]:
        """K predicted futures of each history with their probabilities ("The learners" page, Multi-modal prediction).

        ``n_futures=None``: one future per style under its weights ``theta_[j]``, with p(style | history).
        ``n_futures=K``: in weight space, K weights drawn (``random_state``) from sum_j p(j | history) N(z;
        ``style_log_means_[j]``, ``style_log_covariances_[j]``), each with probability 1 / K; in feature space, the
        min(K, ``n_styles_``) most probable styles, probabilities renormalised over them.

        Returns
        -------
        states : array (M, K, horizon + 1, n_x), or (K, horizon + 1, n_x) for one history
            The MPC's predictions from the last state of each history (row 0 is that state).
        proba : array (M, K) or (K,)
        """
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self)
        self._check_futures_args(horizon, n_futures)
        proba = np.atleast_2d(self.predict_proba(histories))
        histories, single = self._as_histories(histories)
        x0 = np.stack([h.states[-1] for h in histories])
        M = len(histories)
        if n_futures is None:
            states = np.stack([self.model_.predict_states(x0, th, horizon) for th in self.theta_], axis=1)
        elif self.space == "weights":
            K = int(n_futures)
            rng = np.random.default_rng(random_state)
            theta = self._draw_weights(rng, proba, K)  # (M, K, n_features)
            flat = self.model_.predict_states(np.repeat(x0, K, axis=0), theta.reshape(M * K, -1), horizon)
            states = flat.reshape((M, K) + flat.shape[1:])
            proba = np.full((M, K), 1.0 / K)
        else:
            K = min(int(n_futures), self.n_styles_)
            top = np.argsort(-proba, axis=1, kind="stable")[:, :K]  # (M, K) most probable styles first
            per_style = np.stack([self.model_.predict_states(x0, th, horizon) for th in self.theta_], axis=1)
            states = np.take_along_axis(per_style, top[:, :, None, None], axis=1)
            proba = np.take_along_axis(proba, top, axis=1)
            proba = proba / proba.sum(axis=1, keepdims=True)
        return (states[0], proba[0]) if single else (states, proba)

    def _draw_weights(self, rng: np.random.Generator, proba: np.ndarray, K: int) -> np.ndarray:
        """K normalised weight vectors per history drawn from the style mixture (`predict_futures`), (M, K, n_f)."""
        M = proba.shape[0]
        feats = self.model_.features
        others = [k for k in range(feats.n_features) if k != feats.reference_index]
        cum = np.cumsum(proba, axis=1)
        styles = np.minimum((rng.random((M, K))[:, :, None] > cum[:, None, :]).sum(axis=2), self.n_styles_ - 1)
        lam, vec = np.linalg.eigh(self.style_log_covariances_)  # a square root that tolerates singular ones
        chol = vec * np.sqrt(np.maximum(lam, 0.0))[:, None, :]  # (J, D, D), chol @ chol.T = covariance
        z = self.style_log_means_[styles] + np.einsum("mkij,mkj->mki", chol[styles],
                                                       rng.standard_normal((M, K, len(others))))
        theta = np.ones((M, K, feats.n_features))
        theta[:, :, others] = np.exp(z)
        return theta

    def _posterior(self, ll: np.ndarray) -> np.ndarray:
        lp = np.atleast_2d(ll) + np.log(self.style_weights_)[None]
        lp -= lp.max(axis=1, keepdims=True)
        p = np.exp(lp)
        p /= p.sum(axis=1, keepdims=True)
        return p[0] if np.ndim(ll) == 1 else p

    def _assign(self, Z: np.ndarray) -> np.ndarray:
        proba = self.mixture_.predict_proba(Z)[:, self.components_]
        return proba.argmax(axis=1)

    def predict_style(self, histories) -> np.ndarray:
        """Index of the style (row of ``theta_``) whose weights `infer_weights` gives each history, shape (M,) or
        scalar.

        With ``space="weights"`` it is the most probable style under `predict_proba`. With ``space="features"``
        (the paper's algorithm) it is the most probable component of the feature-space mixture ``mixture_`` given
        the history's features, which is how the paper assigns a style online; `predict_proba` is instead the
        posterior under each style's IRL likelihood of the whole history, and the two can disagree (a history's
        features near one cluster, its steps better explained by another style's cost). The most probable style
        under `predict_proba` in both spaces is `most_probable_style`."""
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self)
        histories, single = self._as_histories(histories)
        labels = self._styles(histories)
        return labels[0] if single else labels

    def most_probable_style(self, histories) -> np.ndarray:
        """``argmax(predict_proba(histories))``: the style with the highest posterior given each history, shape (M,)
        or scalar (ties: the lowest index). Equal to `predict_style` with ``space="weights"``."""
        return np.argmax(self.predict_proba(histories), axis=-1)

    def _styles(self, histories):
        if self.space == "weights":
            return self.predict_proba(histories).argmax(axis=1)
        return self._assign(self._to_space(self.model_.feature_values(self._query_windows(histories))))

    def _infer(self, histories):
        return self.theta_[self._styles(histories)]


class PIRLGMM(_MixtureLearner):
    """PIRL with a Gaussian-mixture prior over features (EM), one cost per cluster ("The learners" page; every parameter
    and attribute in full: "In detail: learners.gmm").

    Parameters
    ----------
    n_components, max_components : int or "bic", int   number of clusters, or chosen in 1..max_components by BIC
    covariance_type, n_init, random_state : str, int, int or None   `sklearn.mixture.GaussianMixture`'s; restarts, seed
    min_cluster_size : int               components with fewer training samples are dropped
    space, refine, init : str, int, str   cluster the features (the paper's) or the weight posteriors; see the page

    Attributes
    ----------
    theta_, labels_, n_styles_ : array (n_styles_, K), (M,), int   normalised weights per cluster; each one's cluster
    style_weights_, mixture_, bic_, demo_theta_, demo_log_*, style_log_* : see the page.
    """

    def __init__(
        self,
        model=None,
        *,
        n_components=2,
        max_components=8,
        covariance_type="full",
        min_cluster_size=5,
        n_init=3,
        random_state=None,
        window=None,
        stride=1,
        windows="sliding",
        feature_transform="log",
        log_bounds=(-20.0, 20.0),
        likelihood="trajectory",
        horizon=None,
        step_stride=1,
        irl_hessian="auto",
        irl_max_iter=100,
        space="features",
        refine=1,
        init="deconvolution",
    ):
        self.model = model
        self.n_components = n_components
        self.max_components = max_components
        self.covariance_type = covariance_type
        self.min_cluster_size = min_cluster_size
        self.n_init = n_init
        self.random_state = random_state
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
        self.space = space
        self.refine = refine
        self.init = init

    def _check_params(self, model) -> None:
        super()._check_params(model)
        k = self.n_components
        if k == "bic":
            if not is_positive_int(self.max_components):
                raise ValueError(f"max_components must be a positive integer, got {self.max_components!r}")
        elif not is_positive_int(k):
            raise ValueError(f"n_components must be a positive integer or 'bic', got {k!r}")

    def _make_mixture(self, Z):
        n = Z.shape[0]
        if self.n_components == "bic":
            if not is_positive_int(self.max_components):
                raise ValueError(f"max_components must be a positive integer, got {self.max_components!r}")
            ks = range(1, min(int(self.max_components), n) + 1)
            fits = {k: self._gmm(k).fit(Z) for k in ks}
            self.bic_ = {k: float(m.bic(Z)) for k, m in fits.items()}
            best = min(self.bic_, key=self.bic_.get)
            return fits[best]
        k = self.n_components
        if not is_positive_int(k):
            raise ValueError(f"n_components must be a positive integer or 'bic', got {k!r}")
        if k > n:
            raise ValueError(f"n_components={k} is larger than the number of training samples ({n})")
        return self._gmm(int(k)).fit(Z)

    def _xd(self, X, S, rng):
        n = X.shape[0]
        if self.n_components == "bic":
            if not is_positive_int(self.max_components):
                raise ValueError(f"max_components must be a positive integer, got {self.max_components!r}")
            D = X.shape[1]
            fits, self.bic_ = {}, {}
            for k in range(1, min(int(self.max_components), n) + 1):
                fits[k] = extreme_deconvolution(X, S, k, rng=rng, n_init=self.n_init)
                n_params = (k - 1) + k * (D + D * (D + 1) // 2)
                self.bic_[k] = float(-2.0 * fits[k].log_likelihood + n_params * np.log(n))
            return fits[min(self.bic_, key=self.bic_.get)]
        k = self.n_components
        if not is_positive_int(k):
            raise ValueError(f"n_components must be a positive integer or 'bic', got {k!r}")
        if k > n:
            raise ValueError(f"n_components={k} is larger than the number of training demonstrations ({n})")
        return extreme_deconvolution(X, S, int(k), rng=rng, n_init=self.n_init)

    def _gmm(self, k):
        return GaussianMixture(
            n_components=k, covariance_type=self.covariance_type, n_init=self.n_init, random_state=self.random_state
        )


class PIRLDPGMM(_MixtureLearner):
    """PIRL with a Dirichlet-process Gaussian mixture: the number of styles is inferred ("The learners" page).

    Parameters
    ----------
    max_components : int                   truncation level of the Dirichlet process
    weight_concentration_prior : float or None   concentration (smaller favours fewer styles); None: 1 / max_components
    min_cluster_size : int                 components with fewer training samples are not counted as styles
    weight_mixture : {"dirichlet-process", "mml"}   (``space="weights"``) how the weight posteriors are mixed (the page)
    space, covariance_type, n_init, random_state, refine, ... : as `PIRLGMM`.

    Attributes
    ----------
    n_styles_ : int   number of styles found
    theta_, labels_, mixture_, style_weights_, demo_*, style_log_* : as `PIRLGMM`
    """

    def __init__(
        self,
        model=None,
        *,
        max_components=10,
        weight_concentration_prior=None,
        covariance_type="full",
        min_cluster_size=5,
        n_init=1,
        max_iter=500,
        random_state=None,
        window=None,
        stride=1,
        windows="sliding",
        feature_transform="log",
        log_bounds=(-20.0, 20.0),
        likelihood="trajectory",
        horizon=None,
        step_stride=1,
        irl_hessian="auto",
        irl_max_iter=100,
        space="features",
        refine=1,
        weight_mixture="dirichlet-process",
    ):
        self.model = model
        self.max_components = max_components
        self.weight_concentration_prior = weight_concentration_prior
        self.covariance_type = covariance_type
        self.min_cluster_size = min_cluster_size
        self.n_init = n_init
        self.max_iter = max_iter
        self.random_state = random_state
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
        self.space = space
        self.refine = refine
        self.weight_mixture = weight_mixture

    def _check_params(self, model) -> None:
        super()._check_params(model)
        if not is_positive_int(self.max_components):
            raise ValueError(f"max_components must be a positive integer, got {self.max_components!r}")
        if not is_positive_int(self.max_iter):
            raise ValueError(f"max_iter must be a positive number of iterations of the mixture's fit, got "
                             f"{self.max_iter!r}")
        alpha = self.weight_concentration_prior
        number = (int, float, np.integer, np.floating)
        if alpha is not None and (isinstance(alpha, bool) or not isinstance(alpha, number) or not np.isfinite(alpha)
                                  or alpha <= 0):
            raise ValueError(f"weight_concentration_prior must be None (1 / max_components) or a finite number > 0, "
                             f"got {alpha!r}")
        if self.space == "weights" and self.weight_mixture not in WEIGHT_MIXTURES:
            raise ValueError(f"weight_mixture must be one of {WEIGHT_MIXTURES}, got {self.weight_mixture!r}")

    def _xd(self, X, S, rng):
        k = self.max_components
        if not is_positive_int(k):
            raise ValueError(f"max_components must be a positive integer, got {k!r}")
        if self.weight_mixture not in WEIGHT_MIXTURES:
            raise ValueError(f"weight_mixture must be one of {WEIGHT_MIXTURES}, got {self.weight_mixture!r}")
        if self.weight_mixture == "dirichlet-process":
            return dp_deconvolution(X, S, min(int(k), X.shape[0]), rng=rng,
                                    concentration=self.weight_concentration_prior, n_init=self.n_init,
                                    max_iter=self.max_iter)
        return extreme_deconvolution(X, S, min(int(k), X.shape[0]), rng=rng, n_init=self.n_init,
                                     max_iter=self.max_iter, prune=True)

    def _make_mixture(self, Z):
        k = self.max_components
        if not is_positive_int(k):
            raise ValueError(f"max_components must be a positive integer, got {k!r}")
        k = min(int(k), Z.shape[0])
        return BayesianGaussianMixture(
            n_components=k,
            weight_concentration_prior_type="dirichlet_process",
            weight_concentration_prior=self.weight_concentration_prior,
            covariance_type=self.covariance_type,
            n_init=self.n_init,
            max_iter=self.max_iter,
            random_state=self.random_state,
        ).fit(Z)
