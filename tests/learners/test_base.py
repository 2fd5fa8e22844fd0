"""What every learner shares (pirl_sim.learners.base): the scikit-learn estimator API (score, model selection, batch
predict, n_features_in_), the checks of fit (log_bounds, data scale, horizon), the IRL iteration budget, and K
futures with their probabilities."""

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.exceptions import NotFittedError
from sklearn.model_selection import GridSearchCV, cross_val_score

from pirl_sim.learners import PIRLDPGMM, PIRLGMM, PIRLKNN, TIRL, make_learner
from pirl_sim.metrics import med
from pirl_sim.model import synthetic_model
from pirl_sim.mpc import MAX_HORIZON
from pirl_sim.scenarios.synthetic import SyntheticConfig, generate
from pirl_sim.trajectory import Trajectory

from style_demos import switching_drivers


HISTORY = 10


@pytest.fixture(scope="module")
def data():
    return generate(SyntheticConfig(n_trajectories=48, n_train=40, seed=2))


def _split(trajectories):
    return [t.window(0, HISTORY) for t in trajectories], [t.window(HISTORY) for t in trajectories]


def test_grid_search_chooses_k_by_score_without_a_custom_scorer(data):
    histories, futures = _split(data.train)
    search = GridSearchCV(PIRLKNN(window=HISTORY, windows="first"), {"n_neighbors": [1, 3]}, cv=2,
                          error_score="raise").fit(histories, futures)
    assert search.best_params_["n_neighbors"] in (1, 3)
    assert np.all(np.isfinite(search.cv_results_["mean_test_score"]))
    assert np.all(search.cv_results_["mean_test_score"] <= 0)
    scores = cross_val_score(TIRL(window=HISTORY, windows="first"), histories, futures, cv=2, error_score="raise")
    assert scores.shape == (2,) and np.all(scores < 0)


def test_score_is_the_negative_med_of_the_predicted_futures_in_metres(data):
    learner = PIRLKNN(n_neighbors=3, window=HISTORY, windows="first").fit(data.train)
    histories, futures = _split(data.test)
    futures = [f.window(0, 5 + i % 3) for i, f in enumerate(futures)]  # futures of different lengths
    predicted = [learner.predict_states(h, f.n_steps)[1:, :1] for h, f in zip(histories, futures)]
    expected = med(predicted, [f.states[1:, :1] for f in futures])
    assert learner.score(histories, futures) == pytest.approx(-expected, rel=1e-12)
    assert learner.score(histories[0], futures[0]) <= 0
    with pytest.raises(ValueError, match="one future per history, got 8 histories and 7 futures"):
        learner.score(histories, futures[1:])


def test_fit_with_futures_fits_the_joined_demonstrations(data):
    histories, futures = _split(data.train)
    joined = TIRL().fit(histories, futures)
    whole = TIRL().fit(data.train)
    np.testing.assert_allclose(joined.theta_, whole.theta_, rtol=1e-9)
    with pytest.raises(ValueError, match="future 0 does not start where history 0 ends"):
        TIRL().fit(histories, futures[1:] + futures[:1])


def test_predict_takes_one_history_or_a_batch(data):
    learner = PIRLGMM(random_state=0, window=HISTORY, windows="first").fit(data.train)
    histories, _ = _split(data.test)
    one = learner.predict(histories[0], 6)
    assert isinstance(one, Trajectory) and one.n_steps == 6
    batch = learner.predict(histories, 6)
    assert isinstance(batch, list) and len(batch) == len(histories)
    for h, b in zip(histories, batch):
        single = learner.predict(h, 6)
        np.testing.assert_allclose(b.states, single.states, rtol=1e-12, atol=1e-14)
        np.testing.assert_array_equal(b.metadata["theta"], single.metadata["theta"])
    with pytest.raises(TypeError, match="a Trajectory or a sequence of them"):
        learner.predict("history", 6)


