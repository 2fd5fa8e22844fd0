"""Model-predictive control (pirl_sim.mpc): the LQ prediction, the constrained plan, SequentialMPC's Newton path_model by
one matrix product against the stage-wise assembly, Riccati steps against dense solves, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from pirl_sim.mpc import Bounds, ConstrainedLQPredictor, LQPredictor, SequentialMPC, _OuterExpansion
from pirl_sim.scenarios.passage import PassageConfig


THETA = np.array([3.0, 0.3, 1.0])


@pytest.fixture(scope="module")
def path_model():
    return PassageConfig().model()


def _pair(path_model, assembly):
    p = path_model.predictor()
    return SequentialMPC(p.dynamics, p.features, p.bounds, n_iter=p.n_iter, assembly=assembly)


def _random_inputs(rng, M: int, N: int):
    """Starts (M, 3), control sequences (M, N, 1) and positive weights (M, 3) for comparing Newton models."""
    x0 = np.column_stack([rng.uniform(0, 100, M), rng.uniform(1, 12, M), rng.normal(0, 0.5, M)])
    U = rng.normal(0, 1.0, (M, N, 1))
    theta = np.abs(rng.normal(1.0, 0.5, (M, 3))) + 0.05
    return x0, U, theta


def test_newton_models_agree(path_model):
    rng = np.random.default_rng(0)
    M, N = 40, 25
    x0, U, theta = _random_inputs(rng, M, N)
    A1, b1, c1 = _pair(path_model, "outer")._model(x0, U, theta)
    A0, b0, c0 = _pair(path_model, "stagewise")._model(x0, U, theta)
    assert np.abs(A1 - A0).max() <= 1e-12 * np.abs(A0).max()
    assert np.abs(b1 - b0).max() <= 1e-12 * np.abs(b0).max()
    np.testing.assert_allclose(c1, c0, rtol=1e-13)
    # the exact and the Gauss-Newton branch both occur in this batch (large jerks make exact Hessians indefinite)
    gap = np.abs(A1 - _pair(path_model, "outer")._expansion(N).hessians(theta, *_gn_terms(path_model, x0, U, theta, N)))
    n_exact = int((gap.max(axis=(1, 2)) > 1e-9 * np.abs(A1).max()).sum())
    assert 0 < n_exact < M


def _gn_terms(path_model, x0, U, theta, N):
    mpc = _pair(path_model, "outer")
    exp = mpc._expansion(N)
    _, _, jj, _ = exp.terms(mpc.dynamics.rollout(x0, U), U, theta)
    return jj, None, 1.0


def test_plans_agree_with_bounds(path_model):
    rng = np.random.default_rng(1)
    M = 60
    x0 = np.column_stack([rng.uniform(0, 100, M), rng.uniform(2, 12, M), np.clip(rng.normal(0, 0.5, M), -3.9, 2.9)])
    outer, stagewise = _pair(path_model, "outer"), _pair(path_model, "stagewise")
    U1, U0 = outer.controls(x0, THETA, 40), stagewise.controls(x0, THETA, 40)
    assert outer.n_qp == stagewise.n_qp > 0
    np.testing.assert_allclose(U1, U0, atol=1e-9)


def test_bad_assembly_is_named(path_model):
    p = path_model.predictor()
    with pytest.raises(ValueError, match="assembly must be 'outer' or 'stagewise', got 'fast'"):
        SequentialMPC(p.dynamics, p.features, p.bounds, assembly="fast")


def test_reference_feature_must_be_quadratic(path_model):
    from pirl_sim.features import FeatureSet

    f = path_model.features
    nonquad = FeatureSet(f.features, reference=f.features[0].name)
    with pytest.raises(ValueError, match="quadratic reference feature"):
        _OuterExpansion(path_model.dynamics, nonquad, 10)
    # SequentialMPC falls back to the stage-wise assembly then
    assert SequentialMPC(path_model.dynamics, nonquad)._expansion(10) is None


def test_riccati_steps_equal_dense_solves(path_model):
    """The Riccati recursion gives the dense Newton path_model's step and exact/Gauss-Newton choice, to rounding."""
    rng = np.random.default_rng(2)
    M, N = 60, 30
    x0, U, theta = _random_inputs(rng, M, N)
    mpc = _pair(path_model, "outer")
    exp = mpc._expansion(N)
    A, b, cost = mpc._model(x0, U, theta)
    dense = -np.linalg.solve(A, b[..., None])[..., 0].reshape(M, N, 1) - U
    step, cost_r = exp.newton_steps(mpc.dynamics.rollout(x0, U), U, theta)
    np.testing.assert_allclose(cost_r, cost, rtol=1e-13)
    assert np.abs(step - dense).max() <= 1e-10 * np.abs(dense).max()
    # the definiteness test agrees with the dense Cholesky one, and both branches occur
    from pirl_sim.mpc import _pd_rows

    _, _, jj, ww = exp.terms(mpc.dynamics.rollout(x0, U), U, theta)
    ok, _ = exp.riccati(exp.stage_hessians(theta, jj, ww, 0.5), None)
    np.testing.assert_array_equal(ok, ~_pd_rows(exp.hessians(theta, jj, ww, 0.5)))
    assert 0 < ok.sum() < M


