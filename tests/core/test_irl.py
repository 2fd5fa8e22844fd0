"""Laplace IRL (pirl_sim.irl): gradient and Hessian against finite differences, diagonal and dense paths, weights
from Boltzmann demonstrations, the regularised Hessian, and Gauss-Newton fits that converge away from their start."""

import warnings

import numpy as np
import pytest

from pirl_sim.driving import fit_longitudinal_states, roundabout_model
from pirl_sim.dynamics import longitudinal
from pirl_sim.features import Feature, FeatureSet, Residual, squared_control
from pirl_sim.irl import (
    HessianRegularizationWarning,
    IRLConvergenceWarning,
    LaplaceBlock,
    LogNormalPrior,
    attach_gauss_newton,
    fit_weights,
    laplace_nll,
)
from pirl_sim.learners import PIRLKNN, TIRL
from pirl_sim.paths import ReferencePath
from pirl_sim.population import Population, Style, generate_demonstrations
from pirl_sim.scenarios.passage import PassageConfig, generate, passage_polyline
from pirl_sim.trajectory import Trajectory

from cost_features import nonquadratic_features


def test_laplace_gradient_and_hessian_match_finite_differences(rng):
    dyn, fs = longitudinal(0.2), nonquadratic_features()
    X0 = rng.normal(size=(3, 3)) * 0.3
    U = rng.normal(size=(3, 6, 1))
    der = fs.derivatives(dyn, dyn.rollout(X0, U), U)
    block = LaplaceBlock.from_derivatives(der, fs.reference_index)
    theta = np.array([[2.0, 0.5, 1.0], [1.0, 1.0, 3.0], [0.2, 4.0, 1.5]])
    nll, g, H, *_ = laplace_nll(theta, block, order=2)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        fp, gp, *_ = laplace_nll(theta + e, block, order=1)
        fm, gm, *_ = laplace_nll(theta - e, block, order=1)
        np.testing.assert_allclose(g[:, k], (fp - fm) / (2 * h), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(H[:, :, k], (gp - gm) / (2 * h), rtol=1e-5, atol=1e-6)


def test_diagonal_and_dense_paths_agree(model, rng):
    fs, dyn = model.features, model.dynamics
    x0 = rng.normal(size=(5, 2))
    U = rng.normal(size=(5, 20, 1))
    der = fs.derivatives(dyn, dyn.rollout(x0, U), U)
    diag = LaplaceBlock.from_derivatives(der, fs.reference_index)
    dense = LaplaceBlock(der.grad, der.hess, None)
    assert diag.diagonal and not dense.diagonal
    theta = rng.uniform(0.1, 5, size=(5, 2))
    for a, b in zip(laplace_nll(theta, diag, 2)[:3], laplace_nll(theta, dense, 2)[:3]):
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-8)


def test_noise_free_demos_give_exact_direction_and_bounded_scale(model, rng):
    pop = Population(model.features, (Style("a", 1.0, {"state_sq": 2.5}, {"state_sq": 1.0}),))
    demos = generate_demonstrations(model, pop, rng.normal(size=(50, 2)), 30, rng)
    (block, idx), = model.laplace_blocks(demos)
    res = fit_weights(block, None, model.features, log_bounds=(-20, 20))
    true = np.stack([d.metadata["theta"] for d in demos])[idx]
    np.testing.assert_allclose(res.normalized, true, rtol=1e-3)
    assert np.all(np.isfinite(res.theta)) and res.converged.all()
    assert res.at_bound[:, model.features.reference_index].all()  # scale unidentified: held at its bound
    assert not res.at_bound[:, 0].any()


def _boltzmann_demos(model, n, rng, q=3.0, beta=20.0):
    x0 = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-1, 1, n)])
    pop = Population(model.features, (Style("s", 1.0, {"state_sq": q}),), rationality=beta)
    return generate_demonstrations(model, pop, x0, 30, rng)


def test_tirl_error_shrinks_with_more_boltzmann_demos(model):
    errors = {}
    for n in (20, 500):
        errs = []
        for seed in range(5):
            demos = _boltzmann_demos(model, n, np.random.default_rng(seed))
            (block, _), = model.laplace_blocks(demos)
            res = fit_weights(block, np.zeros(n, int), model.features)
            errs.append(abs(np.log(res.normalized[0, 0] / 3.0)))
            if n == 500:
                assert res.beta[0] == pytest.approx(20.0, rel=0.15)  # the scale is identified on noisy demos
        errors[n] = np.median(errs)
    assert errors[500] < errors[20] / 2
    assert errors[500] < 0.05


