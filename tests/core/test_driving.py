"""The roundabout driving model (pirl_sim.driving): desired-speed profiles and path features, sequential MPC,
composite paths, the speed-level and headway features, and state estimation from positions and speeds."""

from dataclasses import replace

import numpy as np
import pytest

from pirl_sim.driving import (
    PathDriverModel,
    SpeedProfile,
    estimate_longitudinal_states,
    fit_longitudinal_states,
    roundabout_features,
    roundabout_model,
    smooth_desired_speed,
)
from pirl_sim.dynamics import longitudinal
from pirl_sim.mpc import Bounds
from pirl_sim.paths import ReferencePath
from pirl_sim.scenarios.passage import passage_polyline
from pirl_sim.scenarios.replay import load_replay

from style_demos import roundabout_passages


@pytest.fixture(scope="module")
def passage():
    return roundabout_passages()


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


DT = 0.1


def _synthetic(n=120, seed=0):
    """A track through the dynamics: smooth jerks, start (0 m, 10 m/s, 0.5 m/s^2)."""
    rng = np.random.default_rng(seed)
    dyn = longitudinal(DT)
    t = DT * np.arange(n - 1)
    U = (0.8 * np.sin(0.7 * t) + 0.3 * np.cos(1.9 * t + rng.uniform(0, 6)))[:, None]
    X = dyn.rollout(np.array([0.0, 10.0, 0.5]), U)
    return dyn, X, U, rng

def test_exact_positions_and_speeds_give_the_states_back():
    dyn, X, U, _ = _synthetic()
    Xe, Ue = estimate_longitudinal_states(X[:, 0], dyn, v_obs=X[:, 1], sigma_s=1e-3, sigma_v=1e-4, sigma_j=10.0)
    assert Xe.shape == X.shape and Ue.shape == U.shape
    np.testing.assert_allclose(Xe, X, atol=2e-3)
    assert np.sqrt(np.mean((Ue - U) ** 2)) < 0.02  # [m/s^3], true jerk RMS ~0.6


def test_noisy_speeds_beat_positions_only_within_stated_bounds():
    dyn, X, U, rng = _synthetic(n=200, seed=1)
    errs = {"positions": [], "speeds": []}
    for _ in range(10):
        s = X[:, 0] + 0.01 * rng.standard_normal(len(X))  # 1 cm
        v = X[:, 1] + 0.005 * rng.standard_normal(len(X))  # 5 mm/s
        _, Up = estimate_longitudinal_states(s, dyn, sigma_s=0.01, sigma_j=0.1)
        _, Uv = estimate_longitudinal_states(s, dyn, v_obs=v, sigma_s=0.01, sigma_v=0.005, sigma_j=0.1)
        errs["positions"].append(np.sqrt(np.mean((Up - U) ** 2)))
        errs["speeds"].append(np.sqrt(np.mean((Uv - U) ** 2)))
    assert np.mean(errs["speeds"]) < 0.6 * np.mean(errs["positions"])
    assert np.mean(errs["speeds"]) < 0.08  # [m/s^3] (measured 0.057; positions only 0.126)


def test_position_only_estimate_equals_fit_longitudinal_states():
    dyn, X, _, rng = _synthetic()
    s = X[:, 0] + 0.05 * rng.standard_normal(len(X))
    Xa, Ua = fit_longitudinal_states(s, dyn, jerk_weight=0.04)
    Xb, Ub = estimate_longitudinal_states(s, dyn, sigma_s=1.0, sigma_j=5.0)
    np.testing.assert_allclose(Xa, Xb, atol=1e-8)
    np.testing.assert_allclose(Ua, Ub, atol=1e-8)


