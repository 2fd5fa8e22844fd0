"""Yielding at conflict points (scenarios/conflicts.py)."""

import numpy as np
import pytest

from pirl_sim.paths import ReferencePath
from pirl_sim.scenarios.conflicts import ConflictRule, TrackMotion, yield_gaps


def _straight(start, end):
    pts = np.linspace(start, end, 41)
    return ReferencePath.from_polyline(pts, smoothing=0.0)


NORTH = _straight((0.0, -60.0), (0.0, 60.0))  # the ego's path: x = 0, northwards
EAST = _straight((-60.0, 0.0), (60.0, 0.0))  # crossing at the origin, eastwards (from the ego's left)
WEST = _straight((60.0, 0.0), (-60.0, 0.0))  # crossing from the ego's right


def _car(path, xy, v, psi):
    s = float(path.to_frenet(np.array([xy]), extrapolate=True)[0][0])
    return TrackMotion(np.array([7]), np.array([s]), np.array([v]), np.array([xy], dtype=float), np.array([psi]), path)


def test_a_car_yields_to_traffic_from_its_left_and_stops_short_of_the_conflict():
    ego = _car(NORTH, (0.0, -20.0), 5.0, np.pi / 2)
    other = _car(EAST, (-15.0, 0.0), 8.0, 0.0)  # at the crossing after ~1.9 s; the ego after ~4 s
    gaps = yield_gaps([ego, other], ConflictRule(obstacle="stop"))
    assert 15.0 <= gaps[0][0][0] <= 17.5  # ~19 m to where the paths come within 1.5 m, less the 3 m margin
    assert gaps[0][1][0] == 0.0
    assert np.isinf(gaps[1][0][0])  # the other car has the ego on its right: it goes
    # merge: the other car as a virtual vehicle ahead, at the conflict when it gets there, then at its speed
    (gap, speed), _ = yield_gaps([ego, other])
    assert speed[0] == 8.0
    assert gap[0] == pytest.approx(gaps[0][0][0] - 8.0 * 1.8, abs=1.7)  # ~1.8 s at 8 m/s to the crossing


@pytest.mark.parametrize("ego_at, ego_v, other_path, other_at, other_v, why", [
    ((0.0, -20.0), 5.0, WEST, (15.0, 0.0), 8.0, "from the right"),
    ((0.0, -5.0), 15.0, EAST, (-15.0, 0.0), 8.0, "the ego passes 1.5 s before"),
    ((0.0, -20.0), 5.0, EAST, (-15.0, 0.0), 0.5, "the other car is not moving"),
    ((0.0, -20.0), 5.0, EAST, (-50.0, 0.0), 8.0, "the other car arrives after the 4 s horizon"),
])
def test_no_yield(ego_at, ego_v, other_path, other_at, other_v, why):
    ego = _car(NORTH, ego_at, ego_v, np.pi / 2)
    other = _car(other_path, other_at, other_v, 0.0 if other_path is EAST else np.pi)
    assert np.isinf(yield_gaps([ego, other])[0][0][0]), why


def test_a_vehicle_already_on_the_path_is_a_leader_not_a_conflict():
    ego = _car(NORTH, (0.0, -20.0), 5.0, np.pi / 2)
    ahead = _car(NORTH, (-0.5, -5.0), 5.0, np.pi / 2)  # slightly left of the line, on the ego's path
    assert np.isinf(yield_gaps([ego, ahead])[0][0][0])


def test_only_shared_frames_count_and_which_limits_the_work():
    ego = _car(NORTH, (0.0, -20.0), 5.0, np.pi / 2)
    other = _car(EAST, (-15.0, 0.0), 8.0, 0.0)
    later = TrackMotion(other.frames + 1, other.s, other.v, other.xy, other.psi, other.path)
    assert np.isinf(yield_gaps([ego, later])[0][0][0])  # never at the same frame
    assert np.isinf(yield_gaps([ego, other], which=[np.array([], dtype=int), np.array([0])])[0][0][0])


@pytest.mark.parametrize("kwargs", [{"radius": 0.0}, {"horizon": -1.0}, {"clearance": float("nan")},
                                    {"look_ahead": True}, {"obstacle": "wall"}])
def test_bad_rules_are_refused(kwargs):
    with pytest.raises(ValueError):
        ConflictRule(**kwargs)


def test_bad_motion_is_refused():
    with pytest.raises(ValueError, match="shape"):
        TrackMotion(np.arange(3), np.zeros(2), np.zeros(3), np.zeros((3, 2)), np.zeros(3), NORTH)
