"""What the PIRL drivers who interact planned with, recorded during a run: for each (time [s], vehicle id), the gap
[m] and speed [m/s] of the vehicle ahead, then of the obstacle yielded to; and the check that the learner reads the
same from the recording."""

from __future__ import annotations

import contextlib

import numpy as np

from pirl_sim.recovery import run_demonstrations
from pirl_sim.scenarios import drivers as drivers_module


@contextlib.contextmanager
def planned_obstacles():
    """Within the block, every batch of plans adds its drivers' obstacle states to the yielded dict."""
    seen: dict[tuple[float, str], tuple[float, ...]] = {}
    cls = drivers_module.PirlDrivers
    commands, obstacles = cls.commands, cls._obstacles

    def obstacles_spy(self, frame, vids, speed, s_local):
        out = obstacles(self, frame, vids, speed, s_local)
        for v, *cols in zip(vids, *out):
            seen[round(self._now, 1), v] = tuple(cols)
        return out

    def commands_spy(self, time, observations, frame=None):
        self._now = time
        return commands(self, time, observations, frame)

    cls.commands, cls._obstacles = commands_spy, obstacles_spy
    try:
        yield seen
    finally:
        cls.commands, cls._obstacles = commands, obstacles


def assert_the_learner_reads_the_planned_gaps(run, seen, *, min_compared: int, min_near: int) -> None:
    """Every usable step's obstacle columns (states 3..6) of every demonstration equal what its driver planned with
    (5 mm); at least ``min_compared`` steps compared, ``min_near`` of them within 20 m of a vehicle ahead."""
    gt = run.recording.ground_truth
    assert "theta_yielding" in gt and run.model.features.names[-2:] == ("headway", "yielding")
    agents = dict(zip(gt["track_id"], gt["agent_id"]))
    compared, near = 0, 0
    for d in run_demonstrations(run, 10):
        vid = agents[d.metadata["track_id"]]
        times = np.round((d.metadata["first_frame"] + np.arange(len(d.states))) * 0.1, 1)
        planned = np.array([seen.get((t, vid), (np.nan,) * 4) for t in times])
        ok = np.isfinite(planned[:, 0])  # not a step handed back to the simulator
        np.testing.assert_allclose(d.states[ok, 3:7], planned[ok], atol=5e-3)
        compared += int(ok.sum())
        near += int((planned[ok, 0] < 20.0).sum())
    assert compared > min_compared and near > min_near
