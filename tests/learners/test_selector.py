"""PIRL-kNN's aggregate="selected": a bank of next-steps costs chosen online by their learned predicted errors
(learners/selector.py)."""

import numpy as np
import pytest

from pirl_sim.learners import PIRLKNN
from pirl_sim.learners.selector import (ErrorRegression, FutureRegression, cost_bank, mixture_weights,
                                       rollout_errors, softmin)
from pirl_sim.model import synthetic_model
from pirl_sim.trajectory import Trajectory


def _two_kinds(model, rng, n):
    """Point masses regulated to 0 from a random start, half gently (q/r = 0.05), half hard (q/r = 20); the
    speed after a few steps tells which."""
    out = []
    for i in range(n):
        theta = [0.05, 1.0] if i % 2 else [20.0, 1.0]
        x0 = np.array([rng.uniform(1.0, 3.0), 0.0])
        states = model.predict_states(x0[None], np.array([theta]), 30)[0]
        controls = np.diff(states[:, 1])[:, None] / model.dynamics.dt
        out.append(Trajectory(states, controls, model.dynamics.dt))
    return out


def _learner(model, **kw):
    return PIRLKNN(model=model, window=8, stride=2, target="next", target_steps=10, state_features=(0, 1),
                   lookup_features=False, aggregate="selected", **kw)


def test_bank_spans_the_costs_with_one_member_per_cluster():
    rng = np.random.default_rng(0)
    log_theta = np.vstack([rng.normal(-3, 0.1, (20, 2)), rng.normal(3, 0.1, (20, 2))])
    bank = cost_bank(log_theta, 2)
    assert sorted(np.sign(log_theta[bank, 0])) == [-1, 1]  # one from each group
    assert np.array_equal(bank, cost_bank(log_theta, 2))  # same seed, same bank
    np.testing.assert_array_equal(cost_bank(log_theta, 40), np.arange(40))  # as many as the costs: all
    with pytest.raises(ValueError, match="n=0"):
        cost_bank(log_theta, 0)


def test_softmin_is_a_distribution_that_sharpens_with_a_lower_temperature():
    e = np.array([[0.1, 0.2, 0.5]])
    for t in (0.01, 0.1, 1.0):
        p = softmin(e, t)
        np.testing.assert_allclose(p.sum(axis=1), 1.0)
        assert np.all(np.diff(p[0]) < 0)  # a larger error, a lower probability
    assert softmin(e, 0.01)[0, 0] > softmin(e, 1.0)[0, 0]
    np.testing.assert_allclose(softmin(e, 0.1), np.exp(-e / 0.1) / np.exp(-e / 0.1).sum())


def test_rollout_errors_are_mean_absolute_errors_of_each_cost():
    model = synthetic_model()
    x0 = np.array([[2.0, 0.0], [1.0, 0.5]])
    theta = np.array([[0.05, 1.0], [20.0, 1.0]])
    truth = model.predict_states(x0, np.tile(theta[1], (2, 1)), 6)[:, 1:, 0]
    e = rollout_errors(model, x0, theta, truth)
    assert e.shape == (2, 2)
    np.testing.assert_allclose(e[:, 1], 0.0, atol=1e-8)  # the cost that made the truth
    by_hand = np.abs(model.predict_states(x0[:1], theta[:1], 6)[0, 1:, 0] - truth[0]).mean()
    np.testing.assert_allclose(e[0, 0], by_hand)


def test_error_regression_learns_which_cost_fits_where():
    keys = np.linspace(0, 1, 200)[:, None]
    errors = np.hstack([keys, 1 - keys])  # cost 0 fits small keys, cost 1 large ones
    reg = ErrorRegression(50).fit(keys, errors)
    pred = reg.predict(np.array([[0.1], [0.9]]))
    assert pred.shape == (2, 2) and pred[0].argmin() == 0 and pred[1].argmin() == 1


def test_mixture_weights_reproduce_a_target_inside_the_futures_and_the_nearest_outside():
    futures = np.array([[[0.0, 0.0], [2.0, 4.0], [1.0, 1.0]]] * 2)  # (2 windows, 3 futures, 2 steps)
    target = np.array([[0.5, 1.0], [5.0, 9.0]])  # a quarter of the way to future 1; beyond it
    w = mixture_weights(futures, target)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    assert np.all(w >= 0)
    np.testing.assert_allclose(w[0] @ futures[0], target[0], atol=1e-6)
    np.testing.assert_allclose(w[1], [0.0, 1.0, 0.0], atol=1e-6)  # the hull's nearest point is future 1


