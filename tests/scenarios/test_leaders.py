"""The vehicle ahead at one instant (pirl_sim.scenarios.leaders): who counts, bumper gaps, the capped obstacle."""

import numpy as np
import pytest

from pirl_sim.scenarios.leaders import NO_LEADER_GAP, frame_leaders, obstacle


def test_the_nearest_car_ahead_in_lane_counts_bumper_to_bumper():
    #          ego        ahead 20 m   ahead 40 m   beside 3 m   behind    oncoming 10 m
    xy = np.array([[0, 0], [20, 0], [40, 0], [10, 3.0], [-15, 0], [10, 0.5]], dtype=float)
    psi = np.array([0, 0, 0, 0, 0, np.pi])
    speed = np.array([10.0, 8.0, 9.0, 7.0, 11.0, 6.0])
    length = np.array([5.0, 4.0, 5.0, 5.0, 5.0, 5.0])
    gap, v = frame_leaders(xy, psi, speed, length)
    assert gap[0] == pytest.approx(20.0 - 2.5 - 2.0) and v[0] == 8.0  # not the car beside, not the oncoming one
    assert gap[1] == pytest.approx(20.0 - 2.0 - 2.5) and v[1] == 9.0
    assert np.isinf(gap[2]) and np.isnan(v[2])  # nobody ahead of the first car
    assert gap[4] == pytest.approx(15.0 - 5.0) and v[4] == 10.0
    centre, _ = frame_leaders(xy, psi, speed)
    assert centre[0] == pytest.approx(20.0)


def test_a_car_within_the_heading_cone_on_a_curve_counts():
    xy = np.array([[0.0, 0.0], [10.0, 1.5]])
    gap, _ = frame_leaders(xy, np.array([0.0, 0.6]), np.array([5.0, 5.0]), np.array([4.0, 4.0]))
    assert gap[0] == pytest.approx(np.hypot(10.0, 1.5) - 4.0)
    gap, _ = frame_leaders(xy, np.array([0.0, 0.6]), np.array([5.0, 5.0]), max_lateral=1.0)
    assert np.isinf(gap[0])  # 1.5 m beside the heading line


def test_one_or_no_vehicle_has_no_leader():
    for n in (0, 1):
        gap, v = frame_leaders(np.zeros((n, 2)), np.zeros(n), np.zeros(n))
        assert gap.shape == (n,) and np.all(np.isinf(gap)) and np.all(np.isnan(v))


def test_obstacle_caps_the_gap_and_holds_it_without_a_leader():
    g, v = obstacle(np.array([12.0, np.inf, 250.0]), np.array([4.0, np.nan, 9.0]), np.array([10.0, 11.0, 12.0]))
    np.testing.assert_array_equal(g, [12.0, NO_LEADER_GAP, NO_LEADER_GAP])
    np.testing.assert_array_equal(v, [4.0, 11.0, 12.0])
