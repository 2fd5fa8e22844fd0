import warnings

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.exceptions import NotFittedError

from pirl_sim.learners import PIRLDPGMM, PIRLGMM, PIRLKNN, TIRL, make_learner
from pirl_sim.learners.knn import knn_average
from pirl_sim.metrics import adjusted_rand_index
from pirl_sim.population import Population, Style, generate_demonstrations
from pirl_sim.scenarios.synthetic import SyntheticConfig, generate
from pirl_sim.trajectory import Trajectory


@pytest.fixture(scope="module")
def small():
    return generate(SyntheticConfig(n_trajectories=300, n_train=240, seed=3))


def _three_styles(model, n, rng):
    styles = (
        Style("calm", 1.0, {"state_sq": 0.1}, {"state_sq": 0.01}),
        Style("normal", 1.0, {"state_sq": 1.0}, {"state_sq": 0.1}),
        Style("eager", 1.0, {"state_sq": 10.0}, {"state_sq": 1.0}),
    )
    pop = Population(model.features, styles)
    x0 = np.tile([[1.0, 0.0]], (n, 1))
    return generate_demonstrations(model, pop, x0, 40, rng)


@pytest.mark.parametrize("cls", [TIRL, PIRLGMM, PIRLKNN, PIRLDPGMM])
def test_learners_follow_sklearn_conventions(cls, small):
    learner = cls(random_state=0) if "random_state" in cls().get_params() else cls()
    params = learner.get_params()
    clone(learner)  # __init__ only stores
    with pytest.raises(NotFittedError):
        learner.infer_weights(small.test[0])
    assert learner.fit(small.train) is learner
    assert learner.get_params() == params
    theta = learner.infer_weights(small.test)
    assert theta.shape == (len(small.test), 2) and np.all(theta > 0)
    np.testing.assert_allclose(theta[:, 1], 1.0)  # stated normalisation: control_sq weight = 1
    pred = learner.predict(small.test[0], 10)
    assert isinstance(pred, Trajectory) and pred.n_steps == 10
    np.testing.assert_array_equal(pred.states[0], small.test[0].states[-1])


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


def test_knn_exact_match_and_inverse_distance():
    dist = np.array([[0.0, 1.0], [1.0, 3.0]])
    theta = np.array([[[2.0, 1.0], [8.0, 1.0]], [[2.0, 1.0], [8.0, 1.0]]])
    out = knn_average(dist, theta, "linear")
    np.testing.assert_allclose(out[0], [2.0, 1.0])  # exact match wins alone
    np.testing.assert_allclose(out[1], [(2 * 1 + 8 / 3) / (1 + 1 / 3), 1.0])
    out_log = knn_average(dist, theta, "log")
    np.testing.assert_allclose(out_log[1, 0], np.exp((np.log(2) + np.log(8) / 3) / (4 / 3)))


def test_knn_recovers_each_demo_on_noise_free_data(small):
    knn = PIRLKNN(n_neighbors=1).fit(small.train)
    true = np.stack([t.metadata["theta"] for t in small.train])
    np.testing.assert_allclose(knn.demo_theta_, true, rtol=1e-3)
    assert knn.n_weights_at_bound_ == 0
    assert knn.n_scale_at_bound_ == len(small.train)  # noise-free: only the direction is identified
    # a training trajectory queried again is an exact match: its own weights come back
    np.testing.assert_allclose(knn.infer_weights(small.train[:5]), true[:5], rtol=1e-3)


def test_knn_population_prior_runs_and_stays_close(model, rng):
    x0 = np.column_stack([rng.uniform(-3, 3, 80), rng.uniform(-1, 1, 80)])
    pop = Population(model.features, (Style("s", 1.0, {"state_sq": 2.0}, {"state_sq": 0.5}),), rationality=5.0)
    demos = generate_demonstrations(model, pop, x0, 30, rng)
    ml = PIRLKNN().fit(demos)
    mapk = PIRLKNN(prior="population").fit(demos)
    true = np.array([d.metadata["theta"][0] for d in demos])
    err_ml = np.median(np.abs(np.log(ml.demo_theta_[:, 0] / true)))
    err_map = np.median(np.abs(np.log(mapk.demo_theta_[:, 0] / true)))
    assert err_map <= err_ml  # shrinkage towards the population helps weakly identified demos