def test_future_regression_learns_the_positions_beyond_its_base():
    keys = np.linspace(0, 1, 300)[:, None]
    base = np.zeros((300, 3))
    truth = keys * np.array([1.0, 2.0, 3.0])  # the displacement grows with the key
    reg = FutureRegression(100, 0.1).fit(keys, base, truth)
    pred = reg.predict(np.array([[0.2], [0.8]]), np.ones((2, 3)))
    np.testing.assert_allclose(pred, 1.0 + np.array([[0.2], [0.8]]) * [1.0, 2.0, 3.0], atol=0.05)


@pytest.mark.parametrize("selector", ["forecast", "errors"])
def test_selected_costs_predict_which_kind_of_driver_follows(selector):
    model = synthetic_model()
    rng = np.random.default_rng(1)
    train, test = _two_kinds(model, rng, 30), _two_kinds(model, rng, 8)
    hist = [t.window(2, 10) for t in test]
    truth = np.stack([t.states[11:21, 0] for t in test])
    sel = _learner(model, n_candidates=4, temperature=0.01, selector=selector).fit(train)
    assert 1 <= len(sel.bank_) <= 4
    assert selector == "forecast" or sel.bank_errors_.shape[1] == len(sel.bank_)
    pred = sel.predict_states(hist, 10)
    # the mixture of the bank's futures under the learned probabilities
    states, proba = sel.predict_futures(hist, 10)
    assert states.shape == (8, len(sel.bank_), 11, 2)
    np.testing.assert_allclose(proba.sum(axis=1), 1.0)
    np.testing.assert_allclose(pred, np.einsum("mk,mk...->m...", proba, states))
    x0 = np.stack([h.states[-1] for h in hist])  # each future is a bank cost's own rollout (rolled out once)
    bank = sel._futures(x0, np.broadcast_to(sel.bank_, (8, len(sel.bank_))), 10)
    gap = np.abs(bank[:, :, None] - states[:, None]).max(axis=(-2, -1))  # (window, bank cost, future)
    assert np.all(gap.min(axis=1) < 1e-12) and np.all(gap.min(axis=2) < 1e-12)
    # the weights it reports are the most probable bank cost's: a gentle or a hard one, as the history says
    theta = sel.infer_weights(hist)
    hard = np.array([i % 2 == 0 for i in range(8)])
    assert np.all((theta[:, 0] > 1.0) == hard)
    err_sel = np.abs(pred[:, 1:, 0] - truth).mean()
    avg = PIRLKNN(model=model, window=8, stride=2).fit(train)  # one cost per whole demonstration, k = 1
    err_avg = np.abs(avg.predict_states(hist, 10)[:, 1:, 0] - truth).mean()
    assert err_sel < 0.5 * err_avg + 1e-3, (err_sel, err_avg)
    # K drawn futures, reproducible by seed
    a = sel.predict_futures(hist, 10, n_futures=2, random_state=3)
    b = sel.predict_futures(hist, 10, n_futures=2, random_state=3)
    assert a[0].shape[1] == 2 and np.array_equal(a[1], b[1])


@pytest.mark.parametrize("params, error, match", [
    ({"target": "demo"}, ValueError, "needs target='next'"),
    ({"n_candidates": 0}, ValueError, "n_candidates must be a positive integer"),
    ({"temperature": 0.0}, ValueError, "temperature must be a finite number > 0"),
    ({"temperature": float("nan")}, ValueError, "temperature"),
    ({"temperature": "warm"}, ValueError, "temperature"),
    ({"selector": "oracle"}, ValueError, "selector must be one of .*'oracle'"),
])
def test_bad_selection_parameters_name_the_value(params, error, match):
    model = synthetic_model()
    train = _two_kinds(model, np.random.default_rng(2), 6)
    kw = {"target": "next", **params}
    with pytest.raises(error, match=match):
        PIRLKNN(model=model, window=8, stride=2, target_steps=10, state_features=(0, 1), aggregate="selected",
                **kw).fit(train)


def test_a_bank_larger_than_the_costs_takes_every_cost():
    model = synthetic_model()
    sel = _learner(model, n_candidates=10**6).fit(_two_kinds(model, np.random.default_rng(5), 6))
    np.testing.assert_array_equal(sel.bank_, np.arange(len(sel.demo_theta_)))


def test_saving_a_selected_learner_is_refused_by_name(tmp_path):
    """The bank's error regressions are tree ensembles, which the pickle-free file format does not hold."""
    model = synthetic_model()
    sel = _learner(model, n_candidates=2).fit(_two_kinds(model, np.random.default_rng(4), 6))
    with pytest.raises(TypeError, match="selector_.*FutureRegression"):
        sel.save(tmp_path / "sel.npz")
    assert not (tmp_path / "sel.npz").exists()