def test_riccati_with_two_controls():
    """A planar point mass (n_u = 2) with a non-quadratic feature: the recursion's general branch."""
    from pirl_sim.dynamics import LinearDynamics
    from pirl_sim.features import Feature, FeatureSet, Residual, squared_control

    def bowl(x, u):  # r = |p|^2 / 10: not affine in the state
        pos = x[..., :2]
        r = (np.sum(pos**2, axis=-1) / 10.0)[..., None]
        jx = np.zeros(x.shape[:2] + (1, x.shape[-1]))
        jx[..., 0, :2] = pos / 5.0
        hx = np.zeros(x.shape[:2] + (1, x.shape[-1], x.shape[-1]))
        hx[..., 0, 0, 0] = hx[..., 0, 1, 1] = 0.2
        return Residual(r, jx, np.zeros((1, 1, 1, u.shape[-1])), hx)

    dt = 0.1
    dyn = LinearDynamics(A=np.block([[np.eye(2), dt * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]]),
                         B=np.vstack([np.zeros((2, 2)), dt * np.eye(2)]), dt=dt,
                         state_names=("x [m]", "y [m]", "vx [m/s]", "vy [m/s]"),
                         control_names=("ax [m/s^2]", "ay [m/s^2]"), position_index=(0, 1))
    feats = FeatureSet((Feature("bowl", bowl, quadratic=False), squared_control("effort")), reference="effort")
    rng = np.random.default_rng(3)
    M, N = 12, 15
    x0 = rng.normal(0, 3.0, (M, dyn.n_x))
    U = rng.normal(0, 1.0, (M, N, dyn.n_u))
    theta = np.column_stack([rng.uniform(0.5, 2.0, M), np.full(M, 0.05)])
    mpc = SequentialMPC(dyn, feats)
    A, b, _ = mpc._model(x0, U, theta)
    dense = -np.linalg.solve(A, b[..., None])[..., 0].reshape(U.shape) - U
    step, _ = mpc._expansion(N).newton_steps(dyn.rollout(x0, U), U, theta)
    assert np.abs(step - dense).max() <= 1e-9 * np.abs(dense).max()


def test_riccati_and_dense_plans_agree(path_model):
    """Whole predictions with the Riccati steps (large batches) and with dense steps only."""
    rng = np.random.default_rng(4)
    M = 120
    x0 = np.column_stack([rng.uniform(0, 100, M), rng.uniform(2, 12, M), np.clip(rng.normal(0, 0.5, M), -3.9, 2.9)])
    p = path_model.predictor()
    riccati = SequentialMPC(p.dynamics, p.features, p.bounds, riccati_rows=1)
    dense = SequentialMPC(p.dynamics, p.features, p.bounds, riccati_rows=None)
    U1, U0 = riccati.controls(x0, THETA, 40), dense.controls(x0, THETA, 40)
    assert riccati.n_qp == dense.n_qp > 0
    np.testing.assert_allclose(U1, U0, atol=1e-9)


def test_large_batches_are_planned_in_parts(path_model):
    """More starts than ``max_rows``: planned in parts, each start's plan that of one batch to rounding (batched
    products of other sizes round differently), cold and warm."""
    rng = np.random.default_rng(6)
    M = 23
    x0 = np.column_stack([rng.uniform(0, 100, M), rng.uniform(2, 12, M), np.clip(rng.normal(0, 0.5, M), -3.9, 2.9)])
    theta = np.column_stack([rng.uniform(0.5, 2, M), rng.uniform(0.5, 2, M), np.ones(M)])
    p = path_model.predictor()
    whole = SequentialMPC(p.dynamics, p.features, p.bounds, riccati_rows=None)
    parts = SequentialMPC(p.dynamics, p.features, p.bounds, riccati_rows=None, max_rows=5)
    U0 = whole.controls(x0, theta, 30)
    np.testing.assert_allclose(parts.controls(x0, theta, 30), U0, atol=1e-10)
    assert parts.n_qp == whole.n_qp > 0
    init = np.roll(U0, -1, axis=1)
    np.testing.assert_allclose(parts.controls(x0, theta, 30, init), whole.controls(x0, theta, 30, init), atol=1e-10)
    with pytest.raises(ValueError, match="max_rows must be a positive integer"):
        SequentialMPC(p.dynamics, p.features, p.bounds, max_rows=0)


