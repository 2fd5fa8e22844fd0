"""Tests of `pirl_sim.paths.ReferencePath` against lines and circles of known curvature."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from pirl_sim.paths import ReferencePath, desired_speed_from_curvature

A_LAT, V_MAX = 1.8, 13.9
NOISE = 0.1  # [m] positional noise, Gaussian, per coordinate
STEP = 2.0  # [m] vertex spacing of the synthetic centerlines


def circle_points(radius, *, sweep=2 * np.pi, clockwise=False, noise=0.0, seed=0, closed=True):
    """Vertices every ~STEP m on a circle about the origin, counter-clockwise unless ``clockwise``."""
    n = int(round(radius * sweep / STEP))
    theta = np.linspace(0.0, sweep, n, endpoint=not closed)
    if clockwise:
        theta = -theta
    pts = radius * np.column_stack([np.cos(theta), np.sin(theta)])
    return pts + noise * np.random.default_rng(seed).standard_normal(pts.shape)


def interior(path, margin=5.0):
    """Curvature table without ``margin`` m at each end of an open path (all of it for a closed one)."""
    if path.closed:
        return path.kappa
    keep = (path.s > margin) & (path.s < path.length - margin)
    return path.kappa[keep]


# ---------------------------------------------------------------------------------------- curvature


@pytest.mark.parametrize("closed", [True, False])
@pytest.mark.parametrize("radius", [20.0, 23.6])
def test_noisy_circle_curvature_within_15_percent(radius, closed):
    sweep = 2 * np.pi if closed else 1.8 * np.pi
    pts = circle_points(radius, sweep=sweep, noise=NOISE, seed=1, closed=closed)
    path = ReferencePath.from_polyline(pts, closed=closed)
    lo, hi = np.percentile(interior(path), [5, 95])
    assert 0.85 / radius <= lo <= hi <= 1.15 / radius, (lo * radius, hi * radius)


def test_raw_finite_differences_are_useless_but_smoothing_fixes_them():
    """The motivating failure: vertex finite differences scatter far beyond +-15 % of 1/R."""
    radius = 23.6
    pts = circle_points(radius, noise=NOISE, seed=2)
    d1 = np.gradient(pts, axis=0)
    d2 = np.gradient(d1, axis=0)
    raw = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.hypot(*d1.T) ** 3
    raw_lo, raw_hi = np.percentile(raw, [5, 95])
    assert raw_hi - raw_lo > 0.6 / radius  # twice the +-15 % band the smoothed curvature must meet
    lo, hi = np.percentile(ReferencePath.from_polyline(pts, closed=True).kappa, [5, 95])
    assert 0.85 / radius <= lo <= hi <= 1.15 / radius


@pytest.mark.parametrize("closed", [True, False])
def test_clockwise_circle_has_negative_curvature(closed):
    radius = 20.0
    sweep = 2 * np.pi if closed else 1.5 * np.pi
    pts = circle_points(radius, sweep=sweep, clockwise=True, noise=NOISE, seed=3, closed=closed)
    path = ReferencePath.from_polyline(pts, closed=closed)
    lo, hi = np.percentile(interior(path), [5, 95])
    assert -1.15 / radius <= lo <= hi <= -0.85 / radius
    assert np.all(np.diff(path.heading) < 0)  # turning right all the way


@pytest.mark.parametrize("closed", [True, False])
@pytest.mark.parametrize("radius", [20.0, 23.6])
def test_noise_free_circle_within_1_percent(radius, closed):
    sweep = 2 * np.pi if closed else 1.5 * np.pi
    path = ReferencePath.from_polyline(circle_points(radius, sweep=sweep, closed=closed), closed=closed)
    np.testing.assert_allclose(interior(path), 1.0 / radius, rtol=0.01)
    np.testing.assert_allclose(np.hypot(path.x, path.y), radius, rtol=0.01)
    if closed:
        np.testing.assert_allclose(path.length, 2 * np.pi * radius, rtol=0.005)
        np.testing.assert_allclose(path.heading[-1] - path.heading[0], 2 * np.pi, atol=1e-12)


def test_noisy_straight_line_has_no_curvature_and_full_speed():
    rng = np.random.default_rng(4)
    x = np.arange(0.0, 100.0 + STEP / 2, STEP)
    pts = np.column_stack([x, 0.3 * x]) + NOISE * rng.standard_normal((x.size, 2))
    path = ReferencePath.from_polyline(pts)
    assert np.percentile(np.abs(interior(path)), 95) < 0.005
    # the last few metres of an open end see one-sided data and are noisier (std ~0.006 1/m here)
    core = (path.s > 10.0) & (path.s < path.length - 10.0)
    assert np.max(np.abs(path.kappa[core])) < 0.005
    np.testing.assert_array_equal(path.desired_speed(path.s[core], A_LAT, V_MAX), V_MAX)
    np.testing.assert_allclose(path.heading[core], np.arctan(0.3), atol=0.02)


def test_quarter_circle_length():
    radius = 20.0
    path = ReferencePath.from_polyline(circle_points(radius, sweep=np.pi / 2, closed=False))
    np.testing.assert_allclose(path.length, np.pi * radius / 2, rtol=0.005)
    np.testing.assert_allclose(np.diff(path.s), path.length / (len(path.s) - 1))
    assert np.max(np.diff(path.s)) <= 0.5


def test_exact_line_is_reproduced():
    path = ReferencePath.from_polyline([[0.0, 0.0], [7.0, 0.0], [20.0, 0.0]], spacing=1.0)
    np.testing.assert_allclose(path.length, 20.0, rtol=1e-9)
    np.testing.assert_allclose(path.s, np.arange(21.0), atol=1e-9)
    np.testing.assert_allclose(path.y, 0.0, atol=1e-9)
    np.testing.assert_allclose(path.kappa, 0.0, atol=1e-9)


def test_duplicates_and_closing_point_are_dropped():
    pts = circle_points(20.0)
    doubled = np.repeat(pts, 2, axis=0)
    a = ReferencePath.from_polyline(pts, closed=True)
    b = ReferencePath.from_polyline(np.vstack([doubled, pts[:1]]), closed=True)
    np.testing.assert_allclose(b.kappa, a.kappa, atol=1e-9)
    np.testing.assert_allclose(b.length, a.length, atol=1e-9)


# ---------------------------------------------------------------------------------------- queries


def test_queries_are_vectorised_and_interpolate_the_table():
    path = ReferencePath.from_polyline(circle_points(20.0, sweep=np.pi, closed=False))
    s = np.linspace(0.0, path.length, 12).reshape(3, 4)
    assert path.position(s).shape == (3, 4, 2)
    assert path.heading_at(s).shape == (3, 4)
    assert path.curvature(s).shape == (3, 4)
    assert path.desired_speed(s).shape == (3, 4)
    np.testing.assert_allclose(path.position(path.s), np.column_stack([path.x, path.y]))
    mid = 0.5 * (path.s[3] + path.s[4])
    np.testing.assert_allclose(path.curvature(mid), 0.5 * (path.kappa[3] + path.kappa[4]))
    assert isinstance(path.length, float)
    with pytest.raises(ValueError, match="read-only"):
        path.kappa[0] = 1.0


def test_out_of_range_raises_unless_extrapolating():
    path = ReferencePath.from_polyline([[0.0, 0.0], [10.0, 0.0]], spacing=0.5)
    with pytest.raises(ValueError, match=r"s = -1\.0 m is outside the path \[0, 10"):
        path.position(-1.0)
    with pytest.raises(ValueError, match=r"s = 11\.0 m is outside"):
        path.curvature(np.array([5.0, 11.0]))
    np.testing.assert_allclose(path.position([-1.0, 12.0], extrapolate=True), [[-1.0, 0.0], [12.0, 0.0]], atol=1e-9)
    np.testing.assert_array_equal(path.curvature([-1.0, 12.0], extrapolate=True), 0.0)
    np.testing.assert_array_equal(path.desired_speed([-1.0, 12.0], extrapolate=True), V_MAX)


def test_extrapolation_follows_end_heading():
    path = ReferencePath.from_polyline(circle_points(20.0, sweep=np.pi / 2, closed=False))
    h_end = path.heading[-1]
    p = path.position(path.length + 3.0, extrapolate=True)
    np.testing.assert_allclose(p, [path.x[-1] + 3 * np.cos(h_end), path.y[-1] + 3 * np.sin(h_end)])
    assert path.heading_at(path.length + 3.0, extrapolate=True) == h_end


def test_closed_path_wraps_arc_length():
    path = ReferencePath.from_polyline(circle_points(20.0, noise=NOISE, seed=5), closed=True)
    s = np.array([0.0, 3.3, 50.0])
    np.testing.assert_allclose(path.position(s + path.length), path.position(s), atol=1e-12)
    np.testing.assert_allclose(path.position(s - 2 * path.length), path.position(s), atol=1e-9)
    np.testing.assert_allclose(path.curvature(s + path.length), path.curvature(s), atol=1e-12)


# ---------------------------------------------------------------------------------------- Frenet


def test_frenet_known_point_on_a_line():
    path = ReferencePath.from_polyline([[0.0, 0.0], [20.0, 0.0]])
    s, d = path.to_frenet([5.0, 2.0])
    assert s.shape == () and d.shape == ()
    np.testing.assert_allclose([s, d], [5.0, 2.0], atol=1e-9)
    s, d = path.to_frenet([[5.0, 2.0], [12.5, -3.0]])
    np.testing.assert_allclose(s, [5.0, 12.5], atol=1e-9)
    np.testing.assert_allclose(d, [2.0, -3.0], atol=1e-9)
    np.testing.assert_allclose(path.to_cartesian(5.0, 2.0), [5.0, 2.0], atol=1e-9)


def test_frenet_left_is_positive_on_a_ring():
    radius = 20.0
    path = ReferencePath.from_polyline(circle_points(radius), closed=True)
    _, d = path.to_frenet([[0.0, 10.0], [0.0, 25.0]])  # inside a counter-clockwise ring is on the left
    np.testing.assert_allclose(d, [radius - 10.0, -5.0], rtol=0.01)


@pytest.mark.parametrize("closed", [True, False])
def test_frenet_round_trip(closed):
    rng = np.random.default_rng(6)
    if closed:
        path = ReferencePath.from_polyline(circle_points(23.6, noise=NOISE, seed=7), closed=True)
    else:  # an S: left arc then right arc, noisy
        t = np.linspace(0.0, np.pi / 2, 20)
        left = 20.0 * np.column_stack([np.sin(t), 1.0 - np.cos(t)])
        right = left[-1] + 20.0 * np.column_stack([1.0 - np.cos(t[1:]), np.sin(t[1:])])
        pts = np.vstack([left, right])
        path = ReferencePath.from_polyline(pts + NOISE * rng.standard_normal(pts.shape))
    d_max = 0.5 / np.max(np.abs(path.kappa))
    s0 = rng.uniform(2.0, path.length - 2.0, size=500)
    d0 = rng.uniform(-d_max, d_max, size=500)
    p = path.to_cartesian(s0, d0)
    s, d = path.to_frenet(p)
    np.testing.assert_allclose(path.to_cartesian(s, d), p, atol=1e-6)
    np.testing.assert_allclose(s, s0, atol=1e-6)
    np.testing.assert_allclose(d, d0, atol=1e-6)
    # arbitrary points near the path, any batch shape
    q = p.reshape(25, 20, 2) + rng.uniform(-1.0, 1.0, size=(25, 20, 2))
    s, d = path.to_frenet(q)
    assert s.shape == d.shape == (25, 20)
    np.testing.assert_allclose(path.to_cartesian(s, d), q, atol=1e-6)


def test_frenet_beyond_the_end():
    path = ReferencePath.from_polyline([[0.0, 0.0], [10.0, 0.0]])
    with pytest.raises(ValueError, match=r"projects to s = 12 m, outside the path \[0, 10"):
        path.to_frenet([12.0, 1.0])
    s, d = path.to_frenet([12.0, 1.0], extrapolate=True)
    np.testing.assert_allclose([s, d], [12.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(path.to_cartesian(s, d, extrapolate=True), [12.0, 1.0], atol=1e-9)


# ---------------------------------------------------------------------------------------- desired speed


def test_desired_speed_at_zero_curvature_has_no_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        v, dv = desired_speed_from_curvature(np.array([0.0, -0.0, 1e-300]), np.array([1.0, -2.0, 3.0]))
        np.testing.assert_array_equal(v, V_MAX)
        np.testing.assert_array_equal(dv, 0.0)
        path = ReferencePath.from_polyline([[0.0, 0.0], [30.0, 0.0]])
        path = ReferencePath(path.s, path.x, path.y, path.heading, np.zeros_like(path.s))
        v, dv = path.desired_speed_and_slope(path.s, A_LAT, V_MAX)
        np.testing.assert_array_equal(v, V_MAX)
        np.testing.assert_array_equal(dv, 0.0)


def test_desired_speed_values():
    v, _ = desired_speed_from_curvature([0.05, -0.05, 0.001], a_lat=1.8, v_max=13.9)
    np.testing.assert_allclose(v, [6.0, 6.0, 13.9])
    path = ReferencePath.from_polyline(circle_points(20.0), closed=True)
    np.testing.assert_allclose(path.desired_speed(path.s, a_lat=2.0), np.sqrt(2.0 * 20.0), rtol=0.01)


def test_desired_speed_slope_matches_finite_differences():
    # an ellipse: curvature varies smoothly between 15/30^2 and 30/15^2, partly above and below the cap
    t = np.linspace(0.0, 2 * np.pi, 120, endpoint=False)
    path = ReferencePath.from_polyline(np.column_stack([30 * np.cos(t), 15 * np.sin(t)]), closed=True)
    a_lat, v_max = 1.8, 8.0  # cap active where |kappa| < 1.8 / 64 = 0.028
    cap = a_lat / v_max**2
    ds = np.diff(path.s)
    s = path.s[:-1] + 0.37 * ds  # inside segments: the interpolation is smooth there
    k0, k1 = path.kappa[:-1], path.kappa[1:]
    away = (np.minimum(np.abs(k0), np.abs(k1)) > 1.05 * cap) | (np.maximum(np.abs(k0), np.abs(k1)) < 0.95 * cap)
    assert away.sum() > 50 and np.any(np.abs(k0[away]) > cap) and np.any(np.abs(k0[away]) < cap)
    s = s[away]
    h = 1e-4 * ds[away]
    v, dv = path.desired_speed_and_slope(s, a_lat, v_max)
    fd = (path.desired_speed(s + h, a_lat, v_max) - path.desired_speed(s - h, a_lat, v_max)) / (2 * h)
    np.testing.assert_allclose(dv, fd, rtol=1e-6, atol=1e-9)
    assert np.any(np.abs(dv) > 1e-3)
    np.testing.assert_array_equal(dv[np.abs(path.curvature(s)) < cap], 0.0)


# ---------------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "points, kwargs, error, match",
    [
        ([[0.0, 0.0], [0.0, 0.0]], {}, ValueError, "at least 2 distinct points, got 1"),
        ([[0.0, 0.0]], {}, ValueError, "at least 2 distinct points"),
        ([[0.0, 0.0], [np.nan, 1.0], [2.0, 2.0]], {}, ValueError, r"finite, found nan at index \(1, 0\)"),
        ([[0.0, 0.0], [1.0, np.inf]], {}, ValueError, "points must be finite, found inf"),
        ([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], {}, ValueError, r"shape \(P, 2\), got shape \(2, 3\)"),
        ([0.0, 1.0, 2.0], {}, ValueError, r"shape \(P, 2\), got shape \(3,\)"),
        ([["a", "b"], ["c", "d"]], {}, TypeError, "points must be a numeric array"),
        ([[0.0, 0.0], [10.0, 0.0]], {"spacing": 0.0}, ValueError, "spacing must be finite and > 0, got 0.0"),
        ([[0.0, 0.0], [10.0, 0.0]], {"spacing": -1.0}, ValueError, "spacing must be finite and > 0"),
        ([[0.0, 0.0], [10.0, 0.0]], {"spacing": np.nan}, ValueError, "spacing must be finite"),
        ([[0.0, 0.0], [10.0, 0.0]], {"spacing": "1"}, TypeError, "spacing must be a number"),
        ([[0.0, 0.0], [10.0, 0.0]], {"smoothing": -1.0}, ValueError, "smoothing must be finite and >= 0"),
        ([[0.0, 0.0], [0.3, 0.0]], {"spacing": 0.5}, ValueError, "0.3 m long, shorter than spacing = 0.5 m"),
        ([[0.0, 0.0], [10.0, 0.0]], {"closed": "yes"}, TypeError, "closed must be a bool"),
        ([[0.0, 0.0], [10.0, 0.0], [0.0, 0.0]], {"closed": True}, ValueError, "at least 3 distinct points, got 2"),
        ([[0.0, 0.0], [10.0, 0.0], [0.0, 0.0]], {}, ValueError, "smoothing = 4.0 m folds this polyline back"),
    ],
)
def test_from_polyline_rejects_bad_input(points, kwargs, error, match):
    with pytest.raises(error, match=match):
        ReferencePath.from_polyline(points, **kwargs)


def _table(**changes):
    s = np.arange(5.0)
    fields = dict(s=s, x=s.copy(), y=np.zeros(5), heading=np.zeros(5), kappa=np.zeros(5))
    fields.update(changes)
    return fields


@pytest.mark.parametrize(
    "fields, match",
    [
        (_table(s=np.arange(1.0, 6.0)), r"s must start at 0, got s\[0\] = 1.0"),
        (_table(s=np.array([0.0, 1.0, 1.0, 2.0, 3.0])), r"strictly increasing, got s\[1\] = 1.0 >= s\[2\] = 1.0"),
        (_table(kappa=np.zeros(4)), "kappa has 4 entries, s has 5"),
        (_table(x=np.zeros((5, 1))), r"x must be one-dimensional, got shape \(5, 1\)"),
        (_table(heading=np.array([0.0, 0.0, np.nan, 0.0, 0.0])), r"heading must be finite, found nan at index \(2,\)"),
        (dict(s=[0.0], x=[0.0], y=[0.0], heading=[0.0], kappa=[0.0]), "at least 2 table rows, got 1"),
        (_table(closed=True), "closed path must end where it starts"),
    ],
)
def test_constructor_rejects_bad_tables(fields, match):
    with pytest.raises(ValueError, match=match):
        ReferencePath(**fields)


def test_queries_reject_bad_input():
    path = ReferencePath(**_table())
    with pytest.raises(ValueError, match="s must be finite, found nan"):
        path.position(np.nan)
    with pytest.raises(ValueError, match=r"xy must have shape \(\.\.\., 2\), got shape \(3,\)"):
        path.to_frenet([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="xy must be finite"):
        path.to_frenet([np.inf, 0.0])
    with pytest.raises(ValueError, match="d must be finite"):
        path.to_cartesian(1.0, np.nan)
    with pytest.raises(ValueError, match="a_lat must be finite and > 0, got 0.0"):
        path.desired_speed(1.0, a_lat=0.0)
    with pytest.raises(ValueError, match="v_max must be finite and > 0, got -1.0"):
        path.desired_speed(1.0, v_max=-1.0)
    with pytest.raises(TypeError, match="s must be a numeric array"):
        path.curvature("middle")
    with pytest.raises(ValueError, match="max_iter must be a positive integer, got 0"):
        path.to_frenet([1.0, 1.0], max_iter=0)


def _once_around() -> ReferencePath:
    """A route that enters a circle of radius 20 m, drives once around it and a quarter more, and leaves: it
    passes the quarter from (0, -20) to (20, 0) twice."""
    t = np.linspace(-np.pi / 2, 2 * np.pi, 300)
    lead = np.column_stack([np.zeros(20), np.linspace(-60.0, -21.0, 20)])
    tail = np.column_stack([np.linspace(21.0, 60.0, 20), np.zeros(20)])
    return ReferencePath.from_polyline(np.vstack([lead, np.column_stack([20 * np.cos(t), 20 * np.sin(t)]), tail]))


@pytest.mark.parametrize("offset", [0.5, -3.0])
def test_frenet_of_a_track_follows_a_route_that_passes_a_place_twice(offset):
    """Projected point by point, a vehicle on the quarter driven twice lands on whichever pass is nearer: its arc
    length jumps by a lap (~125 m) back and forth. As a track, every point stays on its own pass."""
    path = _once_around()
    s_true = np.linspace(5.0, path.length - 5.0, 600)
    xy = path.to_cartesian(s_true, np.full_like(s_true, offset))
    s_each, _ = path.to_frenet(xy, extrapolate=True)
    assert np.abs(s_each - s_true).max() > 100.0
    s, d = path.to_frenet(xy, extrapolate=True, track=True)
    np.testing.assert_allclose(s, s_true, atol=1e-9)
    np.testing.assert_allclose(d, offset, atol=1e-9)
    with pytest.raises(ValueError, match=r"track=True needs xy of shape \(n, 2\)"):
        path.to_frenet(xy.reshape(30, 20, 2), track=True)


def test_frenet_of_a_track_on_a_closed_path_wraps():
    th = np.linspace(0.0, 2 * np.pi, 100, endpoint=False)
    ring = ReferencePath.from_polyline(np.column_stack([20 * np.cos(th), 20 * np.sin(th)]), closed=True)
    s_true = np.linspace(0.0, 3 * ring.length, 900) % ring.length
    s, d = ring.to_frenet(ring.to_cartesian(s_true, np.ones_like(s_true)), track=True)
    gap = np.abs((s - s_true + 0.5 * ring.length) % ring.length - 0.5 * ring.length)
    assert gap.max() < 1e-9 and np.abs(d - 1.0).max() < 1e-9
