"""Weight-space styles without a fixed k and without the deconvolution (issue 14 item 1): the Dirichlet-process
mixture of noisy points (`pirl_sim.deconvolution.dp_deconvolution`, PIRL-DPGMM's default in weight space) and
hard EM over the IRL likelihoods from random clusters (PIRL-GMM ``init="random"``, Babeș-Vroman et al. 2011)."""

import warnings

import numpy as np
import pytest

from pirl_sim.deconvolution import dp_deconvolution, extreme_deconvolution
from pirl_sim.learners import PIRLDPGMM, PIRLGMM
from pirl_sim.metrics import adjusted_rand_index, match_styles, weight_recovery_error
from pirl_sim.model import synthetic_model
from pirl_sim.population import Population, Style, generate_demonstrations

STYLE_Q = np.array([0.1, 1.0, 10.0])  # normalised state_sq weight of each style (control_sq = 1)


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


@pytest.fixture(scope="module")
def three_styles():
    """Boltzmann-rational LQ drivers of three styles from spread start states (150 demonstrations)."""
    model = synthetic_model()
    styles = tuple(Style(name, 1.0, {"state_sq": q}, {"state_sq": 0.1 * q})
                   for name, q in zip(("calm", "normal", "eager"), STYLE_Q))
    rng = np.random.default_rng(4)
    x0 = np.column_stack([rng.uniform(2.0, 8.0, 150), rng.uniform(-1.0, 1.0, 150)])
    demos = generate_demonstrations(model, Population(model.features, styles, 100.0), x0, 40, rng)
    return model, demos


def _worst_style_error(learner, truth):
    pairs = match_styles(truth, learner.labels_)
    return max(float(weight_recovery_error(learner.theta_[j], np.array([STYLE_Q[s], 1.0]), 1))
               for j, s in pairs.items())


def test_dpgmm_in_weight_space_is_a_dirichlet_process_by_default(three_styles):
    model, demos = three_styles
    truth = np.array([d.metadata["style"] for d in demos])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # components without members are dropped
        dp = PIRLDPGMM(model, random_state=0, space="weights").fit(demos)
        mml = PIRLDPGMM(model, random_state=0, space="weights", weight_mixture="mml").fit(demos)
    assert dp.weight_mixture == "dirichlet-process"
    assert dp.n_styles_ == 3 and adjusted_rand_index(truth, dp.labels_) >= 0.95
    assert _worst_style_error(dp, truth) <= 0.1
    assert adjusted_rand_index(truth, dp.labels_) >= adjusted_rand_index(truth, mml.labels_)  # mml: 4 styles here
    with pytest.raises(ValueError, match=r"weight_mixture must be one of \('dirichlet-process', 'mml'\), got 'vb'"):
        PIRLDPGMM(model, space="weights", weight_mixture="vb").fit(demos)


def test_hard_em_from_random_clusters_finds_the_styles(three_styles):
    model, demos = three_styles
    truth = np.array([d.metadata["style"] for d in demos])
    em = PIRLGMM(model, n_components=3, random_state=0, space="weights", init="random", refine=30).fit(demos)
    assert adjusted_rand_index(truth, em.labels_) >= 0.95 and _worst_style_error(em, truth) <= 0.1
    assert 1 <= em.n_refined_ < 30  # it moved labels and stopped when none moved
    np.testing.assert_array_equal(em.predict_proba(demos).argmax(axis=1), em.labels_)  # a fixed point
    assert em.style_log_covariances_.shape == (3, 1, 1) and not em.style_log_covariances_.any()
    futures, proba = em.predict_futures(demos[0].window(0, 10), 20, n_futures=4, random_state=0)
    assert futures.shape == (4, 21, 2) and np.allclose(proba, 0.25)
    again = PIRLGMM(model, n_components=3, random_state=0, space="weights", init="random", refine=30).fit(demos)
    np.testing.assert_array_equal(again.labels_, em.labels_)  # seeded
    none = PIRLGMM(model, n_components=3, random_state=0, space="weights", init="random", refine=0).fit(demos)
    assert none.n_refined_ == 0 and adjusted_rand_index(truth, none.labels_) < 0.1  # random clusters, no EM


@pytest.mark.parametrize("params,match", [
    ({"init": "kmeans"}, r"init must be one of \('deconvolution', 'random'\), got 'kmeans'"),
    ({"init": "random", "n_components": "bic"}, "init='random' needs a fixed number of styles"),
    ({"init": "random", "n_components": 200}, "n_components=200 is larger than the number of training"),
])
def test_random_start_rejects_what_it_cannot_do(three_styles, params, match):
    model, demos = three_styles
    with pytest.raises(ValueError, match=match):
        PIRLGMM(model, space="weights", **params).fit(demos)


def test_random_start_warns_when_hard_em_would_empty_a_style(three_styles):
    """Babeș-Vroman's EM from random clusters can send every demonstration to one style (the random clusters' fits
    are all the population's average): the learner keeps the last partition and says so with the sizes."""
    model, demos = three_styles
    with pytest.warns(UserWarning, match=r"hard EM stopped after 0 of 5 passes: the next assignment would leave a "
                                          r"style with fewer than 60 demonstrations \(sizes \["):
        em = PIRLGMM(model, n_components=3, random_state=0, space="weights", init="random", refine=5,
                     min_cluster_size=60, n_init=1).fit(demos)
    assert em.n_refined_ == 0 and em.em_collapse_sizes_.min() < 60
