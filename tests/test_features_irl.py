import warnings

import numpy as np
import pytest

from pirl_sim.dynamics import longitudinal
from pirl_sim.features import Feature, FeatureSet, Residual, lqr_features, squared_control, squared_state
from pirl_sim.irl import (
    HessianRegularizationWarning,
    LaplaceBlock,
    LogNormalPrior,
    fit_weights,
    laplace_nll,
)
from pirl_sim.model import DriverModel
from pirl_sim.population import Population, Style, generate_demonstrations, sample_boltzmann_controls


def _nonquadratic_features():
    """A feature with a residual that is not affine in the state: (v - sin(s))^2, plus a^2 and j^2 (means)."""

    def resid(x, u):
        s, v = x[..., 0], x[..., 1]
        r = (v - np.sin(s))[..., None]
        jx = np.zeros(x.shape[:2] + (1, 3))
        jx[..., 0, 0] = -np.cos(s)
        jx[..., 0, 1] = 1.0
        hx = np.zeros(x.shape[:2] + (1, 3, 3))
        hx[..., 0, 0, 0] = np.sin(s)
        return Residual(r, jx, np.zeros((1, 1, 1, 1)), hx)

    return FeatureSet(
        (
            Feature("speed_dev", resid, reduction="mean", quadratic=False),
            squared_state("acc", [2], reduction="mean"),
            squared_control("jerk", reduction="mean"),
        ),
        reference="jerk",
    )


def _fd_check(fs, dyn, x0, U):
    N = U.shape[0]
    X = dyn.rollout(x0[None], U[None])
    der = fs.derivatives(dyn, X, U[None])

    def vals(Uflat):
        Uc = Uflat.reshape(1, N, dyn.n_u)
        return fs.values(dyn.rollout(x0[None], Uc), Uc)[0]

    u = U.ravel()
    h = 1e-6
    d = u.size
    grad_fd = np.empty((fs.n_features, d))
    hess_fd = np.empty((fs.n_features, d, d))
    for i in range(d):
        e = np.zeros(d)
        e[i] = h
        grad_fd[:, i] = (vals(u + e) - vals(u - e)) / (2 * h)
    # Hessian by differencing the exact gradient
    def grads(Uflat):
        Uc = Uflat.reshape(1, N, dyn.n_u)
        return fs.derivatives(dyn, dyn.rollout(x0[None], Uc), Uc).grad[0]

    for i in range(d):
        e = np.zeros(d)
        e[i] = h
        hess_fd[:, :, i] = (grads(u + e) - grads(u - e)) / (2 * h)
    hess = np.broadcast_to(der.hess, (1,) + der.hess.shape[1:])[0]
    return der.grad[0], grad_fd, hess, hess_fd


@pytest.mark.parametrize("case", ["lqr", "nonquadratic"])
def test_feature_derivatives_match_finite_differences(case, rng):
    if case == "lqr":
        from pirl_sim.dynamics import point_mass

        dyn, fs = point_mass(0.1), lqr_features()
    else:
        dyn, fs = longitudinal(0.2), _nonquadratic_features()
    x0 = rng.normal(size=dyn.n_x)
    U = rng.normal(size=(8, dyn.n_u))
    g, g_fd, H, H_fd = _fd_check(fs, dyn, x0, U)
    assert np.max(np.abs(g - g_fd)) <= 1e-5 * max(1.0, np.max(np.abs(g)))
    assert np.max(np.abs(H - H_fd)) <= 1e-5 * max(1.0, np.max(np.abs(H)))


def test_laplace_gradient_and_hessian_match_finite_differences(rng):
    dyn, fs = longitudinal(0.2), _nonquadratic_features()
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


def test_feature_set_names_and_weights():
    fs = lqr_features()
    assert fs.names == ("state_sq", "control_sq")
    np.testing.assert_array_equal(fs.weights({"control_sq": 1, "state_sq": 4}), [4, 1])
    with pytest.raises(ValueError, match="unknown: \\['speed'\\]"):
        fs.weights({"speed": 1, "state_sq": 1, "control_sq": 1})
    with pytest.raises(ValueError, match="2 entries"):
        fs.weights([1, 2, 3])
    with pytest.raises(ValueError, match="not one of"):
        FeatureSet(fs.features, reference="nope")
    np.testing.assert_allclose(fs.normalize([8.0, 2.0]), [4.0, 1.0])
