"""Receding-horizon IRL (pirl_sim.receding): exact recovery of re-planning drivers, derivatives, bad input."""

import numpy as np
import pytest

from pirl_sim.driving import roundabout_model
from pirl_sim.learners import PIRLKNN, TIRL
from pirl_sim.metrics import weight_recovery_error
from pirl_sim.model import synthetic_model
from pirl_sim.paths import ReferencePath
from pirl_sim.receding import STEP_MASK, RecedingPolicy, fit_receding, receding_steps
from pirl_sim.scenarios.passage import passage_polyline
from pirl_sim.simulate import simulate_receding_horizon

from replay_scenes import load_sumo_scene


@pytest.fixture(scope="module")
def lq_drivers():
    """20 receding-horizon LQ drivers (point mass, horizon 15), q/r spread over e^-2 .. e^2."""
    rng = np.random.default_rng(0)
    x0 = np.column_stack([rng.uniform(1, 5, 20), rng.uniform(-1, 1, 20)])
    theta = np.column_stack([np.exp(rng.uniform(-2, 2, 20)), np.ones(20)])
    model = synthetic_model()
    trajs = simulate_receding_horizon(model, x0, theta, 40, 15)
    return model, trajs, theta


@pytest.fixture(scope="module")
def path_drivers():
    """Receding-horizon drivers of the roundabout model (bounded MPC, horizon 20) along a passage."""
    path = ReferencePath.from_polyline(passage_polyline(20.0, 40.0, 270.0, 40.0), smoothing=4.0)
    model = roundabout_model(path, dt=0.1)
    x0 = np.array([[2.0, 9.0, 0.0], [5.0, 12.0, 0.5], [0.0, 6.0, -0.5], [8.0, 10.0, 0.0]])
    theta = np.array([[3.0, 0.3, 1.0], [0.1, 3.0, 1.0], [0.3, 0.3, 1.0], [1.0, 1.0, 1.0]])
    trajs = simulate_receding_horizon(model, x0, theta, 60, 20)
    return model, trajs, theta


def test_lq_receding_drivers_recovered_exactly(lq_drivers):
    model, trajs, theta = lq_drivers
    res = fit_receding(model, trajs, horizon=15)
    assert res.converged.all()
    np.testing.assert_allclose(res.normalized, theta, rtol=1e-6)
    assert res.sigma.max() < 1e-6
    # the learners, by parameter: one weight vector per demo, and one for all
    knn = PIRLKNN(model, likelihood="receding", horizon=15).fit(trajs)
    np.testing.assert_allclose(knn.demo_theta_, theta, rtol=1e-6)
    same = [t for t, th in zip(trajs, theta) if th[0] == theta[0, 0]]
    np.testing.assert_allclose(TIRL(model, likelihood="receding", horizon=15).fit(same).theta_, theta[0], rtol=1e-6)


def test_wrong_horizon_does_not_recover_exactly(lq_drivers):
    model, trajs, theta = lq_drivers
    res = fit_receding(model, trajs[:6], horizon=5)
    assert np.max(np.abs(np.log(res.normalized[:, 0] / theta[:6, 0]))) > 1e-3
    assert res.sigma.max() > 1e-4


def test_path_drivers_recovered(path_drivers):
    model, trajs, theta = path_drivers
    res = fit_receding(model, trajs, horizon=20)
    assert res.converged.all()
    np.testing.assert_allclose(res.normalized, theta, rtol=1e-3)


def _fd_jacobian(policy, x0, theta, h=1e-6):
    out = np.empty((x0.shape[0], policy.model.dynamics.n_u, theta.shape[1]))
    for k in range(theta.shape[1]):
        up, down = theta.copy(), theta.copy()
        up[:, k] *= np.exp(h)
        down[:, k] *= np.exp(-h)
        out[:, :, k] = (policy.solve(x0, up).first - policy.solve(x0, down).first) / (2 * h * theta[:, k:k + 1])
    return out


def test_policy_jacobian_matches_finite_differences(path_drivers):
    model, trajs, theta = path_drivers
    policy = RecedingPolicy(model, 20, tol=1e-10)
    x0 = np.stack([t.states[10] for t in trajs])
    sol = policy.solve(x0, theta)
    assert sol.converged.all()
    np.testing.assert_allclose(sol.jac, _fd_jacobian(policy, x0, theta), atol=1e-5 * np.abs(sol.jac).max())


def test_policy_jacobian_with_active_bounds(path_drivers):
    """Starts that brake hard into the acceleration bound: the plan rides the bound, the derivative is the
    one of the equality-constrained problem on the active set."""
    model, _, _ = path_drivers
    policy = RecedingPolicy(model, 20, tol=1e-10)
    x0 = np.array([[60.0, 16.0, -3.5], [62.0, 17.0, -3.9], [55.0, 15.0, 2.9]])
    theta = np.array([[3.0, 0.3, 1.0], [2.0, 0.1, 1.0], [5.0, 0.5, 1.0]])
    sol = policy.solve(x0, theta)
    assert sol.bounded.all() and sol.converged.all()
    np.testing.assert_allclose(sol.jac, _fd_jacobian(policy, x0, theta), atol=1e-4 * np.abs(sol.jac).max())


