"""The learners as scikit-learn estimators: score, model selection, batch predict, the style of a history,
n_features_in_, and the parameter checks of fit (log_bounds, max_iter, data scale, horizon)."""

import warnings

import numpy as np
import pytest
from sklearn.model_selection import GridSearchCV, cross_val_score

from pirl_sim.learners import PIRLDPGMM, PIRLGMM, PIRLKNN, TIRL
from pirl_sim.metrics import med
from pirl_sim.mpc import MAX_HORIZON
from pirl_sim.scenarios.synthetic import SyntheticConfig, generate
from pirl_sim.trajectory import Trajectory

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


@pytest.mark.parametrize("max_iter", [0, -1, 2.5, None])
def test_dpgmm_without_iterations_is_refused(data, max_iter):
    for space in ("features", "weights"):
        with pytest.raises(ValueError, match="max_iter must be a positive number of iterations"):
            PIRLDPGMM(max_iter=max_iter, space=space).fit(data.train)


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
