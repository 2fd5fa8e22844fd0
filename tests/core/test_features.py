"""Cost features (pirl_sim.features): derivatives against finite differences, names and weights, and windows that
partition the features (a hypothesis property)."""

import numpy as np
import pytest

from pirl_sim.dynamics import longitudinal
from pirl_sim.features import FeatureSet, lqr_features

pytest.importorskip("hypothesis")

from hypothesis import given, settings  # noqa: E402

from pirl_sim.dynamics import point_mass  # noqa: E402
from pirl_sim.testing import trajectories  # noqa: E402

from cost_features import nonquadratic_features  # noqa: E402


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
        dyn, fs = longitudinal(0.2), nonquadratic_features()
    x0 = rng.normal(size=dyn.n_x)
    U = rng.normal(size=(8, dyn.n_u))
    g, g_fd, H, H_fd = _fd_check(fs, dyn, x0, U)
    assert np.max(np.abs(g - g_fd)) <= 1e-5 * max(1.0, np.max(np.abs(g)))
    assert np.max(np.abs(H - H_fd)) <= 1e-5 * max(1.0, np.max(np.abs(H)))


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


@settings(max_examples=40, deadline=None)
@given(trajectories(point_mass(0.1), min_steps=2))
def test_windows_partition_the_features(traj):
    # sum-reduced features are additive over consecutive windows
    fs = lqr_features()
    k = traj.n_steps // 2
    whole = fs.trajectory_values([traj])[0]
    parts = fs.trajectory_values([traj.window(0, k), traj.window(k)])
    np.testing.assert_allclose(parts.sum(axis=0), whole, rtol=1e-9, atol=1e-9)