@pytest.mark.parametrize("bad", [0, -3, 2.5, "many"])
def test_bad_riccati_rows_are_named(path_model, bad):
    p = path_model.predictor()
    with pytest.raises(ValueError, match="riccati_rows must be a positive integer or None"):
        SequentialMPC(p.dynamics, p.features, p.bounds, riccati_rows=bad)


def test_positive_definite_solves_match_lu():
    from pirl_sim.mpc import _solve_pd

    rng = np.random.default_rng(5)
    X = rng.normal(size=(6, 12, 12))
    A = X @ np.swapaxes(X, 1, 2) + 0.1 * np.eye(12)
    A[2] = np.diag(np.r_[-1.0, np.ones(11)])  # not positive definite: solved by LU instead
    b = rng.normal(size=(6, 12))
    np.testing.assert_allclose(_solve_pd(A, b), np.linalg.solve(A, b[..., None])[..., 0], rtol=1e-10, atol=1e-12)


def test_lq_prediction_is_the_optimum(model, rng):
    pred = LQPredictor(model.dynamics, model.features)
    x0 = rng.normal(size=(4, 2))
    theta = np.array([3.0, 1.0])
    U = pred.controls(x0, theta, 15)
    # gradient of the cost at the returned controls is zero
    X = model.dynamics.rollout(x0, U)
    der = model.features.derivatives(model.dynamics, X, U)
    g = np.einsum("k,mkd->md", theta, der.grad)
    assert np.max(np.abs(g)) < 1e-9
    # per-row weights give the same answer as shared ones
    np.testing.assert_allclose(pred.controls(x0, np.tile(theta, (4, 1)), 15), U, atol=1e-10)


def test_constrained_agrees_when_inactive_and_respects_bounds(model, rng):
    x0 = np.column_stack([rng.uniform(-2, 2, 10), rng.uniform(-0.5, 0.5, 10)])
    theta = np.array([2.0, 1.0])
    free = LQPredictor(model.dynamics, model.features).predict(x0, theta, 30)
    loose = ConstrainedLQPredictor(
        model.dynamics, model.features, Bounds(state={"v [m/s]": (-100, 100)}, control={"a [m/s^2]": (-100, 100)})
    ).predict(x0, theta, 30)
    np.testing.assert_allclose(loose, free, atol=1e-8)
    tight = ConstrainedLQPredictor(
        model.dynamics, model.features, Bounds(state={"v [m/s]": (-1.0, 1.0)}, control={"a [m/s^2]": (-1.5, 1.5)})
    )
    X = tight.predict(x0, theta, 30)
    U = tight.controls(x0, theta, 30)
    assert X[:, 1:, 1].min() >= -1.0 - 1e-6 and X[:, 1:, 1].max() <= 1.0 + 1e-6
    assert np.abs(U).max() <= 1.5 + 1e-6
    assert np.abs(U).max() > 1.4  # the bound is active somewhere: the two really differ


def test_mpc_bad_input(model):
    pred = LQPredictor(model.dynamics, model.features)
    with pytest.raises(ValueError, match="start states must have shape"):
        pred.predict(np.zeros((2, 3)), [1.0, 1.0], 5)
    with pytest.raises(ValueError, match="horizon must be >= 1"):
        pred.predict(np.zeros((2, 2)), [1.0, 1.0], 0)
    with pytest.raises(TypeError, match="horizon must be an integer"):
        pred.predict(np.zeros((2, 2)), [1.0, 1.0], 2.5)
    with pytest.raises(ValueError, match="start states must be finite"):
        pred.predict(np.array([[np.nan, 0.0]]), [1.0, 1.0], 5)
    with pytest.raises(ValueError, match="unknown state names \\['speed'\\]"):
        ConstrainedLQPredictor(model.dynamics, model.features, Bounds(state={"speed": (0, 1)}))
    with pytest.raises(ValueError, match="low <= high"):
        ConstrainedLQPredictor(model.dynamics, model.features, Bounds(control={"a [m/s^2]": (1, 0)}))
    infeasible = ConstrainedLQPredictor(
        model.dynamics, model.features, Bounds(state={"v [m/s]": (-0.1, 0.1)}, control={"a [m/s^2]": (-0.1, 0.1)})
    )
    with pytest.raises(RuntimeError, match="infeasible"):
        infeasible.predict(np.array([[0.0, 3.0]]), [1.0, 1.0], 5)


