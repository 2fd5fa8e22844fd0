"""Multi-modal prediction (issue 14 item 3): K futures with probabilities, minADE_K / minFDE_K / miss rate as the
INTERACTION challenge defines them, the mixture NLL, and their columns in `evaluate`."""

import warnings

import numpy as np
import pytest

from pirl_sim.evaluation.protocols import PAPER_PROTOCOL, Protocol, evaluate
from pirl_sim.learners import PIRLDPGMM, PIRLGMM, PIRLKNN, TIRL
from pirl_sim.metrics import (
    interaction_longitudinal_threshold,
    interaction_miss,
    min_ade,
    min_fde,
    mixture_nll,
)
from pirl_sim.model import synthetic_model
from pirl_sim.population import Population, Style, generate_demonstrations


# ---------------------------------------------------------------------------------------------- metrics
def _two_futures():
    """One case, 3 steps in 2-D: the truth along x at 1 m/step; future 0 is 1 m to the left all along, future 1
    exact but for 2 m ahead at the last step."""
    truth = np.array([[[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]])
    f0 = truth[0] + [0.0, 1.0]
    f1 = truth[0] + [[0.0, 0.0], [0.0, 0.0], [2.0, 0.0]]
    return np.stack([f0, f1])[None], truth


def test_min_ade_and_min_fde_by_hand():
    futures, truth = _two_futures()
    np.testing.assert_allclose(min_ade(futures, truth), [2.0 / 3.0])  # future 1: (0 + 0 + 2) / 3 < future 0: 1
    np.testing.assert_allclose(min_fde(futures, truth), [1.0])  # future 0 ends 1 m off, future 1 2 m
    # K = 1 is the single prediction's ADE / FDE
    np.testing.assert_allclose(min_ade(futures[:, :1], truth), [1.0])
    np.testing.assert_allclose(min_fde(futures[:, 1:], truth), [2.0])


def test_longitudinal_threshold_is_the_challenges_piecewise_rule():
    v = np.array([0.0, 1.4, 6.2, 11.0, 30.0])
    np.testing.assert_allclose(interaction_longitudinal_threshold(v), [1.0, 1.0, 1.5, 2.0, 2.0])


def test_miss_rule_lateral_longitudinal_and_all_futures():
    truth = np.zeros((1, 2, 2))
    truth[0, :, 0] = [0.0, 10.0]  # heading along +x, 10 m/s at the end
    lon_max = 1.0 + (10.0 - 1.4) / (11.0 - 1.4)  # 1.896 m at 10 m/s
    speed, heading = np.array([10.0]), np.array([0.0])

    def miss(offset):  # one future, offset (dx, dy) at the last step
        futures = truth[:, None].copy()
        futures[0, 0, -1] += offset
        return bool(interaction_miss(futures, truth, speed, heading)[0])

    assert not miss([lon_max - 0.01, 0.0]) and miss([lon_max + 0.01, 0.0])  # longitudinal, speed-dependent
    assert not miss([-(lon_max - 0.01), 0.0]) and miss([-(lon_max + 0.01), 0.0])
    assert not miss([0.0, 0.99]) and miss([0.0, 1.01])  # lateral: 1 m whatever the speed
    assert not miss([0.0, 1.0])  # "larger than" the threshold: exactly 1 m is a hit
    # the frame is the true heading's: the same 1.5 m offset along y is longitudinal when the car drives along y
    futures = truth[:, None].copy()
    futures[0, 0, -1] += [0.0, 1.5]
    assert interaction_miss(futures, truth, speed, np.array([0.0]))[0]
    assert not interaction_miss(futures, truth, speed, np.array([np.pi / 2]))[0]
    # a case misses only when every future misses
    two = np.concatenate([futures, truth[:, None]], axis=1)
    assert not interaction_miss(two, truth, speed, np.array([0.0]))[0]
    # slow car: 1 m longitudinal threshold
    assert interaction_miss(futures, truth, np.array([1.0]), np.array([np.pi / 2]))[0]
    # 1-D positions: the whole error is longitudinal, no heading needed
    line = np.array([[[0.0], [5.0]]])
    assert interaction_miss(line[:, None] + 1.2, line, np.array([1.0]))[0]
    assert not interaction_miss(line[:, None] + 1.2, line, np.array([11.0]))[0]


def test_mixture_nll_by_hand():
    futures, truth = _two_futures()
    sigma = 0.5
    T, P = 3, 2
    const = T * P * (np.log(sigma) + 0.5 * np.log(2 * np.pi))
    sq = np.array([3.0, 4.0])  # squared errors summed over steps and coordinates
    p = np.array([0.25, 0.75])
    expected = -np.log(np.sum(p * np.exp(-0.5 * sq / sigma**2))) + const
    np.testing.assert_allclose(mixture_nll(futures, p[None], truth, sigma), [expected])
    # a zero-probability future does not count; one exact future at probability 1 gives the constant only
    np.testing.assert_allclose(mixture_nll(futures, [[1.0, 0.0]], truth, sigma), [0.5 * 3.0 / sigma**2 + const])
    np.testing.assert_allclose(mixture_nll(truth[:, None], [[1.0]], truth, sigma), [const])


@pytest.mark.parametrize("call", [min_ade, min_fde])
def test_bad_futures_are_rejected(call):
    futures, truth = _two_futures()
    with pytest.raises(ValueError, match="K >= 1.*K=0"):
        call(futures[:, :0], truth)
    with pytest.raises(ValueError, match=r"true futures must be \(M, T, P\).*got shape \(1, 2, 2\)"):
        call(futures, truth[:, :2])
    with pytest.raises(ValueError, match=r"futures must be \(M cases, K futures.*shape \(2, 3, 2\)"):
        call(futures[0], truth)
    bad = futures.copy()
    bad[0, 1, 2, 0] = np.nan
    with pytest.raises(ValueError, match=r"predicted futures contain 1 non-finite.*\(0, 1, 2, 0\)"):
        call(bad, truth)
    with pytest.raises(ValueError, match="true futures contain 1 non-finite"):
        call(futures, np.where(truth == 3.0, np.nan, truth))


def test_bad_miss_and_nll_inputs_are_rejected():
    futures, truth = _two_futures()
    with pytest.raises(ValueError, match=r"speed must be \(M,\)"):
        interaction_miss(futures, truth, np.array([1.0, 2.0]), np.array([0.0]))
    with pytest.raises(ValueError, match="heading .* is required"):
        interaction_miss(futures, truth, np.array([1.0]))
    with pytest.raises(ValueError, match="speeds contain 1 non-finite"):
        interaction_miss(futures, truth, np.array([np.nan]), np.array([0.0]))
    with pytest.raises(ValueError, match="speeds must be >= 0 m/s, got a minimum of -1.0"):
        interaction_miss(futures, truth, np.array([-1.0]), np.array([0.0]))
    with pytest.raises(ValueError, match="headings contain 1 non-finite"):
        interaction_miss(futures, truth, np.array([1.0]), np.array([np.nan]))
    with pytest.raises(ValueError, match="sum to 1, case 0 sums to 0.9"):
        mixture_nll(futures, [[0.4, 0.5]], truth, 0.5)
    with pytest.raises(ValueError, match=r"proba must be \(M, K\) = \(1, 2\).*got shape \(1, 3\)"):
        mixture_nll(futures, [[0.2, 0.3, 0.5]], truth, 0.5)
    with pytest.raises(ValueError, match="probabilities must be >= 0"):
        mixture_nll(futures, [[-0.5, 1.5]], truth, 0.5)
    with pytest.raises(ValueError, match="probabilities contain 1 non-finite"):
        mixture_nll(futures, [[np.nan, 1.0]], truth, 0.5)
    for sigma in (0.0, -1.0, np.nan, True):
        with pytest.raises(ValueError, match=f"sigma must be .* got {sigma!r}"):
            mixture_nll(futures, [[0.5, 0.5]], truth, sigma)


# ---------------------------------------------------------------------------------------------- learners
@pytest.fixture(scope="module")
def styles_data():
    """Boltzmann-rational LQ drivers of three styles (q = 0.1, 1, 10; 10 % spread) from spread starts."""
    model = synthetic_model()
    styles = tuple(Style(name, 1.0, {"state_sq": q}, {"state_sq": 0.1 * q})
                   for name, q in zip(("calm", "normal", "eager"), (0.1, 1.0, 10.0)))
    rng = np.random.default_rng(3)
    n = 200
    x0 = np.column_stack([rng.uniform(2.0, 8.0, n), rng.uniform(-1.0, 1.0, n)])
    demos = generate_demonstrations(model, Population(model.features, styles, 100.0), x0, 30, rng)
    return model, demos[:160], demos[160:]


@pytest.fixture(scope="module")
def fitted(styles_data):
    model, train, _ = styles_data
    common = {"window": 10, "windows": "first"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return {
            "tirl": TIRL(model, **common).fit(train),
            "gmm-weights": PIRLGMM(model, n_components=3, random_state=0, space="weights", **common).fit(train),
            "gmm-features": PIRLGMM(model, n_components=3, random_state=0, **common).fit(train),
            "dpgmm-weights": PIRLDPGMM(model, random_state=0, space="weights", **common).fit(train),
            "knn-likelihood": PIRLKNN(model, n_neighbors=10, weighting="likelihood", **common).fit(train),
            "knn-distance": PIRLKNN(model, n_neighbors=10, **common).fit(train),
        }


LEARNERS = ("tirl", "gmm-weights", "gmm-features", "dpgmm-weights", "knn-likelihood", "knn-distance")


@pytest.mark.parametrize("name", LEARNERS)
@pytest.mark.parametrize("n_futures", [None, 1, 3])
def test_futures_have_probabilities_that_sum_to_one(fitted, styles_data, name, n_futures):
    _, _, test = styles_data
    learner = fitted[name]
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
def test_drawn_futures_are_reproducible_and_depend_on_the_seed(fitted, styles_data, name):
    _, _, test = styles_data
    learner = fitted[name]
    histories = [t.window(0, 10) for t in test[:8]]
    a = learner.predict_futures(histories, 20, n_futures=6, random_state=7)
    b = learner.predict_futures(histories, 20, n_futures=6, random_state=np.random.default_rng(7))
    c = learner.predict_futures(histories, 20, n_futures=6, random_state=8)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[0].shape == (8, 6, 21, 2) and not np.array_equal(a[0], c[0])


def test_weight_space_draws_follow_the_style_posterior(fitted, styles_data):
    """Drawn weights come from the styles p(style | history) favours: with the (sharp) posterior of these
    histories, every draw's log weight lies within 4 standard deviations of the most probable style's mean."""
    _, _, test = styles_data
    gmm = fitted["gmm-weights"]
    histories = [t.window(0, 10) for t in test[:8]]
    best = gmm.predict_proba(histories).argmax(axis=1)
    theta = gmm._draw_weights(np.random.default_rng(0), gmm.predict_proba(histories), 50)  # (8, 50, 2)
    z = np.log(theta[:, :, 0])  # state_sq relative to control_sq (the reference)
    mean = gmm.style_log_means_[best, 0][:, None]
    sd = np.sqrt(gmm.style_log_covariances_[best, 0, 0])[:, None]
    assert np.all(np.abs(z - mean) < 4 * sd)
    np.testing.assert_array_equal(theta[:, :, 1], 1.0)


def test_per_style_futures_unchanged_and_features_space_takes_the_top_styles(fitted, styles_data):
    model, _, test = styles_data
    histories = [t.window(0, 10) for t in test[:5]]
    gmm = fitted["gmm-features"]
    per_style, p_style = gmm.predict_futures(histories, 20)
    np.testing.assert_array_equal(p_style, gmm.predict_proba(histories))
    top, p_top = gmm.predict_futures(histories, 20, n_futures=2)
    order = np.argsort(-p_style, axis=1, kind="stable")[:, :2]
    np.testing.assert_array_equal(top, np.take_along_axis(per_style, order[:, :, None, None], axis=1))
    np.testing.assert_allclose(p_top, np.take_along_axis(p_style, order, axis=1)
                               / np.take_along_axis(p_style, order, axis=1).sum(axis=1, keepdims=True))


def test_bad_future_requests_are_rejected_and_knn_gives_at_most_k(fitted, styles_data):
    _, _, test = styles_data
    history = test[0].window(0, 10)
    for name in LEARNERS:
        for bad in (0, -1, 2.5, True):
            with pytest.raises(ValueError, match=f"n_futures .* got {bad!r}"):
                fitted[name].predict_futures(history, 20, n_futures=bad)
        with pytest.raises(ValueError, match="horizon must be a positive number of steps, got 0"):
            fitted[name].predict_futures(history, 0)
    states, proba = fitted["knn-likelihood"].predict_futures(history, 20, n_futures=11, random_state=0)
    assert states.shape == (10, 21, 2) and proba.shape == (10,)  # at most its k = 10 neighbours


# ---------------------------------------------------------------------------------------------- evaluate
def test_evaluate_adds_the_scores_only_when_asked(fitted, styles_data):
    _, _, test = styles_data
    online = Protocol("online", 10)
    plain = evaluate(fitted["gmm-weights"], test, online)
    multi = evaluate(fitted["gmm-weights"], test, online, n_futures=6, random_state=0)
    assert "min_ade" not in plain
    for key in ("med", "fde", "weight_error", "n_test"):
        assert multi[key] == plain[key]
    assert multi["k_futures"] == 6
    assert multi["min_ade"] <= multi["med"] and multi["min_fde"] <= multi["fde"] + 1e-12
    assert 0.0 <= multi["miss_rate"] <= 1.0 and np.isfinite(multi["nll"])
    again = evaluate(fitted["gmm-weights"], test, online, n_futures=6, random_state=0)
    assert again["min_ade"] == multi["min_ade"] and again["nll"] == multi["nll"]
    # one future: minADE_1 is the MED of the point prediction
    tirl = evaluate(fitted["tirl"], test, online, n_futures=6)
    assert tirl["k_futures"] == 1 and tirl["min_ade"] == pytest.approx(tirl["med"], rel=1e-12)
    assert tirl["min_fde"] == pytest.approx(tirl["fde"], rel=1e-12)


def test_evaluate_rolling_scores_every_prediction(styles_data):
    model, train, test = styles_data
    rolling = Protocol("rolling", 10, "sliding", horizon=10, stride=5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        knn = PIRLKNN(model, n_neighbors=10, **rolling.learner_params()).fit(train)
    row = evaluate(knn, test[:10], rolling, n_futures=6, random_state=0)
    assert row["k_futures"] == 6 and row["min_ade"] <= row["med"] + 1e-12
    with pytest.raises(ValueError, match="online or rolling protocol"):
        evaluate(knn, test[:10], PAPER_PROTOCOL, n_futures=6)
    with pytest.raises(ValueError, match="n_futures .* got 0"):
        evaluate(knn, test[:10], rolling, n_futures=0)
    with pytest.raises(ValueError, match="nll_sigma must be .* got -1.0"):
        evaluate(knn, test[:10], rolling, n_futures=6, nll_sigma=-1.0)