def test_per_demo_weights_correlate_with_truth(model, rng):
    from scipy.stats import spearmanr

    n = 300
    x0 = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-1, 1, n)])
    pop = Population(model.features, (Style("s", 1.0, {"state_sq": 2.0}, {"state_sq": 1.5}),), rationality=50.0)
    demos = generate_demonstrations(model, pop, x0, 40, rng)
    (block, idx), = model.laplace_blocks(demos)
    res = fit_weights(block, None, model.features)
    true = np.array([d.metadata["theta"][0] for d in demos])[idx]
    rho = spearmanr(res.normalized[:, 0], true).statistic
    assert rho > 0.6


def _concave_features():
    """(1 - s^2)^2 is concave in s near s = 0 (its Hessian there is -4): a cost that breaks the Laplace step."""

    def resid(x, u):
        s = x[..., 0]
        jx = np.zeros(x.shape[:2] + (1, 3))
        jx[..., 0, 0] = -2.0 * s
        hx = np.zeros(x.shape[:2] + (1, 3, 3))
        hx[..., 0, 0, 0] = -2.0
        return Residual((1.0 - s**2)[..., None], jx, np.zeros((1, 1, 1, 1)), hx)

    return FeatureSet((Feature("bump", resid, quadratic=False), squared_control("jerk")), reference="jerk")


def test_indefinite_hessian_is_regularised_with_a_warning(rng):
    dyn, fs = longitudinal(0.2), _concave_features()
    U = rng.normal(size=(4, 6, 1)) * 0.01
    der = fs.derivatives(dyn, dyn.rollout(np.zeros((4, 3)), U), U)
    block = LaplaceBlock.from_derivatives(der, fs.reference_index)
    nll, *_, n_reg, worst = laplace_nll(np.tile([1e6, 1.0], (4, 1)), block, order=0)
    assert n_reg == 4 and worst < 0 and np.all(np.isfinite(nll))
    with pytest.warns(HessianRegularizationWarning, match="not positive definite"):
        res = fit_weights(block, None, fs, log_bounds=(5.0, 20.0))
    assert np.all(np.isfinite(res.theta)) and res.n_regularized > 0


def test_fit_weights_rejects_bad_arguments(model, rng):
    demos = _boltzmann_demos(model, 5, rng)
    (block, _), = model.laplace_blocks(demos)
    with pytest.raises(ValueError, match="labels of shape"):
        fit_weights(block, np.zeros(3, int), model.features)
    with pytest.raises(ValueError, match="log_bounds"):
        fit_weights(block, None, model.features, log_bounds=(1, -1))
    with pytest.raises(ValueError, match="prior std must be > 0"):
        LogNormalPrior(np.zeros(2), np.array([1.0, 0.0]))


STOP_LINE = 45.0  # [m] along the path: the ring entry is at 50 m
N_DEMOS, N_STEPS, DT = 30, 75, 0.2  # 15 s demonstrations


def _yielding_demos(n: int, n_steps: int, rng: np.random.Generator, sigma: float = 0.1):
    """Drivers who brake to a stop before the entry, wait and accelerate into the ring; states estimated
    from noisy positions."""
    path = ReferencePath.from_polyline(passage_polyline(20.0, 50.0, 270.0, 50.0))
    model = roundabout_model(path, dt=DT)
    A, B = model.dynamics.A, model.dynamics.B[:, 0]
    demos = []
    for _ in range(n):
        x = np.array([rng.uniform(5.0, 15.0), rng.uniform(7.0, 11.0), 0.0])  # s [m], v [m/s], a [m/s^2]
        brake, wait, accel = rng.uniform(1.5, 3.0), rng.uniform(0.5, 2.5), rng.uniform(1.0, 2.0)
        s_true, t_stop = [x[0]], None
        for k in range(n_steps):
            if t_stop is None:
                braking = x[0] >= STOP_LINE - x[1] ** 2 / (2.0 * brake)
                a_target = -brake if braking and x[1] > 0.05 else 0.0
                if x[1] <= 0.05:
                    t_stop = k * DT
            elif k * DT < t_stop + wait:
                a_target = 0.0
            else:
                a_target = accel if x[1] < 7.0 else 0.0
            x = A @ x + B * np.clip((a_target - x[2]) / DT, -8.0, 8.0)
            if x[1] < 0.0:
                x = np.array([x[0], 0.0, 0.0])
            s_true.append(x[0])
        s_obs = np.asarray(s_true) + sigma * rng.standard_normal(n_steps + 1)
        states, controls = fit_longitudinal_states(s_obs, model.dynamics)
        demos.append(Trajectory(states, controls, DT))
    return model, demos


@pytest.fixture(scope="module")
def yielding():
    return _yielding_demos(N_DEMOS, N_STEPS, np.random.default_rng(0))