@pytest.mark.parametrize("solver", ["daqp", "casadi:qpoases"])
def test_solve_many_equals_row_by_row(path_model, solver):
    """`BoxQP.solve_many` (the bounds of all rows at once, then the solver per row) gives `solve`'s controls on
    random bounded problems, most of them on a bound, and marks the infeasible ones (a start too fast to stop
    within the speed bound) instead of raising."""
    from pirl_sim.mpc import BoxQP

    pytest.importorskip("daqp" if solver == "daqp" else "casadi")
    p = path_model.predictor()
    rng = np.random.default_rng(3)
    N, M = 15, 60
    x0 = np.column_stack([rng.uniform(0, 100, M), rng.uniform(0, 14, M), rng.uniform(-3.5, 2.5, M)])
    x0[-1] = [0.0, 35.0, 3.0]  # far above the speed bound: no control gets it back in time
    R = rng.normal(size=(M, N, N))
    A = R @ np.swapaxes(R, 1, 2) + 0.5 * np.eye(N)
    b = rng.normal(0, 40.0, (M, N))  # strong pulls: most unconstrained optima break a bound
    many = BoxQP(p.dynamics, p.bounds, solver)
    U, feasible = many.solve_many(A, b, x0, N)
    one = BoxQP(p.dynamics, p.bounds, solver)
    on_bound = 0
    for m in range(M):
        try:
            ref = one.solve(A[m], b[m], x0[m], N)
        except RuntimeError:
            assert not feasible[m] and np.isnan(U[m]).all()
            continue
        assert feasible[m]
        np.testing.assert_allclose(U[m], ref, atol=1e-9, rtol=0)
        free = -np.linalg.solve(A[m], b[m])
        on_bound += bool(one.violation(x0[m : m + 1], free[None, :, None])[0] > 1e-9)
    assert not feasible[-1]
    assert on_bound > M // 2


def test_a_residuals_stated_support_gives_the_expansion_found_without_it():
    """Residuals that state the state entries they depend on (``x_support``) give the stage terms found by
    scanning their Jacobians, exactly."""
    import dataclasses

    from pirl_sim.driving import SpeedProfile, roundabout_features
    from pirl_sim.dynamics import following
    from pirl_sim.features import Feature, FeatureSet
    from pirl_sim.paths import ReferencePath

    path = ReferencePath.from_polyline(np.column_stack([np.linspace(0.0, 200.0, 41), np.zeros(41)]))
    feats = roundabout_features(SpeedProfile(path, 2.0, 8.0), "interacting")

    def unstated(feat):
        def residual(x, u, _f=feat.residual):
            return _f(x, u)._replace(x_support=None)
        return dataclasses.replace(feat, residual=residual)

    assert all(feats.features[k].residual(np.zeros((1, 2, 7)), np.zeros((1, 2, 1))).x_support is not None
               for k in (0, 3, 4))  # speed_dev, headway, yielding
    plain = FeatureSet([unstated(f) for f in feats.features], reference=feats.reference)
    dyn = following(0.2, obstacles=2)
    rng = np.random.default_rng(3)
    M, N = 5, 12
    x0 = np.column_stack([rng.uniform(0, 100, M), rng.uniform(2, 10, M), rng.normal(0, 0.5, M),
                          rng.uniform(3, 30, M), rng.uniform(2, 10, M), rng.uniform(3, 30, M), np.zeros(M)])
    U = rng.normal(0, 0.3, (M, N, 1))
    X = dyn.rollout(x0, U)
    theta = rng.uniform(0.1, 2.0, (M, feats.n_features))
    exp_stated, exp_found = _OuterExpansion(dyn, feats, N), _OuterExpansion(dyn, plain, N)
    stated, found = exp_stated.stage_terms(X, U, theta), exp_found.stage_terms(X, U, theta)
    for a, b in zip(stated[:2], found[:2]):  # values, stage gradients
        np.testing.assert_array_equal(a, b)
    # on a straight path speed_dev does not depend on s: its stated column only adds zeros
    np.testing.assert_array_equal(exp_stated.stage_hessians(theta, *stated[2:], 0.5),
                                  exp_found.stage_hessians(theta, *found[2:], 0.5))
