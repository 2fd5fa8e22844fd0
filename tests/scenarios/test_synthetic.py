"""The synthetic scenario (pirl_sim.scenarios.synthetic): the paper's kernels and data, reproducible, bad values
refused."""

import numpy as np
import pytest

from pirl_sim.features import lqr_features
from pirl_sim.population import Population
from pirl_sim.scenarios.synthetic import PAPER_STYLES, SyntheticConfig, generate


def test_synthetic_follows_the_paper_and_is_reproducible():
    a = generate(SyntheticConfig(n_trajectories=100, n_train=90, seed=7))
    b = generate(SyntheticConfig(n_trajectories=100, n_train=90, seed=7))
    c = generate(SyntheticConfig(n_trajectories=100, n_train=90, seed=8))
    assert len(a.train) == 90 and len(a.test) == 10
    assert all(t.n_steps == 50 and t.dt == 0.1 for t in a.train)
    assert all(np.array_equal(x.states, y.states) for x, y in zip(a.train, b.train))
    assert not all(np.array_equal(x.states, y.states) for x, y in zip(a.train, c.train))
    theta = np.array([t.metadata["theta"][0] for t in a.train + a.test])
    assert np.all(theta > 0)
    model = a.model
    for t in a.train[:5]:
        np.testing.assert_allclose(model.dynamics.residual(t.states, t.controls), 0.0, atol=1e-12)


def test_paper_kernels_have_the_papers_moments():
    pop = Population(lqr_features(), PAPER_STYLES)
    theta, style = pop.sample_weights(20000, np.random.default_rng(0))
    k1, k2 = theta[style == 0, 0], theta[style == 1, 0]
    assert k1.mean() == pytest.approx(4.0, abs=0.05) and k1.std() == pytest.approx(1.0, abs=0.05)
    assert k2.mean() == pytest.approx(0.4, abs=0.01) and k2.std() == pytest.approx(0.1, abs=0.01)


def test_synthetic_config_rejects_bad_values():
    with pytest.raises(ValueError, match="n_train must be in"):
        SyntheticConfig(n_trajectories=10, n_train=10)
    with pytest.raises(ValueError, match="dt must be"):
        SyntheticConfig(dt=0.0)
    with pytest.raises(TypeError, match="n_steps must be an integer"):
        SyntheticConfig(n_steps=2.5)
