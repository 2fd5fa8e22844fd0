"""Mixtures in weight space and the style posterior of histories (pirl_sim.learners.weight_space, through PIRL-GMM
with ``space="weights"``)."""

import warnings

import numpy as np
import pytest

from pirl_sim.learners import PIRLDPGMM, PIRLGMM
from pirl_sim.metrics import adjusted_rand_index, match_styles, weight_recovery_error
from pirl_sim.model import synthetic_model
from pirl_sim.simulate import simulate_receding_horizon

from style_demos import STYLE_Q, three_style_demonstrations


@pytest.fixture(scope="module")
def three_styles():
    """Boltzmann-rational LQ drivers of three styles from spread start states (train 300, test 60)."""
    return three_style_demonstrations(1, 360, 40, 300)


def _styles(demos):
    return np.array([d.metadata["style"] for d in demos])


# ---------------------------------------------------------------------------------------------- learners
def test_weight_space_recovers_three_styles_that_feature_space_loses(three_styles):
    model, train, _ = three_styles
    truth = _styles(train)
    feat = PIRLGMM(model, n_components=3, random_state=0).fit(train)
    assert adjusted_rand_index(truth, feat.labels_) < 0.6  # the start states dominate the features
    gmm = PIRLGMM(model, n_components=3, random_state=0, space="weights").fit(train)
    assert adjusted_rand_index(truth, gmm.labels_) >= 0.95
    pairs = match_styles(truth, gmm.labels_)
    errors = [float(weight_recovery_error(gmm.theta_[j], np.array([STYLE_Q[s], 1.0]), 1)) for j, s in pairs.items()]
    assert len(errors) == 3 and max(errors) <= 0.1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        dp = PIRLDPGMM(model, random_state=0, space="weights").fit(train)
    assert dp.n_styles_ == 3 and adjusted_rand_index(truth, dp.labels_) >= 0.95
    assert gmm.demo_log_weights_.shape == (300, 1) and gmm.demo_log_covariances_.shape == (300, 1, 1)
    assert np.isclose(gmm.style_weights_.sum(), 1.0)


def test_per_demonstration_posteriors_are_calibrated(three_styles):
    """The Laplace posterior's standard deviations match the actual errors of the per-demo log weights."""
    model, train, _ = three_styles
    gmm = PIRLGMM(model, n_components=3, random_state=0, space="weights").fit(train)
    true = np.log([d.metadata["theta"][0] for d in train])
    z = (gmm.demo_log_weights_[:, 0] - true) / np.sqrt(gmm.demo_log_covariances_[:, 0, 0])
    assert 0.8 < z.std() < 1.25 and 0.5 < np.median(np.abs(z)) < 0.85  # N(0, 1): 1 and 0.674


def test_style_posterior_of_whole_trajectories_and_of_first_steps(three_styles):
    model, train, test = three_styles
    truth = _styles(test)
    for params, histories in (({}, test), ({"window": 10, "windows": "first"}, [t.window(0, 10) for t in test])):
        gmm = PIRLGMM(model, n_components=3, random_state=0, space="weights", **params).fit(train)
        to_true = match_styles(_styles(train), gmm.labels_)
        proba = gmm.predict_proba(histories)
        assert proba.shape == (len(test), 3)
        np.testing.assert_allclose(proba.sum(axis=1), 1.0)
        np.testing.assert_array_equal(gmm.predict_style(histories), proba.argmax(axis=1))
        accuracy = np.mean([to_true[j] == s for j, s in zip(proba.argmax(axis=1), truth)])
        assert accuracy >= 0.95, (params, accuracy)
        np.testing.assert_array_equal(gmm.infer_weights(histories), gmm.theta_[proba.argmax(axis=1)])
        one = gmm.predict_proba(histories[0])
        assert one.shape == (3,)
    # the feature-space learner has the same style posterior (its own styles and mixture weights)
    feat = PIRLGMM(model, n_components=3, random_state=0).fit(train)
    np.testing.assert_allclose(feat.predict_proba(test).sum(axis=1), 1.0)


def test_receding_likelihood_in_weight_space():
    model = synthetic_model()
    rng = np.random.default_rng(2)
    style = np.repeat([0, 1, 2], 20)
    q = STYLE_Q[style] * np.exp(rng.normal(0.0, 0.1, style.size))
    x0 = np.column_stack([rng.uniform(2.0, 8.0, style.size), rng.uniform(-1.0, 1.0, style.size)])
    drivers = simulate_receding_horizon(model, x0, np.column_stack([q, np.ones_like(q)]), 30, 15, rng=rng,
                                        control_noise=0.05)
    gmm = PIRLGMM(model, n_components=3, random_state=0, space="weights", likelihood="receding",
                  horizon=15).fit(drivers)
    assert adjusted_rand_index(style, gmm.labels_) >= 0.95
    z = (gmm.demo_log_weights_[:, 0] - np.log(q)) / np.sqrt(gmm.demo_log_covariances_[:, 0, 0])
    assert 0.6 < z.std() < 1.6  # calibrated, 60 drivers
    to_true = match_styles(style, gmm.labels_)
    assert np.mean([to_true[j] == s for j, s in zip(gmm.predict_style(drivers), style)]) >= 0.95


def test_one_future_per_style_with_its_probability(three_styles):
    model, train, test = three_styles
    gmm = PIRLGMM(model, n_components=3, random_state=0, space="weights", window=10, windows="first").fit(train)
    histories = [t.window(0, 10) for t in test[:5]]
    futures, proba = gmm.predict_futures(histories, 30)
    assert futures.shape == (5, 3, 31, 2) and proba.shape == (5, 3)
    np.testing.assert_array_equal(futures[:, :, 0], np.stack([[h.states[-1]] * 3 for h in histories]))
    np.testing.assert_allclose(futures[:, 1], model.predict_states(np.stack([h.states[-1] for h in histories]),
                                                                   gmm.theta_[1], 30))
    np.testing.assert_array_equal(proba, gmm.predict_proba(histories))
    one, p1 = gmm.predict_futures(histories[0], 30)
    assert one.shape == (3, 31, 2) and p1.shape == (3,)


def test_refinement_by_the_style_likelihoods(three_styles):
    """Hard EM over the IRL likelihoods after the deconvolution: it stops when no label moves, and refine=0 keeps
    the deconvolution's partition and mixture weights."""
    model, train, _ = three_styles
    plain = PIRLGMM(model, n_components=3, random_state=0, space="weights", refine=0).fit(train)
    assert plain.n_refined_ == 0
    refined = PIRLGMM(model, n_components=3, random_state=0, space="weights", refine=3).fit(train)
    assert refined.n_refined_ <= 1  # separable styles: at most one pass moves anything
    again = refined.predict_proba(train).argmax(axis=1)
    if refined.n_refined_:
        np.testing.assert_allclose(refined.style_weights_, np.bincount(refined.labels_) / len(train))
    assert adjusted_rand_index(again, refined.labels_) > 0.99
    with pytest.raises(ValueError, match="refine must be a non-negative integer, got -1"):
        PIRLGMM(model, space="weights", refine=-1).fit(train)


def test_space_is_checked(three_styles):
    model, train, _ = three_styles
    with pytest.raises(ValueError, match=r"space must be one of \('features', 'weights'\), got 'theta'"):
        PIRLGMM(model, space="theta").fit(train)
    with pytest.raises(ValueError, match="n_components=400 is larger than the number of training demonstrations"):
        PIRLGMM(model, n_components=400, space="weights").fit(train)
