"""The roundabout driving model (issue 3): path features, sequential MPC, Boltzmann demos, styles, switches."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from pirl_sim.driving import (
    SpeedProfile,
    fit_longitudinal_states,
    roundabout_model,
    smooth_desired_speed,
)
from pirl_sim.dynamics import longitudinal
from pirl_sim.evaluation.protocols import Protocol, evaluate
from pirl_sim.learners import TIRL, PIRLGMM, PIRLKNN
from pirl_sim.metrics import adjusted_rand_index, match_styles
from pirl_sim.mpc import Bounds
from pirl_sim.paths import ReferencePath
from pirl_sim.population import Population, Style, sample_boltzmann_controls
from pirl_sim.scenarios.passage import PassageConfig, generate, passage_polyline
from pirl_sim.simulate import simulate_receding_horizon


@pytest.fixture(scope="module")
def passage():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return generate(PassageConfig(n_trajectories=240, n_train=200, seed=1))


def _fd(fs, dyn, x0, U, h=1e-6):
    N = U.shape[0]
    der = fs.derivatives(dyn, dyn.rollout(x0[None], U[None]), U[None])
    u = U.ravel()

    def grads(uf):
        Uc = uf.reshape(1, N, 1)
        return fs.derivatives(dyn, dyn.rollout(x0[None], Uc), Uc).grad[0]

    def vals(uf):
        Uc = uf.reshape(1, N, 1)
        return fs.values(dyn.rollout(x0[None], Uc), Uc)[0]

    g_fd = np.empty_like(der.grad[0])
    H_fd = np.empty_like(der.hess[0])
    for i in range(u.size):
        e = np.zeros(u.size)
        e[i] = h
        g_fd[:, i] = (vals(u + e) - vals(u - e)) / (2 * h)
        H_fd[:, :, i] = (grads(u + e) - grads(u - e)) / (2 * h)
    return der.grad[0], g_fd, der.hess[0], H_fd


def test_smooth_desired_speed_limits_and_derivatives():
    k = np.array([0.0, 0.01, 0.05, -0.05, 0.2])
    v, dv, d2v = smooth_desired_speed(k, 1.8, 13.9)
    assert v[0] == pytest.approx(13.9)
    np.testing.assert_allclose(v[2:], np.sqrt(1.8 / np.abs(k[2:])), rtol=3e-3)  # where v_c < 0.6 v_max
    h = 1e-6 * np.maximum(np.abs(k), 1e-3)  # v_des is flat to fourth order at kappa = 0: small steps there
    vp, dvp, _ = smooth_desired_speed(k + h, 1.8, 13.9)
    vm, dvm, _ = smooth_desired_speed(k - h, 1.8, 13.9)
    np.testing.assert_allclose(dv, (vp - vm) / (2 * h), rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(d2v, (dvp - dvm) / (2 * h), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_path_feature_derivatives_match_finite_differences(passage, seed):
    rng = np.random.default_rng(seed)
    model = passage.model
    x0 = np.array([rng.uniform(30, 70), rng.uniform(4, 10), rng.normal(0, 0.5)])  # braking into the ring
    U = rng.normal(0, 1.0, size=(12, 1))
    g, g_fd, H, H_fd = _fd(model.features, model.dynamics, x0, U)
    assert np.max(np.abs(g - g_fd)) <= 1e-5 * max(1.0, np.abs(g).max())
    assert np.max(np.abs(H - H_fd)) <= 1e-5 * max(1.0, np.abs(H).max())


def test_straight_road_has_constant_desired_speed_and_works_end_to_end():
    path = ReferencePath.from_polyline(np.column_stack([np.linspace(0, 200, 101), np.zeros(101)]))
    prof = SpeedProfile(path, v_max=13.9)
    v, dv, d2v = prof(np.linspace(0, 200, 50))
    np.testing.assert_allclose(v, 13.9, rtol=1e-9)
    np.testing.assert_allclose(dv, 0.0, atol=1e-9)
    model = roundabout_model(path)
    X = model.predict_states(np.array([[10.0, 8.0, 0.0]]), [1.0, 0.1, 1.0], 40)
    assert X[0, -1, 1] > 8.0  # speeds up towards the limit on a straight road


def test_prediction_past_the_end_of_the_path_extrapolates():
    path = ReferencePath.from_polyline(passage_polyline(20.0, 20.0, 90.0, 10.0))
    model = roundabout_model(path)
    X = model.predict_states(np.array([[path.length - 5.0, 8.0, 0.0]]), [1.0, 0.1, 1.0], 40)
    assert X[0, -1, 0] > path.length  # beyond the end: straight-line extension, constant desired speed
    xy = model.positions(X)
    assert np.all(np.isfinite(xy))


def test_sequential_mpc_reaches_a_stationary_point_and_respects_bounds(passage):
    model = passage.model
    rng = np.random.default_rng(3)
    x0 = np.column_stack([rng.uniform(0, 60, 30), rng.uniform(3, 12, 30), rng.normal(0, 0.3, 30)])
    theta = np.array([3.0, 0.3, 1.0])
    free = roundabout_model(model.path, bounds=None).predictor()
    U = free.controls(x0, theta, 30)
    der = model.features.derivatives(model.dynamics, model.dynamics.rollout(x0, U), U)
    assert np.abs(np.einsum("k,mkd->md", theta, der.grad)).max() < 1e-6  # exact-gradient stationarity
    tight = roundabout_model(
        model.path, bounds=Bounds(state={"v [m/s]": (0, 30), "a [m/s^2]": (-1.0, 1.0)}, control={"j [m/s^3]": (-2, 2)})
    )
    X = tight.predict_states(x0, theta, 30)
    assert X[:, 1:, 2].min() >= -1.0 - 1e-6 and X[:, 1:, 2].max() <= 1.0 + 1e-6
    assert tight.predictor().n_qp > 0


def test_negative_speed_start_is_clipped_into_bounds(passage):
    X = passage.model.predict_states(np.array([[30.0, -2.0, -9.0]]), [3.0, 0.3, 1.0], 20)
    assert X[0, 0, 1] == 0.0 and X[0, 0, 2] == 0.0  # a stopped car: v = 0, no further deceleration
    assert X[0, :, 1].min() >= -1e-6


def test_start_state_by_least_squares_through_the_dynamics():
    dyn = longitudinal(0.2)
    rng = np.random.default_rng(0)
    err_ls, err_fd = [], []
    for _ in range(200):
        true = dyn.rollout(np.array([0.0, 8.0, -1.0]), rng.normal(0, 0.5, (25, 1)))
        noisy = true[:, 0] + rng.normal(0, 0.1, 26)
        X, U = fit_longitudinal_states(noisy, dyn, jerk_weight=1.0)
        err_ls.append(X[-1, 1] - true[-1, 1])
        err_fd.append((noisy[-1] - noisy[-2]) / 0.2 - true[-1, 1])  # the last speed by differences
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))
    assert rms(err_ls) < 0.5 * rms(err_fd)
    np.testing.assert_allclose(dyn.residual(X, U), 0.0, atol=1e-9)  # consistent with the dynamics
    with pytest.raises(ValueError, match="at least 2"):
        fit_longitudinal_states(np.array([1.0]), dyn)


def test_boltzmann_on_a_curved_path_uses_metropolis(passage):
    model = passage.model
    rng = np.random.default_rng(5)
    x0 = np.tile([[40.0, 10.0, 0.0]], (400, 1))
    theta = 20.0 * np.array([3.0, 0.3, 1.0])
    U, acc = sample_boltzmann_controls(model, x0, theta, 30, rng, return_acceptance=True)
    assert 0.3 < acc < 1.0  # the Laplace proposal is not exact here, and the chain corrects it
    # importance-sampling check of one statistic: the mean final speed under the exact density
    prop, _ = sample_boltzmann_controls(model, x0, theta, 30, rng, mh_steps=0, return_acceptance=True)
    v_mh = model.dynamics.rollout(x0, U)[:, -1, 1].mean()
    v_prop = model.dynamics.rollout(x0, prop)[:, -1, 1].mean()
    se = model.dynamics.rollout(x0, U)[:, -1, 1].std() / np.sqrt(400)
    assert abs(v_mh - v_prop) < 10 * se + 0.5  # close to the Laplace answer, as a sanity bound


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


def test_knn_beats_tirl_online(passage):
    proto = Protocol("rolling", 10, "sliding", horizon=15, stride=5)
    rows = {}
    for learner in (TIRL(passage.model), PIRLKNN(passage.model, n_neighbors=10, stride=2)):
        learner.set_params(**proto.learner_params())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            learner.fit(passage.train)
        rows[type(learner).__name__] = evaluate(learner, passage.test, proto)["med"]
    assert rows["PIRLKNN"] < 0.7 * rows["TIRL"]


def test_a_style_switch_is_followed_within_five_steps(passage):
    model = passage.model
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        knn = PIRLKNN(model, n_neighbors=10, window=10, stride=2).fit(passage.train)
    calm = model.features.weights({"speed_dev": 0.1, "acc_sq": 3.0, "jerk_sq": 1.0})
    eager = model.features.weights({"speed_dev": 3.0, "acc_sq": 0.3, "jerk_sq": 1.0})
    M, switch = 8, 20
    rng = np.random.default_rng(2)
    x0 = np.column_stack([np.zeros(M), rng.uniform(10, 12, M), np.zeros(M)])
    trajs = simulate_receding_horizon(
        model, x0, lambda k: np.tile(calm if k < switch else eager, (M, 1)), 45, 25, rng=rng, control_noise=0.3
    )
    log_ratio = lambda t: np.median(np.log(knn.infer_weights([tr.window(t - 10, t) for tr in trajs])[:, 0]))
    before = log_ratio(switch)
    after = log_ratio(switch + 5)
    assert before < np.log(0.5)  # calm: small speed_dev weight
    assert after > np.log(1.0)  # five steps after the switch the eager style is inferred
    assert np.array_equal(trajs[0].metadata["theta_schedule"][switch], eager)


def test_model_curvature_is_its_speed_profiles():
    """`PathDriverModel.curvature`: |kappa| of the speed_dev feature's profile; a model without one says so."""
    from pirl_sim.driving import SpeedProfile
    from pirl_sim.features import FeatureSet, squared_control

    path = ReferencePath.from_polyline(passage_polyline(20.0, 20.0, 90.0, 10.0))
    model = roundabout_model(path)
    s = np.linspace(0.0, path.length, 50)
    np.testing.assert_allclose(model.curvature(s), np.abs(SpeedProfile(path).curvature(s)[0]))
    assert model.curvature(s).max() > 0.01
    bare = replace(model, features=FeatureSet((squared_control("jerk_sq"),), reference="jerk_sq"))
    with pytest.raises(ValueError, match="no speed_dev feature"):
        bare.curvature(s)