def test_n_features_in_is_the_number_of_cost_features(data):
    learner = TIRL().fit(data.train)
    assert learner.n_features_in_ == len(learner.infer_weights(data.test[0])) == 2
    assert list(learner.feature_names_in_) == ["state_sq", "control_sq"]


@pytest.mark.parametrize("bounds", [5, "ab", (1.0,), (3.0, -3.0), (0.0, float("nan")), (True, 2.0), None])
def test_log_bounds_of_another_form_are_a_clear_error(data, bounds):
    for cls in (TIRL, PIRLKNN, PIRLGMM):
        with pytest.raises(ValueError, match=r"log_bounds must be a pair \(low, high\) of finite numbers with "
                                             r"low < high.*e\.g\. \(-20\.0, 20\.0\)"):
            cls(log_bounds=bounds).fit(data.train)


def test_log_bounds_as_a_list_still_fit(data):
    np.testing.assert_array_equal(TIRL(log_bounds=[-20, 20]).fit(data.train).theta_, TIRL().fit(data.train).theta_)


def test_overflowing_data_is_a_clear_warning_or_error(data):
    scaled = [Trajectory(t.states * 1e150, t.controls * 1e150, t.dt) for t in data.train[:20]]
    with pytest.warns(UserWarning, match=r"TIRL: floating-point overflow or invalid values in the IRL.*not reliable"
                                         r".*features reach .*'state_sq'.*rescale"):
        TIRL().fit(scaled)
    huge = [Trajectory(t.states * 1e160, t.controls * 1e160, t.dt) for t in data.train[:20]]
    with pytest.raises(ValueError, match=r"training trajectory 0: feature 'state_sq' overflows float64 \(states or "
                                         r"controls up to [\d.]+e\+160\); rescale"):
        TIRL().fit(huge)


def test_horizons_beyond_the_bound_are_refused_before_anything_is_allocated(data):
    learner = TIRL().fit(data.train)
    h = data.test[0].window(0, HISTORY)
    for horizon in (10**11, MAX_HORIZON + 1):
        with pytest.raises(ValueError, match=rf"horizon must be .*{MAX_HORIZON}"):
            learner.predict_states(h, horizon)
        with pytest.raises(ValueError, match=rf"horizon must be .*{MAX_HORIZON}"):
            learner.predict(h, horizon)
        with pytest.raises(ValueError, match=rf"horizon must be .*{MAX_HORIZON}"):
            learner.predict_futures(h, horizon)
        with pytest.raises(ValueError, match=rf"horizon must be at most {MAX_HORIZON} steps"):
            learner.model_.predict_states(h.states[-1:], learner.theta_, horizon)


# ---------------------------------------------------------------------------------------------- learners
# (the fixtures styles_data and styles_learners: tests/conftest.py)
LEARNERS = ("tirl", "gmm-weights", "gmm-features", "dpgmm-weights", "knn-likelihood", "knn-distance")