def test_future_regression_on_principal_components():
    """n_components: the residuals' mean and leading components, one ensemble per component; on residuals of
    rank 2 two components hold all the variance and predict as one ensemble per step does; as many components
    as steps is the per-step regression itself."""
    rng = np.random.default_rng(0)
    keys = rng.uniform(0, 1, (400, 2))
    steps = np.arange(1, 7)
    truth = keys[:, :1] * steps + np.sin(3 * keys[:, 1:]) * steps**2 / 10  # rank 2 in the steps
    base = rng.normal(0, 1, (400, 6))
    per_step = FutureRegression(100, 0.1).fit(keys, base, truth + base)
    pca = FutureRegression(100, 0.1, n_components=2).fit(keys, base, truth + base)
    assert len(pca.models_) == 2 and len(per_step.models_) == 6
    np.testing.assert_allclose(pca.components_ @ pca.components_.T, np.eye(2), atol=1e-12)
    assert pca.explained_variance_ratio_.sum() > 1 - 1e-12
    query, qbase = rng.uniform(0.1, 0.9, (50, 2)), rng.normal(0, 1, (50, 6))
    want = qbase + query[:, :1] * steps + np.sin(3 * query[:, 1:]) * steps**2 / 10
    for reg in (per_step, pca):  # targets up to ~8 m
        assert np.abs(reg.predict(query, qbase) - want).mean() < 0.1
    assert np.abs(pca.predict(query, qbase) - per_step.predict(query, qbase)).mean() < 0.05
    every = FutureRegression(100, 0.1, n_components=6).fit(keys, base, truth + base)
    np.testing.assert_array_equal(every.predict(query, qbase), per_step.predict(query, qbase))
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match="n_components must be a positive integer or None"):
            FutureRegression(n_components=bad)


def test_a_selection_finished_on_other_trajectories_reads_them():
    """with_aggregate reuses the fit's estimated histories only for the trajectories it was fitted on: others
    with as many windows are read afresh."""
    model = synthetic_model()
    rng = np.random.default_rng(5)
    train = _two_kinds(model, rng, 12)
    futures = _learner(model, n_neighbors=2).set_params(aggregate="futures").fit(train)
    moved = [Trajectory(t.states + 0.25, t.controls, t.dt, t.metadata) for t in train]
    head = {"aggregate": "selected", "n_candidates": 4, "n_neighbors": 3}
    same, other = futures.with_aggregate(train, **head), futures.with_aggregate(moved, **head)
    assert same._next_data is futures._next_data
    samples, _, _, truth = futures._next_pairs(model, moved)
    np.testing.assert_array_equal(other._next_data["truth"], truth)
    np.testing.assert_array_equal(other._next_data["x0"], np.stack([h.states[-1] for h in samples]))
    assert not np.array_equal(other._next_data["x0"], futures._next_data["x0"])


@pytest.mark.parametrize("selector", ["forecast", "errors"])
def test_a_selection_finished_on_another_aggregates_fit_predicts_as_its_own_fit(selector):
    """with_aggregate: the next-steps costs of a futures-averaging fit, finished as a selection, predict exactly as
    a selection fitted from scratch (the replay fits the IRL of PIRL-kNN next and PIRL-select once)."""
    model = synthetic_model()
    rng = np.random.default_rng(4)
    train, test = _two_kinds(model, rng, 12), _two_kinds(model, rng, 4)
    hist = [t.window(2, 10) for t in test]
    head = {"aggregate": "selected", "selector": selector, "n_candidates": 4, "n_neighbors": 3}
    futures = _learner(model, n_neighbors=2).set_params(aggregate="futures").fit(train)
    own = _learner(model, **{k: v for k, v in head.items() if k != "aggregate"}).fit(train)
    derived = futures.with_aggregate(train, **head)
    assert futures.aggregate == "futures" and not hasattr(futures, "bank_")  # the base is not changed
    np.testing.assert_array_equal(derived.bank_, own.bank_)
    np.testing.assert_array_equal(derived.predict_states(hist, 10), own.predict_states(hist, 10))
    back = derived.with_aggregate(train, aggregate="futures", n_neighbors=2)
    np.testing.assert_array_equal(back.predict_states(hist, 10), futures.predict_states(hist, 10))
    assert not hasattr(back, "bank_")
    with pytest.raises(ValueError, match=r"\['window'\] enter the IRL"):
        futures.with_aggregate(train, window=4)
    with pytest.raises(ValueError, match="pass the trajectories this learner was fitted on"):
        futures.with_aggregate(train[:6], aggregate="selected")
    with pytest.raises(ValueError, match="n_candidates must be a positive integer"):
        futures.with_aggregate(train, aggregate="selected", n_candidates=0)