def test_step_mask_leaves_steps_out(lq_drivers):
    model, trajs, theta = lq_drivers
    mask = np.zeros(trajs[0].n_steps, dtype=bool)
    mask[5:12] = True
    masked = [trajs[0].with_metadata(**{STEP_MASK: mask})]
    steps = receding_steps(masked, 15)
    assert steps.n_steps == 7
    np.testing.assert_array_equal(steps.x, trajs[0].states[5:12])
    # corrupted steps outside the mask do not matter
    bad = trajs[0].controls.copy()
    bad[~mask] += 5.0
    from pirl_sim.trajectory import Trajectory

    corrupted = Trajectory(trajs[0].states, bad, trajs[0].dt, {STEP_MASK: mask})
    res = fit_receding(model, [corrupted], horizon=15)
    np.testing.assert_allclose(res.normalized[0], theta[0], rtol=1e-6)


def test_cauchy_loss_ignores_outlier_steps_gauss_does_not(lq_drivers):
    model, trajs, theta = lq_drivers
    from pirl_sim.trajectory import Trajectory

    t = trajs[1]
    bad = t.controls.copy()
    bad[[3, 17, 30]] += 3.0  # three steps where the driver did something else
    corrupted = Trajectory(t.states, bad, t.dt)
    robust = fit_receding(model, [corrupted], horizon=15, loss="cauchy")
    least = fit_receding(model, [corrupted], horizon=15, loss="gauss")
    err = lambda r: abs(np.log(r.normalized[0, 0] / theta[1, 0]))
    assert err(robust) < 1e-3 < err(least)


def test_control_noise_scale_recovered():
    rng = np.random.default_rng(3)
    model = synthetic_model()
    x0 = np.column_stack([rng.uniform(1, 5, 10), rng.uniform(-1, 1, 10)])
    trajs = simulate_receding_horizon(model, x0, np.array([2.0, 1.0]), 200, 15, rng=rng, control_noise=0.05)
    for loss in ("gauss", "cauchy"):
        res = fit_receding(model, trajs, np.zeros(10, dtype=int), horizon=15, loss=loss)
        assert res.sigma[0] == pytest.approx(0.05, rel=0.1)
        assert abs(np.log(res.normalized[0, 0] / 2.0)) < 0.1


def test_horizon_longer_than_a_track_is_fine(lq_drivers):
    """Each step is a decision whose plan runs past the recorded end, as the driver's did."""
    model, trajs, theta = lq_drivers
    short = [t.window(0, 8) for t in trajs[:3]]
    res = fit_receding(model, short, horizon=15)
    np.testing.assert_allclose(res.normalized, theta[:3], rtol=1e-6)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(horizon=0), "horizon"),
        (dict(horizon=-3), "horizon"),
        (dict(horizon=2.5), "horizon"),
        (dict(horizon=15, stride=0), "stride"),
        (dict(horizon=15, loss="huber"), "loss"),
        (dict(horizon=15, log_bounds=(5.0, -5.0)), "log_bounds"),
        (dict(horizon=15, labels=np.array([0, 1])), "labels"),
    ],
)
def test_bad_arguments_are_clear_errors(lq_drivers, kwargs, match):
    model, trajs, _ = lq_drivers
    with pytest.raises(ValueError, match=match):
        fit_receding(model, trajs[:3], **kwargs)


def test_masks_that_leave_nothing_or_do_not_fit_are_errors(lq_drivers):
    model, trajs, _ = lq_drivers
    none = [t.with_metadata(**{STEP_MASK: np.zeros(t.n_steps, dtype=bool)}) for t in trajs[:2]]
    with pytest.raises(ValueError, match="no usable step"):
        fit_receding(model, none, horizon=15)
    wrong = [trajs[0].with_metadata(**{STEP_MASK: np.ones(3, dtype=bool)})]
    with pytest.raises(ValueError, match="step_mask"):
        fit_receding(model, wrong, horizon=15)


def test_learner_parameters_are_checked(lq_drivers):
    model, trajs, _ = lq_drivers
    with pytest.raises(ValueError, match="horizon"):
        TIRL(model, likelihood="receding").fit(trajs)
    with pytest.raises(ValueError, match="likelihood"):
        TIRL(model, likelihood="closed-loop", horizon=15).fit(trajs)
    with pytest.raises(ValueError, match="step_stride"):
        TIRL(model, likelihood="receding", horizon=15, step_stride=0).fit(trajs)
    with pytest.raises(ValueError, match="prior"):
        PIRLKNN(model, likelihood="receding", horizon=15, prior="population").fit(trajs)