@pytest.mark.parametrize("name", LEARNERS)
@pytest.mark.parametrize("n_futures", [None, 1, 3])
def test_futures_have_probabilities_that_sum_to_one(styles_learners, styles_data, name, n_futures):
    _, _, test = styles_data
    learner = styles_learners[name]
    histories = [t.window(0, 10) for t in test[:8]]
    states, proba = learner.predict_futures(histories, 20, n_futures=n_futures, random_state=0)
    K = proba.shape[1]
    assert states.shape == (8, K, 21, 2) and proba.shape == (8, K)
    if n_futures is not None:
        assert 1 <= K <= n_futures
    np.testing.assert_allclose(proba.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(proba >= 0)
    np.testing.assert_array_equal(states[:, :, 0], np.stack([[h.states[-1]] * K for h in histories]))
    one, p1 = learner.predict_futures(histories[0], 20, n_futures=n_futures, random_state=0)
    assert one.shape == states.shape[1:] and p1.shape == proba.shape[1:]
    if n_futures is None or name in ("tirl", "gmm-features"):  # no draws: one history alone gets the same
        # to rounding: a batch of one and a batch of eight may take different BLAS kernels (numpy 2.4: 1 ulp)
        np.testing.assert_allclose(one, states[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(p1, proba[0], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["gmm-weights", "knn-likelihood", "knn-distance"])
def test_drawn_futures_are_reproducible_and_depend_on_the_seed(styles_learners, styles_data, name):
    _, _, test = styles_data
    learner = styles_learners[name]
    histories = [t.window(0, 10) for t in test[:8]]
    a = learner.predict_futures(histories, 20, n_futures=6, random_state=7)
    b = learner.predict_futures(histories, 20, n_futures=6, random_state=np.random.default_rng(7))
    c = learner.predict_futures(histories, 20, n_futures=6, random_state=8)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[0].shape == (8, 6, 21, 2) and not np.array_equal(a[0], c[0])


def test_weight_space_draws_follow_the_style_posterior(styles_learners, styles_data):
    """Drawn weights come from the styles p(style | history) favours: with the (sharp) posterior of these
    histories, every draw's log weight lies within 4 standard deviations of the most probable style's mean."""
    _, _, test = styles_data
    gmm = styles_learners["gmm-weights"]
    histories = [t.window(0, 10) for t in test[:8]]
    best = gmm.predict_proba(histories).argmax(axis=1)
    theta = gmm._draw_weights(np.random.default_rng(0), gmm.predict_proba(histories), 50)  # (8, 50, 2)
    z = np.log(theta[:, :, 0])  # state_sq relative to control_sq (the reference)
    mean = gmm.style_log_means_[best, 0][:, None]
    sd = np.sqrt(gmm.style_log_covariances_[best, 0, 0])[:, None]
    assert np.all(np.abs(z - mean) < 4 * sd)
    np.testing.assert_array_equal(theta[:, :, 1], 1.0)


def test_per_style_futures_unchanged_and_features_space_takes_the_top_styles(styles_learners, styles_data):
    model, _, test = styles_data
    histories = [t.window(0, 10) for t in test[:5]]
    gmm = styles_learners["gmm-features"]
    per_style, p_style = gmm.predict_futures(histories, 20)
    np.testing.assert_array_equal(p_style, gmm.predict_proba(histories))
    top, p_top = gmm.predict_futures(histories, 20, n_futures=2)
    order = np.argsort(-p_style, axis=1, kind="stable")[:, :2]
    np.testing.assert_array_equal(top, np.take_along_axis(per_style, order[:, :, None, None], axis=1))
    np.testing.assert_allclose(p_top, np.take_along_axis(p_style, order, axis=1)
                               / np.take_along_axis(p_style, order, axis=1).sum(axis=1, keepdims=True))


def test_bad_future_requests_are_rejected_and_knn_gives_at_most_k(styles_learners, styles_data):
    _, _, test = styles_data
    history = test[0].window(0, 10)
    for name in LEARNERS:
        for bad in (0, -1, 2.5, True):
            with pytest.raises(ValueError, match=f"n_futures .* got {bad!r}"):
                styles_learners[name].predict_futures(history, 20, n_futures=bad)
        with pytest.raises(ValueError, match="horizon must be a positive number of steps, got 0"):
            styles_learners[name].predict_futures(history, 0)
    states, proba = styles_learners["knn-likelihood"].predict_futures(history, 20, n_futures=11, random_state=0)
    assert states.shape == (10, 21, 2) and proba.shape == (10,)  # at most its k = 10 neighbours


@pytest.fixture(scope="module")
def small():
    return generate(SyntheticConfig(n_trajectories=300, n_train=240, seed=3))


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


@pytest.mark.parametrize("key", ["tirl", "pirl-gmm", "pirl-dpgmm", "pirl-knn"])
def test_every_learner_takes_the_irl_iteration_budget(key):
    from pirl_sim.learners import make_learner

    model = synthetic_model()
    train = switching_drivers(model, np.random.default_rng(4), 6)
    assert make_learner(key, model=model).get_params()["irl_max_iter"] == 100
    with pytest.raises(ValueError, match="irl_max_iter"):
        make_learner(key, model=model, irl_max_iter=0).fit(train)
