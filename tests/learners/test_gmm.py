"""PIRL-GMM and PIRL-DPGMM (pirl_sim.learners.gmm): three styles recovered, the Dirichlet process in weight space,
hard EM from random clusters, the most probable style, and the checks of their parameters."""

import warnings

import numpy as np
import pytest

from pirl_sim.learners import PIRLDPGMM, PIRLGMM
from pirl_sim.metrics import adjusted_rand_index, match_styles, weight_recovery_error
from pirl_sim.model import synthetic_model
from pirl_sim.population import Population, Style, generate_demonstrations
from pirl_sim.scenarios.synthetic import SyntheticConfig, generate

from style_demos import roundabout_passages


STYLE_Q = np.array([0.1, 1.0, 10.0])  # normalised state_sq weight of each style (control_sq = 1)


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


@pytest.fixture(scope="module")
def data():
    return generate(SyntheticConfig(n_trajectories=48, n_train=40, seed=2))


@pytest.mark.parametrize("space", ["features", "weights"])
def test_most_probable_style_is_the_argmax_of_predict_proba(data, space):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        learner = PIRLGMM(random_state=0, space=space).fit(data.train)
    proba = learner.predict_proba(data.test)
    np.testing.assert_array_equal(learner.most_probable_style(data.test), proba.argmax(axis=1))
    assert learner.most_probable_style(data.test[0]) == proba[0].argmax()
    if space == "weights":
        np.testing.assert_array_equal(learner.predict_style(data.test), proba.argmax(axis=1))


@pytest.mark.parametrize("max_iter", [0, -1, 2.5, None])
def test_dpgmm_without_iterations_is_refused(data, max_iter):
    for space in ("features", "weights"):
        with pytest.raises(ValueError, match="max_iter must be a positive number of iterations"):
            PIRLDPGMM(max_iter=max_iter, space=space).fit(data.train)


@pytest.mark.parametrize("cls, params, match", [
    (PIRLGMM, {"covariance_type": "foo"}, r"covariance_type must be one of \('full', 'tied', 'diag', 'spherical'\), "
                                          r"got 'foo'"),
    (PIRLDPGMM, {"covariance_type": None}, r"covariance_type must be one of .*got None"),
    (PIRLGMM, {"random_state": -1}, r"random_state must be None, an integer seed in \[0, 2\*\*32\) or a numpy "
                                    r"RandomState, got -1"),
    (PIRLDPGMM, {"random_state": "foo"}, r"random_state must be None, an integer seed .*got 'foo'"),
    (PIRLDPGMM, {"weight_concentration_prior": -1.0}, r"weight_concentration_prior must be None \(1 / max_components\) "
                                                      r"or a finite number > 0, got -1.0"),
    (PIRLDPGMM, {"weight_concentration_prior": float("nan")}, r"weight_concentration_prior must be .*got nan"),
])
def test_mixture_parameters_are_checked_before_the_fit(data, cls, params, match):
    for space in ("features", "weights"):
        with pytest.raises(ValueError, match=match):
            cls(**params, space=space).fit(data.train)


@pytest.fixture(scope="module")
def passage():
    return roundabout_passages()


def test_gmm_recovers_three_styles_on_the_roundabout(passage):
    truth = np.array([t.metadata["style"] for t in passage.train])
    gmm = PIRLGMM(passage.model, n_components=3, random_state=0).fit(passage.train)
    ari = adjusted_rand_index(truth, gmm.labels_)
    assert ari >= 0.9
    pairing = match_styles(truth, gmm.labels_)
    for learned, true_style in pairing.items():
        mean = passage.config.styles[true_style].mean
        est = gmm.theta_[learned]
        assert est[0] == pytest.approx(mean["speed_dev"], rel=0.3)
        assert est[1] == pytest.approx(mean["acc_sq"], rel=0.3)


def _three_styles(model, n, rng):
    styles = (
        Style("calm", 1.0, {"state_sq": 0.1}, {"state_sq": 0.01}),
        Style("normal", 1.0, {"state_sq": 1.0}, {"state_sq": 0.1}),
        Style("eager", 1.0, {"state_sq": 10.0}, {"state_sq": 1.0}),
    )
    pop = Population(model.features, styles)
    x0 = np.tile([[1.0, 0.0]], (n, 1))
    return generate_demonstrations(model, pop, x0, 40, rng)


def test_gmm_recovers_three_styles_and_dpgmm_finds_their_number(model, rng):
    demos = _three_styles(model, 300, rng)
    truth = np.array([d.metadata["style"] for d in demos])
    gmm = PIRLGMM(n_components=3, random_state=0).fit(demos)
    assert adjusted_rand_index(truth, gmm.labels_) > 0.95
    # the clustering alone (for figures) gives fit's labels without fitting any weights
    alone = PIRLGMM(n_components=3, random_state=0)
    np.testing.assert_array_equal(alone.cluster_labels(demos), gmm.labels_)
    assert not hasattr(alone, "theta_")
    with pytest.raises(ValueError, match="space"):
        PIRLGMM(n_components=3, space="weights").cluster_labels(demos)
    learned = np.sort(gmm.theta_[:, 0])
    np.testing.assert_allclose(learned, [0.1, 1.0, 10.0], rtol=0.15)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        dp = PIRLDPGMM(random_state=0).fit(demos)
    assert dp.n_styles_ == 3
    assert adjusted_rand_index(truth, dp.labels_) > 0.95
    bic = PIRLGMM(n_components="bic", max_components=5, random_state=0).fit(demos)
    assert bic.n_styles_ == 3
