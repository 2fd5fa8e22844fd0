"""Trajectories (pirl_sim.trajectory): validation, immutability, windows with their offsets and step masks, stacking."""

import numpy as np
import pytest

from pirl_sim.trajectory import Trajectory, stack_trajectories


def test_trajectory_validates_shapes_and_values():
    t = Trajectory(np.zeros((4, 2)), np.zeros((3, 1)), 0.1, {"style": 1})
    assert t.n_steps == 3 and t.duration == pytest.approx(0.3)
    with pytest.raises(ValueError, match="one more state than controls"):
        Trajectory(np.zeros((3, 2)), np.zeros((3, 1)), 0.1)
    with pytest.raises(ValueError, match="at least one step"):
        Trajectory(np.zeros((1, 2)), np.zeros((0, 1)), 0.1)
    bad = np.zeros((4, 2))
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"states must be finite.*index \(2, 1\)"):
        Trajectory(bad, np.zeros((3, 1)), 0.1)
    bad[2, 1] = np.inf
    with pytest.raises(ValueError, match="finite"):
        Trajectory(bad, np.zeros((3, 1)), 0.1)
    with pytest.raises(ValueError, match="2 dimensions"):
        Trajectory(np.zeros(4), np.zeros((3, 1)), 0.1)
    with pytest.raises(ValueError, match="dt must be"):
        Trajectory(np.zeros((4, 2)), np.zeros((3, 1)), 0.0)
    with pytest.raises(TypeError, match="dt"):
        Trajectory(np.zeros((4, 2)), np.zeros((3, 1)), "0.1")
    with pytest.raises(TypeError, match="numeric"):
        Trajectory([["a", "b"]] * 4, np.zeros((3, 1)), 0.1)


def test_trajectory_is_immutable_and_windows_keep_offsets():
    t = Trajectory(np.arange(10.0).reshape(5, 2), np.ones((4, 1)), 0.1)
    with pytest.raises(ValueError):
        t.states[0, 0] = 1.0
    w = t.window(1, 3)
    assert w.n_steps == 2 and w.metadata["window_start"] == 1
    np.testing.assert_array_equal(w.states, t.states[1:4])
    assert t.window(-2).metadata["window_start"] == 2
    with pytest.raises(ValueError, match="window"):
        t.window(3, 3)


def test_stack_rejects_mixed_lengths():
    a = Trajectory(np.zeros((4, 2)), np.zeros((3, 1)), 0.1)
    b = Trajectory(np.zeros((5, 2)), np.zeros((4, 1)), 0.1)
    with pytest.raises(ValueError, match="group trajectories by length"):
        stack_trajectories([a, b])
    with pytest.raises(TypeError, match="expected a pirl_sim.Trajectory"):
        stack_trajectories([a, "b"])


DT = 0.1


def test_window_slices_the_step_mask():
    mask = np.array([True, False, True, True, False])
    tr = Trajectory(np.zeros((6, 3)), np.zeros((5, 1)), DT, {"step_mask": mask, "track_id": 3})
    w = tr.window(1, 4)
    np.testing.assert_array_equal(w.metadata["step_mask"], mask[1:4])
    np.testing.assert_array_equal(w.window(-2).metadata["step_mask"], mask[2:4])
    assert w.metadata["track_id"] == 3 and tr.window(2).metadata["window_start"] == 2
    bad = Trajectory(np.zeros((6, 3)), np.zeros((5, 1)), DT, {"step_mask": mask[:3]})
    with pytest.raises(ValueError, match=r"step_mask has shape \(3,\), expected one flag per step \(5,\)"):
        bad.window(1)
