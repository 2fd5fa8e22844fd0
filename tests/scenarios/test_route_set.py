"""Routes on one arc-length axis (pirl_sim.scenarios.route_set): layout, speed profiles and their derivatives,
projection and positions."""

import numpy as np
import pytest

pytest.importorskip("sumolib")

from pirl_sim.driving import SpeedProfile  # noqa: E402
from pirl_sim.scenarios.drivers import RouteSet, RouteSetProfile  # noqa: E402
from pirl_sim.scenarios.sumo import DEFAULT_NETWORK  # noqa: E402

# route_set: the scenarios' default paths on one axis (a fixture of tests/conftest.py)


def test_route_set_layout(route_set):
    assert route_set.n_routes == 12
    np.testing.assert_allclose(route_set.offsets, 1e4 * np.arange(12))
    r, s = route_set.to_local(route_set.to_global([3, 5], [10.0, -2.0]))
    np.testing.assert_array_equal(r, [3, 5])
    np.testing.assert_allclose(s, [10.0, -2.0])
    assert route_set.path("arm1_to_arm3") is route_set.paths[route_set.index("arm1_to_arm3")]
    with pytest.raises(ValueError, match="unknown route 'arm0_to_arm0'"):
        route_set.index("arm0_to_arm0")


def test_route_set_rejects_bad_input(route_set):
    p = route_set.paths[0]
    with pytest.raises(ValueError, match="unique"):
        RouteSet(("a", "a"), (p, p))
    with pytest.raises(ValueError, match="spacing"):
        RouteSet(("a",), (p,), spacing=100.0)
    with pytest.raises(ValueError, match="2 route ids for 1 paths"):
        RouteSet(("a", "b"), (p,))


def test_profile_on_the_global_axis_equals_each_routes_speed_profile(route_set):
    route_set = RouteSet(route_set.route_ids, route_set.paths)  # speed_smoothing = 0: the paths' own curvature
    profile = RouteSetProfile(route_set)
    rng = np.random.default_rng(0)
    for r, path in enumerate(route_set.paths):
        s = np.concatenate([rng.uniform(-20.0, path.length + 20.0, 300), [0.0, path.length / 2]])
        want = SpeedProfile(path)(s)
        got = profile(route_set.to_global(np.full(len(s), r), s))
        for w, g in zip(want, got):
            np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-9)


def test_speed_smoothing_rounds_the_curvature_peaks_but_keeps_the_ring(route_set):
    raw = RouteSet(route_set.route_ids, route_set.paths)
    r = route_set.index("arm0_to_arm3")
    s = route_set.to_global(np.full(2000, r), np.linspace(0.0, route_set.lengths[r], 2000))
    k_raw, k_smooth = raw.curvature(s)[0], route_set.curvature(s)[0]
    assert np.abs(k_smooth).max() < 0.75 * np.abs(k_raw).max()
    on_ring = np.abs(k_raw - 1.0 / DEFAULT_NETWORK.radius) < 0.002
    assert np.median(k_smooth[on_ring]) == pytest.approx(1.0 / DEFAULT_NETWORK.radius, rel=0.05)
    assert RouteSetProfile(route_set)(s)[0].min() > 6.0  # [m/s] no near-stop dips in the desired speed
    with pytest.raises(ValueError, match="speed_smoothing"):
        RouteSet(route_set.route_ids, route_set.paths, speed_smoothing=-1.0)


def test_profile_derivatives_match_finite_differences(route_set):
    profile = RouteSetProfile(route_set)
    s = route_set.to_global(np.arange(12), np.linspace(20.0, 150.0, 12))
    h = 1e-4
    v, dv, d2v = profile(s)
    np.testing.assert_allclose(dv, (profile(s + h)[0] - profile(s - h)[0]) / (2 * h), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(d2v, (profile(s + h)[1] - profile(s - h)[1]) / (2 * h), rtol=1e-4, atol=1e-6)


def test_project_and_position_agree_with_the_reference_paths(route_set):
    rng = np.random.default_rng(1)
    for r, path in enumerate(route_set.paths):
        s = rng.uniform(0.0, path.length, 40)
        d = rng.uniform(-1.5, 1.5, 40)
        xy = path.to_cartesian(s, d)
        ref = path.to_frenet(xy)[0]
        idx = np.full(40, r)
        np.testing.assert_allclose(route_set.project(idx, xy, ref + rng.uniform(-1, 1, 40)), ref, atol=1e-6)
        np.testing.assert_allclose(route_set.project(idx, xy), ref, atol=1e-6)  # cold: to_frenet first
        s_out = np.concatenate([s, [-3.0, path.length + 4.0]])
        np.testing.assert_allclose(route_set.position(route_set.to_global(np.full(42, r), s_out)),
                                   path.position(s_out, extrapolate=True), atol=1e-9)
