import numpy as np
import pytest

from pirl_sim.metrics import ade_fde, adjusted_rand_index, match_styles, med, weight_recovery_error
from pirl_sim.mpc import Bounds, ConstrainedLQPredictor, LQPredictor


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


def test_med_is_the_papers_formula():
    truth = np.zeros((2, 4, 2))
    pred = np.zeros((2, 4, 2))
    pred[0, :, 0] = 3.0
    pred[1, :, 1] = [0.0, 0.0, 0.0, 4.0]
    assert med(pred, truth) == pytest.approx((3.0 + 1.0) / 2)
    # different lengths: each trajectory averaged over its own length first
    assert med([pred[0], pred[1, :2]], [truth[0], truth[1, :2]]) == pytest.approx(1.5)
    ade, fde = ade_fde(pred, truth)
    assert ade == pytest.approx(2.0) and fde == pytest.approx(3.5)
    with pytest.raises(ValueError, match="differ in shape"):
        med(pred, truth[:, :3])
    with pytest.raises(ValueError, match="non-finite"):
        med(np.full((1, 2, 1), np.nan), np.zeros((1, 2, 1)))


def test_recovery_and_clustering_metrics():
    err = weight_recovery_error(np.array([[2.0, 1.0], [0.5, 1.0]]), np.array([[1.0, 1.0], [1.0, 1.0]]), 1)
    np.testing.assert_allclose(err, [np.log(2), np.log(2)])
    assert adjusted_rand_index([0, 0, 1, 1], [1, 1, 0, 0]) == pytest.approx(1.0)
    assert match_styles([0, 0, 1, 1, 2], [5, 5, 7, 7, 7]) == {5: 0, 7: 1}
    with pytest.raises(ValueError, match="positive"):
        weight_recovery_error(np.array([0.0, 1.0]), np.array([1.0, 1.0]), 1)