def test_residuals_score_given_weights_on_held_out_tracks(lq_drivers):
    from pirl_sim.receding import cauchy_nll, cauchy_scale, receding_residuals

    model, trajs, theta = lq_drivers
    r_true, owner = receding_residuals(model, trajs[:4], theta[:4], 15)
    assert r_true.shape == (4 * 40, 1) and np.array_equal(np.bincount(owner), [40] * 4)
    assert np.abs(r_true).max() < 1e-8
    r_wrong, _ = receding_residuals(model, trajs[:4], np.array([1.0, 1.0]), 15)
    scale = float(cauchy_scale(0.0, np.concatenate([t.controls for t in trajs[:4]])))
    assert scale > 0 and cauchy_nll(r_true, scale) < cauchy_nll(r_wrong, scale)
    with pytest.raises(ValueError, match="rows"):
        receding_residuals(model, trajs[:4], theta[:3], 15)


def test_receding_fit_on_the_replay_recovers_the_drivers_weights(sumo_recording):
    from pirl_sim.receding import fit_receding

    scene, rec = load_sumo_scene(sumo_recording)
    tracks = scene.selected
    res = fit_receding(scene.model, tracks, horizon=rec.horizon)
    err = weight_recovery_error(res.normalized, np.stack([t.metadata["theta"] for t in tracks]), 2)
    assert np.median(err) < 0.02  # measured 0.003 on this run; 0.0026 on simulate sumo --seed 0
    # positions only and the replay's default desired speed (no speed smoothing): far off
    off, _ = load_sumo_scene(sumo_recording, estimate="positions", speed_smoothing=0.0)
    res_off = fit_receding(off.model, off.selected[:6], horizon=rec.horizon)
    true = np.stack([t.metadata["theta"] for t in off.selected[:6]])
    assert np.median(weight_recovery_error(res_off.normalized, true, 2)) > 5 * np.median(err)


def test_log_standard_errors_from_the_information():
    from pirl_sim.receding import log_standard_errors

    info = np.array([[[4.0, 0.0], [0.0, 0.25]],  # sigma / sqrt(diag): 0.5 / 2 and 0.5 / 0.5
                     [[1.0, 0.0], [0.0, 0.0]],   # the second weight has no information
                     [[1.0, 1.0], [1.0, 1.0]],   # only their sum is informed: both open
                     np.zeros((2, 2))])           # no information at all
    se = log_standard_errors(info, np.array([0.5, 1.0, 1.0, 1.0]))
    np.testing.assert_allclose(se[0], [0.25, 1.0])
    assert se[1, 0] == 1.0 and se[1, 1] == np.inf
    assert np.all(np.isinf(se[2])) and np.all(np.isinf(se[3]))


def test_a_free_weight_leaves_the_error_of_a_determined_one():
    """The uninformed direction leans on the determined weight by 1e-4 (as when a fit left a weight where its
    feature is flat): that weight keeps a finite error near sigma / sqrt(its information); one leaning by 0.1
    does not."""
    from pirl_sim.receding import log_standard_errors

    for lean, finite in ((1e-4, True), (0.1, False)):
        c, s = np.cos(lean), np.sin(lean)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        info = R @ np.diag([4.0, 0.0, 1.0]) @ R.T  # weight 1 free, leaning on weight 0
        se = log_standard_errors(info[None], np.array([1.0]))[0]
        assert np.isinf(se[1]) and se[2] == pytest.approx(1.0)
        assert np.isfinite(se[0]) == finite
        if finite:
            assert se[0] == pytest.approx(0.5, rel=1e-6)


def test_starts_whose_bounded_plans_are_all_infeasible_stay_unconverged(path_drivers, monkeypatch):
    """When no bounded QP of a round can be solved (each infeasible from its start), the policy keeps the plans,
    unconverged, instead of failing on an empty batch."""
    model, _, _ = path_drivers
    policy = RecedingPolicy(model, 20, tol=1e-10)
    x0 = np.array([[60.0, 16.0, -3.5], [62.0, 17.0, -3.9]])  # they brake into the acceleration bound
    theta = np.array([[3.0, 0.3, 1.0], [2.0, 0.1, 1.0]])

    def infeasible(*args, **kwargs):
        raise RuntimeError("infeasible")

    monkeypatch.setattr(policy._qp, "solve", infeasible)
    sol = policy.solve(x0, theta)
    assert not sol.converged.any() and np.isfinite(sol.U).all()
    empty = policy._expand(x0[:0], sol.U[:0], theta[:0])
    assert [a.shape for a in empty] == [(0, 3), (0, 3, 20), (0, 20, 20)]
