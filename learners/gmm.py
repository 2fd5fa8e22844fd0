"""PIRL-GMM and PIRL-DPGMM: cluster demonstrations in feature space, one cost per cluster.

The paper's Algorithm 1-2: an EM-fitted Gaussian mixture over (transformed, standardised) features groups the
demonstrations; continuous-domain IRL on each group gives that style's weights; online, a history takes the
weights of its most probable cluster. PIRL-DPGMM replaces the fixed k by a truncated Dirichlet-process mixture
(`sklearn.mixture.BayesianGaussianMixture`), which finds the number of styles itself.

Degenerate clusters: a component holding fewer than ``min_cluster_size`` training samples is dropped; its
samples, and any later query, go to the most probable remaining component.
"""

from __future__ import annotations

import warnings

import numpy as np
from sklearn.mixture import BayesianGaussianMixture, GaussianMixture

from pirl_sim.validation import is_positive_int

from .base import BaseLearner

__all__ = ["PIRLGMM", "PIRLDPGMM"]


class _MixtureLearner(BaseLearner):
    def _make_mixture(self, Z: np.ndarray):  # pragma: no cover - abstract
        raise NotImplementedError

    def _check_min_size(self) -> None:
        m = self.min_cluster_size
        if not is_positive_int(m):
            raise ValueError(f"min_cluster_size must be a positive integer, got {m!r}")

    def _fit(self, model, trajectories):
        self._check_min_size()
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
        res = self._irl(model, trajectories, self.labels_, self.n_styles_)
        self.irl_result_ = res
        self.theta_ = res.normalized
        self.cluster_sizes_ = np.bincount(self.labels_, minlength=self.n_styles_)

    def _assign(self, Z: np.ndarray) -> np.ndarray:
        proba = self.mixture_.predict_proba(Z)[:, self.components_]
        return proba.argmax(axis=1)

    def predict_style(self, histories) -> np.ndarray:
        """Index of the most probable style (row of ``theta_``) of each history, shape (M,) or scalar."""
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self)
        histories, single = self._as_histories(histories)
        labels = self._assign(self._to_space(self.model_.feature_values(self._query_windows(histories))))
        return labels[0] if single else labels

    def _infer(self, histories):
        labels = self._assign(self._to_space(self.model_.feature_values(self._query_windows(histories))))
        return self.theta_[labels]


class PIRLGMM(_MixtureLearner):
    """PIRL with a Gaussian-mixture prior over features (EM), one cost per cluster.

    Parameters
    ----------
    n_components : int or "bic"
        Number of clusters, or "bic" to choose it in 1..max_components by the Bayesian information criterion.
    max_components : int
        Upper end of the BIC search.
    covariance_type : str
        As in `sklearn.mixture.GaussianMixture`.
    min_cluster_size : int
        Components with fewer training samples are dropped (see module doc).
    n_init : int
        EM restarts.
    random_state : int, Generator-seeded int or None
        Seed of the EM initialisation.

    Attributes
    ----------
    theta_ : array (n_styles_, K)   normalised weights per cluster
    labels_ : array (M,)            cluster of each training trajectory
    n_styles_ : int
    mixture_ : GaussianMixture
    bic_ : dict {k: BIC} when n_components == "bic"
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

    def _gmm(self, k):
        return GaussianMixture(
            n_components=k, covariance_type=self.covariance_type, n_init=self.n_init, random_state=self.random_state
        )


class PIRLDPGMM(_MixtureLearner):
    """PIRL with a Dirichlet-process Gaussian mixture: the number of styles is inferred.

    Parameters
    ----------
    max_components : int
        Truncation level of the Dirichlet process.
    weight_concentration_prior : float or None
        Dirichlet-process concentration (smaller favours fewer styles); None = 1 / max_components.
    min_cluster_size : int
        Components with fewer training samples are not counted as styles (see module doc).
    Other parameters as `PIRLGMM`.

    Attributes
    ----------
    n_styles_ : int   number of styles found
    theta_, labels_, mixture_ : as `PIRLGMM`
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