def test_step_mask_fits_each_run_on_its_own_and_anchors_restarts():
    dyn, X, U, _ = _synthetic(n=80)
    X2 = X.copy()  # the driver re-started at frame 40 from another acceleration: dynamics broken there
    U2 = U.copy()
    X2[40:] = dyn.rollout(np.array([X[40, 0], X[40, 1], X[40, 2] - 1.5]), U[40:])
    mask = np.ones(79, dtype=bool)
    mask[39] = False
    a_obs = np.full(80, np.nan)
    a_obs[40] = X2[40, 2]
    Xe, Ue = estimate_longitudinal_states(X2[:, 0], dyn, v_obs=X2[:, 1], sigma_s=1e-3, sigma_v=1e-4, sigma_j=10.0,
                                          step_mask=mask, a_obs=a_obs)
    ok = mask
    assert np.abs(Ue[ok] - U2[ok]).max() < 0.05
    np.testing.assert_allclose(Xe[:, 2], X2[:, 2], atol=5e-3)
    # fitted through the break, the jerks near it are far off
    _, Ubad = estimate_longitudinal_states(X2[:, 0], dyn, v_obs=X2[:, 1], sigma_s=1e-3, sigma_v=1e-4, sigma_j=10.0)
    assert np.abs(Ubad[ok] - U2[ok]).max() > 1.0


@pytest.mark.parametrize("kwargs, match", [
    ({"s_obs": np.array([0.0, np.nan, 2.0])}, r"s_obs contains non-finite values \(nan at index 1\)"),
    ({"s_obs": np.zeros((3, 2))}, r"s_obs must be a 1-D array"),
    ({"s_obs": np.array([1.0])}, r"s_obs must be a 1-D array of at least 2"),
    ({"v_obs": np.ones(4)}, r"v_obs must have one speed per position: got 4 speeds for 3 positions"),
    ({"v_obs": np.array([1.0, np.inf, 1.0])}, r"v_obs contains non-finite values"),
    ({"sigma_s": 0.0}, r"sigma_s must be a finite number > 0, got 0.0"),
    ({"sigma_v": -1.0}, r"sigma_v must be a finite number > 0"),
    ({"sigma_j": float("nan")}, r"sigma_j must be a finite number > 0"),
    ({"sigma_a": True}, r"sigma_a must be a finite number > 0"),
    ({"a_obs": np.array([np.inf, np.nan, np.nan])}, r"a_obs contains infinite values"),
    ({"a_obs": np.zeros(2)}, r"a_obs must have one value"),
    ({"step_mask": np.ones(3, dtype=bool)}, r"step_mask must be a boolean array of shape \(2,\)"),
    ({"step_mask": np.ones(2)}, r"step_mask must be a boolean array"),
])
def test_bad_input_raises(kwargs, match):
    args = {"s_obs": np.array([0.0, 1.0, 2.0]), **kwargs}
    s = args.pop("s_obs")
    with pytest.raises(ValueError, match=match):
        estimate_longitudinal_states(s, longitudinal(DT), **args)


def test_speed_level_features_blend_the_desired_speed_with_the_drivers_level():
    path = ReferencePath.from_polyline(np.column_stack([np.linspace(0, 400, 81), np.zeros(81)]))
    feats = roundabout_features(SpeedProfile(path, 1.8, 10.0), "speed-level")
    assert feats.names == ("speed_dev", "acc_sq", "jerk_sq", "speed_sq", "speed_hi")
    model = PathDriverModel(longitudinal(0.2), feats, None, path=path)
    x0 = np.array([[0.0, 8.0, 0.0]])
    # preferred speed (w v_des + w_hi v_hi) / (w + w_0 + w_hi): 10 / 2 = 5 and (10 + 20) / 2 = 15 m/s
    for theta, v_pref in (([1.0, 0.1, 0.1, 1.0, 1e-9], 5.0), ([1.0, 0.1, 0.1, 1e-9, 1.0], 15.0)):
        states = model.predict_states(x0, np.array([theta]), 150)[0]
        assert abs(states[100, 1] - v_pref) < 0.1
    vals = feats.values(np.array([[[0, 8, 1.0], [1, 9, 2.0]]]), np.array([[[3.0]]]))
    np.testing.assert_allclose(vals[0, 3:], [81.0, 121.0])
    with pytest.raises(ValueError, match="feature set"):
        roundabout_features(SpeedProfile(path), "lateral")
    with pytest.raises(ValueError, match="features"):
        load_replay([], "nowhere.osm", features="all")