def _fit(model, demos, labels, **kw):
    blocks = attach_gauss_newton(model.laplace_blocks(demos), model.features, model.dynamics, demos)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = fit_weights([b for b, _ in blocks], [labels[i] for _, i in blocks], model.features,
                          n_groups=int(labels.max()) + 1, **kw)
    return res, [w.category for w in caught]


def test_exact_hessian_fit_freezes_at_its_start(yielding):
    """The freeze itself (``hessian="exact"``, still an option): one group, [1, 1, 1], beta near e^-20."""
    model, demos = yielding
    res, caught = _fit(model, demos, np.zeros(N_DEMOS, int), hessian="exact")
    np.testing.assert_allclose(res.normalized[0], [1.0, 1.0, 1.0])
    assert np.log(res.beta[0]) < -15.0
    assert res.n_regularized > N_DEMOS // 2 and HessianRegularizationWarning in caught
    assert not res.gauss_newton.any()


def test_tirl_converges_away_from_its_start(yielding):
    model, demos = yielding
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # neither a regularisation nor a convergence warning
        tirl = TIRL(model).fit(demos)
    res = tirl.irl_result_
    assert res.converged.all() and res.gauss_newton.all() and res.n_regularized == 0
    assert res.gradient_norm[0] <= 1e-6 * N_DEMOS
    assert not np.allclose(tirl.theta_, 1.0, rtol=1e-3)
    assert not res.at_bound[0, model.features.reference_index]  # beta is interior
    assert 1.0 < tirl.beta_ < 1e4
    # the optimum: no direction in w lowers the Gauss-Newton likelihood
    blocks = attach_gauss_newton(model.laplace_blocks(demos), model.features, model.dynamics, demos)
    from pirl_sim.irl import laplace_nll

    def nll(theta):
        return sum(laplace_nll(theta[None].repeat(b.n_demos, 0), b.gauss_newton(), 0)[0].sum() for b, _ in blocks)

    base = nll(res.theta[0])
    for k in range(3):
        for factor in (0.9, 1.1):
            theta = res.theta[0].copy()
            theta[k] *= factor
            assert nll(theta) >= base - 1e-6 * abs(base)


def test_per_demonstration_fits_all_converge(yielding):
    model, demos = yielding
    res, caught = _fit(model, demos, np.arange(N_DEMOS))
    assert res.converged.all() and IRLConvergenceWarning not in caught
    assert res.n_regularized == 0 and HessianRegularizationWarning not in caught
    stuck_at_start = np.all(np.isclose(res.normalized, 1.0, rtol=1e-6), axis=1)
    assert not stuck_at_start.any()
    assert not res.at_bound[:, model.features.reference_index].any()  # no beta at a bound
    knn = PIRLKNN(model, n_neighbors=3).fit(demos)
    assert knn.n_scale_at_bound_ == 0
    np.testing.assert_allclose(knn.demo_theta_, res.normalized, rtol=1e-8)


def test_auto_keeps_the_exact_fit_where_it_is_well_posed():
    """Boltzmann-rational drivers of the paper's passage: every exact Hessian is positive definite at the fit,
    so "auto" returns the exact fit bit for bit (the reproductions depend on it); the Gauss-Newton fit of the
    same near-optimal demonstrations is close to it."""
    data = generate(PassageConfig(n_trajectories=60, n_train=50, seed=1))
    model, demos = data.model, data.train
    labels = np.arange(len(demos))
    exact, _ = _fit(model, demos, labels, hessian="exact")
    auto, _ = _fit(model, demos, labels, hessian="auto")
    assert not auto.gauss_newton.any()
    np.testing.assert_array_equal(auto.theta, exact.theta)
    gn, _ = _fit(model, demos, np.zeros(len(demos), int), hessian="gauss_newton")
    ex1, _ = _fit(model, demos, np.zeros(len(demos), int), hessian="exact")
    assert gn.converged.all() and gn.gauss_newton.all()
    np.testing.assert_allclose(np.log(gn.normalized), np.log(ex1.normalized), atol=0.1)


def test_quadratic_features_have_no_separate_gauss_newton_blocks():
    from pirl_sim.scenarios.synthetic import SyntheticConfig, generate as synthetic

    data = synthetic(SyntheticConfig(n_trajectories=20, n_train=10))
    blocks = data.model.laplace_blocks(data.train)
    attached = attach_gauss_newton(blocks, data.model.features, data.model.dynamics, data.train)
    assert all(b1 is b2 and b1.gauss_newton() is b1 for (b1, _), (b2, _) in zip(blocks, attached))


def test_fit_weights_rejects_an_unknown_hessian(yielding):
    model, demos = yielding
    (block, _), *_ = model.laplace_blocks(demos[:2])
    with pytest.raises(ValueError, match="hessian must be one of"):
        fit_weights(block, None, model.features, hessian="newton")
