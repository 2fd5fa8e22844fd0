"""SequentialMPC's Newton model by one matrix product (``assembly="outer"``, the default) against the stage-wise
assembly through FeatureSet.derivatives: the same matrices and plans to floating-point rounding."""

from __future__ import annotations

import numpy as np
import pytest

from pirl_sim.mpc import SequentialMPC, _OuterExpansion
from pirl_sim.scenarios.passage import PassageConfig

THETA = np.array([3.0, 0.3, 1.0])


@pytest.fixture(scope="module")
def model():
    return PassageConfig().model()


def _pair(model, assembly):
    p = model.predictor()
    return SequentialMPC(p.dynamics, p.features, p.bounds, n_iter=p.n_iter, assembly=assembly)


def test_newton_models_agree(model):
    rng = np.random.default_rng(0)
    M, N = 40, 25
    x0 = np.column_stack([rng.uniform(0, 100, M), rng.uniform(1, 12, M), rng.normal(0, 0.5, M)])
    U = rng.normal(0, 1.0, (M, N, 1))
    theta = np.abs(rng.normal(1.0, 0.5, (M, 3))) + 0.05
    A1, b1, c1 = _pair(model, "outer")._model(x0, U, theta)
    A0, b0, c0 = _pair(model, "stagewise")._model(x0, U, theta)
    assert np.abs(A1 - A0).max() <= 1e-12 * np.abs(A0).max()
    assert np.abs(b1 - b0).max() <= 1e-12 * np.abs(b0).max()
    np.testing.assert_allclose(c1, c0, rtol=1e-13)
    # the exact and the Gauss-Newton branch both occur in this batch (large jerks make exact Hessians indefinite)
    gap = np.abs(A1 - _pair(model, "outer")._expansion(N).hessians(theta, *_gn_terms(model, x0, U, theta, N)))
    n_exact = int((gap.max(axis=(1, 2)) > 1e-9 * np.abs(A1).max()).sum())
    assert 0 < n_exact < M


def _gn_terms(model, x0, U, theta, N):
    mpc = _pair(model, "outer")
    exp = mpc._expansion(N)
    _, _, jj, _ = exp.terms(mpc.dynamics.rollout(x0, U), U, theta)
    return jj, None, 1.0


def test_plans_agree_with_bounds(model):
    rng = np.random.default_rng(1)
    M = 60
    x0 = np.column_stack([rng.uniform(0, 100, M), rng.uniform(2, 12, M), np.clip(rng.normal(0, 0.5, M), -3.9, 2.9)])
    outer, stagewise = _pair(model, "outer"), _pair(model, "stagewise")
    U1, U0 = outer.controls(x0, THETA, 40), stagewise.controls(x0, THETA, 40)
    assert outer.n_qp == stagewise.n_qp > 0
    np.testing.assert_allclose(U1, U0, atol=1e-9)


def test_bad_assembly_is_named(model):
    p = model.predictor()
    with pytest.raises(ValueError, match="assembly must be 'outer' or 'stagewise', got 'fast'"):
        SequentialMPC(p.dynamics, p.features, p.bounds, assembly="fast")


def test_reference_feature_must_be_quadratic(model):
    from pirl_sim.features import FeatureSet

    f = model.features
    nonquad = FeatureSet(f.features, reference=f.features[0].name)
    with pytest.raises(ValueError, match="quadratic reference feature"):
        _OuterExpansion(model.dynamics, nonquad, 10)
    # SequentialMPC falls back to the stage-wise assembly then
    assert SequentialMPC(model.dynamics, nonquad)._expansion(10) is None