def test_headway_feature_derivatives_and_a_car_stopping_behind_a_standing_obstacle():
    from pirl_sim.driving import HeadwayResidual
    from pirl_sim.dynamics import following

    res = HeadwayResidual()
    x = np.array([[[0.0, 6.0, 0.5, 4.0, 2.0], [1.0, 7.0, 0.0, 80.0, 7.0]]])
    out = res(x, np.zeros((1, 2, 1)))
    eps = 1e-6
    for i in (1, 3):
        dx = np.zeros(5)
        dx[i] = eps
        fd = (res(x + dx, np.zeros((1, 2, 1))).r - res(x - dx, np.zeros((1, 2, 1))).r)[..., 0] / (2 * eps)
        np.testing.assert_allclose(out.jac_x[..., 0, i], fd, rtol=1e-6, atol=1e-9)
        fd2 = (res(x + dx, np.zeros((1, 2, 1))).jac_x - res(x - dx, np.zeros((1, 2, 1))).jac_x)[..., 0, :] / (2 * eps)
        np.testing.assert_allclose(out.second_x()[..., 0, i, :], fd2, rtol=1e-5, atol=1e-8)
    assert out.r[0, 0, 0] > 3.9 and out.r[0, 1, 0] < 1e-20  # 2 + 6 - 4 below the safe gap; far ahead: none
    path = ReferencePath.from_polyline(np.column_stack([np.linspace(0, 400, 81), np.zeros(81)]))
    model = PathDriverModel(following(0.2), roundabout_features(SpeedProfile(path, 1.8, 10.0), "following"),
                            None, path=path)
    x0 = np.array([[0.0, 8.0, 0.0, 40.0, 0.0]])  # a standing obstacle 40 m ahead
    free, blocked = (model.predict_states(x0, np.array([[1.0, 1.0, 1.0, 1e-3, 1e-3, w]]), 60)[0]
                     for w in (1e-6, 100.0))
    assert free[-1, 0] > 100.0  # no care for the gap: drives through it
    assert blocked[-1, 0] < 40.0 and blocked[-1, 1] < 1.0  # stops short of it
    with pytest.raises(ValueError, match="following"):
        res(np.zeros((1, 2, 3)), np.zeros((1, 2, 1)))
    with pytest.raises(ValueError, match="softness"):
        HeadwayResidual(softness=0.0)


def test_composite_path_keeps_points_before_a_path_on_that_path():
    from pirl_sim.driving import CompositePath
    from pirl_sim.paths import ReferencePath

    x = np.linspace(0.0, 100.0, 11)
    a = ReferencePath.from_polyline(np.column_stack([x, np.zeros_like(x)]))
    b = ReferencePath.from_polyline(np.column_stack([x, np.full_like(x, 50.0)]))
    comp = CompositePath((a, b), gap=300.0)
    off = comp.offsets[1]
    s = np.array([off - 20.0, off - 149.0, a.length + 20.0, a.length + 149.0, -5.0, off + b.length + 400.0])
    np.testing.assert_array_equal(comp.segment_of(s), [1, 1, 0, 0, 0, 1])
    xy = comp.to_cartesian(s, np.zeros_like(s))
    expected = [[-20.0, 50.0], [-149.0, 50.0], [120.0, 0.0], [249.0, 0.0], [-5.0, 0.0], [500.0, 50.0]]
    np.testing.assert_allclose(xy, expected, atol=1e-6)  # each extrapolated straight from its own path
    # an explicit segment wins over the arc length
    np.testing.assert_allclose(comp.to_cartesian(off - 200.0, 0.0, segment=1), [-200.0, 50.0], atol=1e-6)
    assert comp.local_range(0) == (-np.inf, a.length + 150.0) and comp.local_range(1) == (-150.0, np.inf)
    with pytest.raises(ValueError, match="segment must be integer path indices"):
        comp.to_cartesian(0.0, 0.0, segment=2)