def test_online_windows_and_short_history(small):
    knn = PIRLKNN(n_neighbors=3, window=10, windows="first").fit(small.train)
    assert len(knn.sample_theta_) == len(small.train)
    sliding = PIRLKNN(n_neighbors=3, window=10, stride=5).fit(small.train)
    assert len(sliding.sample_theta_) == len(small.train) * 9
    with pytest.raises(ValueError, match="shorter than the feature window of 10 steps"):
        knn.infer_weights(small.test[0].window(0, 5))


@pytest.mark.parametrize(
    "learner, match",
    [
        (PIRLKNN(n_neighbors=10_000), "larger than the number of training samples"),
        (PIRLKNN(n_neighbors=0), "n_neighbors must be a positive integer"),
        (PIRLKNN(average="median"), "average must be one of"),
        (PIRLGMM(n_components=0), "n_components must be a positive integer or 'bic'"),
        (PIRLGMM(n_components=10_000), "larger than the number of training samples"),
        (TIRL(window=0), "window must be a positive number of steps"),
        (TIRL(feature_transform="sqrt"), "feature_transform must be one of"),
        (PIRLKNN(window=10_000), "longer than every training trajectory"),
    ],
)
def test_bad_parameters_raise(learner, match, small):
    with pytest.raises(ValueError, match=match):
        learner.fit(small.train)


def test_bad_training_data_raises(small):
    with pytest.raises(ValueError, match="empty"):
        TIRL().fit([])
    with pytest.raises(TypeError, match="single Trajectory"):
        TIRL().fit(small.train[0])
    with pytest.raises(TypeError, match="element 1 is a str"):
        TIRL().fit([small.train[0], "x"])
    wrong = Trajectory(np.zeros((5, 3)), np.zeros((4, 1)), 0.1)
    with pytest.raises(ValueError, match="n_x=3"):
        TIRL().fit([wrong])
    wrong_dt = Trajectory(np.zeros((5, 2)), np.zeros((4, 1)), 0.2)
    with pytest.raises(ValueError, match="dt=0.2"):
        TIRL().fit([wrong_dt])
    with pytest.raises(ValueError, match="unknown learner 'svm'"):
        make_learner("svm")


@pytest.mark.parametrize("options", [{}, {"window": 10, "windows": "first", "weighting": "likelihood"}])
def test_knn_with_neighbors_equals_refitting(small, options):
    base = PIRLKNN(n_neighbors=1, **options).fit(small.train)
    test = small.test[:12]
    histories = [t.window(0, 10) for t in test] if options else test
    for k in (2, 7):
        refit = PIRLKNN(n_neighbors=k, **options).fit(small.train)
        derived = base.with_neighbors(k)
        assert derived.get_params()["n_neighbors"] == k and base.n_neighbors == 1
        assert derived.irl_result_ is base.irl_result_ and derived.scaler_ is base.scaler_  # shared, not refitted
        np.testing.assert_array_equal(derived.infer_weights(histories), refit.infer_weights(histories))
        np.testing.assert_array_equal(derived.predict_states(histories, 5), refit.predict_states(histories, 5))
        for a, b in zip(derived.predict_futures(histories, 5), refit.predict_futures(histories, 5)):
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(base.infer_weights(histories), PIRLKNN(**options).fit(small.train).infer_weights(histories))
    with pytest.raises(ValueError, match="larger than the number of training samples"):
        base.with_neighbors(10_000)
    with pytest.raises(ValueError, match="positive integer"):
        base.with_neighbors(0)
    with pytest.raises(NotFittedError):
        PIRLKNN().with_neighbors(2)
