"""Mixtures of noisy points in weight space (pirl_sim.deconvolution): extreme deconvolution, pruning to the number
of components, and the Dirichlet-process mixture."""

import numpy as np
import pytest

from pirl_sim.deconvolution import XDMixture, dp_deconvolution, extreme_deconvolution
from pirl_sim.metrics import adjusted_rand_index


def _noisy_clusters(rng, centres, n_per=120, spread=0.3):
    """Points of well-separated Gaussian clusters seen through heteroscedastic noise of known covariance."""
    centres = np.asarray(centres, dtype=float)
    z = np.repeat(np.arange(len(centres)), n_per)
    v = centres[z] + spread * rng.normal(size=(len(z), centres.shape[1]))
    sd = rng.uniform(0.05, 0.8, size=v.shape)
    S = np.einsum("na,ab->nab", sd**2, np.eye(centres.shape[1]))
    return v + sd * rng.normal(size=v.shape), S, z


def test_dirichlet_process_finds_the_number_of_clusters_from_a_generous_truncation():
    for k in (1, 3):
        centres = [[-3.0, 0.0], [0.0, 3.0], [3.0, 0.0]][:k]
        X, S, z = _noisy_clusters(np.random.default_rng(k), centres)
        fit = dp_deconvolution(X, S, 10, rng=np.random.default_rng(0))
        big = fit.weights > 0.05
        assert big.sum() == k, fit.weights
        if k > 1:
            assert adjusted_rand_index(z, fit.predict_proba(X, S).argmax(axis=1)) >= 0.95
        order = np.argsort(fit.means[big][:, 0] + 0.1 * fit.means[big][:, 1])
        np.testing.assert_allclose(fit.means[big][order], np.asarray(centres)[np.argsort(
            np.asarray(centres)[:, 0] + 0.1 * np.asarray(centres)[:, 1])], atol=0.15)
        # the noise is deconvolved: the components are about as wide as the noise-free clusters (0.3^2 = 0.09)
        assert np.all(np.einsum("jii->ji", fit.covariances[big]) < 0.2)
        assert np.isclose(fit.weights.sum(), 1.0)
    again = dp_deconvolution(X, S, 10, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(again.means, fit.means)  # seeded: same result


def test_dirichlet_process_keeps_one_component_where_pruning_keeps_one_too():
    """A single noisy cluster: both the Dirichlet process and the message-length pruning end with one."""
    X, S, _ = _noisy_clusters(np.random.default_rng(5), [[0.0, 0.0]], n_per=300)
    assert (dp_deconvolution(X, S, 6, rng=np.random.default_rng(0)).weights > 0.05).sum() == 1
    assert extreme_deconvolution(X, S, 6, rng=np.random.default_rng(0), prune=True, n_init=1).n_components == 1


@pytest.mark.parametrize("kwargs,error,match", [
    ({"concentration": 0.0}, ValueError, r"concentration \(the Dirichlet process's alpha\) must be a number > 0"),
    ({"concentration": "1"}, ValueError, "concentration"),
    ({"max_components": 11}, ValueError, "max_components=11 is more than the 10 points"),
    ({"max_components": 0}, ValueError, "max_components must be a positive integer"),
    ({"rng": 0}, TypeError, "rng must be a numpy.random.Generator"),
    ({"reg_covar": -1.0}, ValueError, "reg_covar must be > 0"),
    ({"S": np.zeros((10, 2, 3))}, ValueError, r"measurement covariances must have shape \(10, 2, 2\)"),
])
def test_dirichlet_process_rejects_bad_input(kwargs, error, match):
    args = {"X": np.zeros((10, 2)), "S": np.zeros((10, 2, 2)), "max_components": 2, "rng": np.random.default_rng(0)}
    args.update(kwargs)
    with pytest.raises(error, match=match):
        dp_deconvolution(args.pop("X"), args.pop("S"), args.pop("max_components"), **args)


# ---------------------------------------------------------------------------------------------- deconvolution
def _noisy_mixture(rng, n=1000):
    z = rng.integers(2, size=n)
    means = np.array([[0.0, 0.0], [3.0, 1.0]])
    covs = np.array([np.diag([0.1, 0.2]), [[0.3, 0.1], [0.1, 0.2]]])
    v = np.stack([rng.multivariate_normal(means[k], covs[k]) for k in z])
    sd = rng.uniform(0.1, 1.0, n)
    S = np.einsum("n,ab->nab", sd**2, np.eye(2))
    return v + rng.normal(size=(n, 2)) * sd[:, None], S, z, means, covs


def test_extreme_deconvolution_recovers_the_noise_free_mixture():
    X, S, z, means, covs = _noisy_mixture(np.random.default_rng(0))
    fit = extreme_deconvolution(X, S, 2, rng=np.random.default_rng(0))
    order = np.argsort(fit.means[:, 0])
    np.testing.assert_allclose(fit.means[order], means, atol=0.1)
    np.testing.assert_allclose(fit.covariances[order], covs, atol=0.08)  # the noise is deconvolved
    naive = [np.cov(X[z == k].T) for k in range(2)]
    assert all(np.trace(n) > np.trace(c) + 0.4 for n, c in zip(naive, covs))  # what a plain GMM would see
    assert fit.converged and np.isclose(fit.weights.sum(), 1.0)
    again = extreme_deconvolution(X, S, 2, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(again.means, fit.means)  # seeded: same result


def test_pruning_finds_the_number_of_components():
    rng = np.random.default_rng(3)
    centres = np.array([[-4.0, 0.0], [0.0, 3.0], [4.0, 0.0]])
    X = np.concatenate([c + 0.3 * rng.normal(size=(100, 2)) for c in centres])
    S = np.broadcast_to(0.05 * np.eye(2), (len(X), 2, 2)).copy()
    fit = extreme_deconvolution(X, S, 6, rng=np.random.default_rng(0), n_init=1, prune=True)
    assert fit.n_components == 3


@pytest.mark.parametrize("kwargs,error,match", [
    ({"S": np.zeros((5, 2, 2))}, ValueError, r"measurement covariances must have shape \(10, 2, 2\)"),
    ({"n_components": 11}, ValueError, "n_components=11 is more than the 10 points"),
    ({"n_components": 0}, ValueError, "n_components must be a positive integer"),
    ({"rng": 0}, TypeError, "rng must be a numpy.random.Generator"),
    ({"reg_covar": 0.0}, ValueError, "reg_covar must be > 0"),
])
def test_deconvolution_rejects_bad_input(kwargs, error, match):
    args = {"X": np.zeros((10, 2)), "S": np.zeros((10, 2, 2)), "n_components": 2, "rng": np.random.default_rng(0)}
    args.update(kwargs)
    with pytest.raises(error, match=match):
        extreme_deconvolution(args.pop("X"), args.pop("S"), args.pop("n_components"), **args)
    with pytest.raises(ValueError, match="weights must be >= 0 and sum to 1"):
        XDMixture(np.array([0.5, 0.6]), np.zeros((2, 1)), np.ones((2, 1, 1)), 0.0, 1, True)
