"""Driver populations (pirl_sim.population): the Boltzmann sampler's moments, Metropolis on a curved path, and
bad styles refused."""

import numpy as np
import pytest

from pirl_sim.features import lqr_features
from pirl_sim.population import Population, Style, sample_boltzmann_controls

from style_demos import roundabout_passages


@pytest.fixture(scope="module")
def passage():
    return roundabout_passages()


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


def test_boltzmann_sampler_has_the_maxent_moments(model, rng):
    from pirl_sim.mpc import LQPredictor

    theta = np.array([3.0, 1.0]) * 5.0
    x0 = np.tile([[1.0, -0.5]], (20000, 1))
    U = sample_boltzmann_controls(model, x0, theta, 10, rng).reshape(20000, -1)
    cost = LQPredictor(model.dynamics, model.features).cost(10)
    A, b = cost.terms(x0[:1], theta)
    mean = -np.linalg.solve(A, b[0])
    cov = np.linalg.inv(A)
    se = np.sqrt(np.diag(cov) / 20000)
    assert np.all(np.abs(U.mean(0) - mean) < 5 * se)
    np.testing.assert_allclose(np.cov(U.T), cov, atol=0.05 * np.abs(cov).max())


def test_population_rejects_bad_styles():
    fs = lqr_features()
    with pytest.raises(ValueError, match="unknown feature names in mean: \\['speed'\\]"):
        Population(fs, (Style("x", 1.0, {"speed": 1.0}),))
    with pytest.raises(ValueError, match="positive semi-definite"):
        Population(fs, (Style("x", 1.0, {"state_sq": 1.0}, cov=np.array([[1.0, 0.0], [0.0, -1.0]])),))
    with pytest.raises(ValueError, match="weight must be > 0"):
        Style("x", 0.0, {"state_sq": 1.0})
    with pytest.raises(ValueError, match="unique"):
        Population(fs, (Style("x", 1.0, {"state_sq": 1.0}), Style("x", 1.0, {"state_sq": 2.0})))
    with pytest.raises(ValueError, match="rationality"):
        Population(fs, (Style("x", 1.0, {"state_sq": 1.0}),), rationality=-1.0)
    with pytest.raises(TypeError, match="Generator"):
        Population(fs, (Style("x", 1.0, {"state_sq": 1.0}),)).sample_weights(3, 0)
