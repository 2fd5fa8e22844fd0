"""Recorded simulator runs back to demonstrations for the learners (simulator-neutral).

:func:`recorded_demonstrations` turns the tracks of a :class:`~pirl_sim.scenarios.recording.ScenarioRecording`
(any simulator's) into longitudinal demonstrations on the routes' global arc-length axis
(:class:`~pirl_sim.scenarios.drivers.RouteSet`), by default only PIRL drivers' tracks without interaction;
:class:`RecordedRun` is a run read back from its directory (each simulator's ``load_*_run``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from pirl_sim.driving import fit_longitudinal_states
from pirl_sim.dynamics import longitudinal
from pirl_sim.trajectory import Trajectory

from .drivers import RouteSet, RouteSetDriverModel
from .population_config import FEATURE_NAMES
from .recording import FRAME_DT_S, ScenarioRecording

__all__ = ["recorded_demonstrations", "RecordedRun"]


def recorded_demonstrations(recording: ScenarioRecording, routes: RouteSet, *, dt: float = FRAME_DT_S,
                            pirl_only: bool = True, non_interacting: bool = True, min_steps: int = 10,
                            jerk_weight: float = 1e-2) -> list[Trajectory]:
    """Recorded tracks as longitudinal demonstrations (s, v, a; jerk) on the routes' global axis.

    Each track's positions are projected on its route's reference path
    (:meth:`pirl_sim.paths.ReferencePath.to_frenet`), shifted to the route's place on the global axis,
    sampled every ``dt`` and turned into states and controls consistent with the dynamics by
    :func:`pirl_sim.driving.fit_longitudinal_states`.

    Parameters
    ----------
    recording : ScenarioRecording
    routes : RouteSet
        Must hold every selected track's route.
    dt : float
        [s], a whole multiple of the 0.1 s frames.
    pirl_only : bool
        Only tracks driven by PIRL drivers.
    non_interacting : bool
        Leave out tracks that interacted, collided or were removed early.
    min_steps : int
        Leave out shorter tracks [steps of dt].
    jerk_weight : float
        Ridge on the jerks of the fit (see ``fit_longitudinal_states``).

    Returns
    -------
    list of Trajectory
        In track order; metadata ``track_id``, ``agent_id``, ``route_id``, ``is_pirl``, ``style``,
        ``style_name``, ``theta`` (normalised weights, NaN for background), ``interacted``.
    """
    stride = round(dt / FRAME_DT_S)
    if stride < 1 or not math.isclose(stride * FRAME_DT_S, dt, rel_tol=1e-9):
        raise ValueError(f"dt must be a whole multiple of {FRAME_DT_S} s, got {dt!r}")
    gt = recording.ground_truth
    keep = np.ones(len(gt), dtype=bool)
    if pirl_only:
        keep &= gt["is_pirl"].to_numpy()
    if non_interacting:
        keep &= ~(gt["interacted"].fillna(False).to_numpy(dtype=bool) | gt["collided"].to_numpy()
                  | gt["removed_early"].to_numpy())
    dyn = longitudinal(dt)
    by_track = {tid: g for tid, g in recording.tracks.groupby("track_id", sort=True)}
    out = []
    for row in gt[keep].itertuples(index=False):
        g = by_track[row.track_id].sort_values("time_s", kind="stable")
        frames = np.round(g["time_s"].to_numpy() / FRAME_DT_S).astype(np.int64)
        if np.any(np.diff(frames) != 1):
            raise ValueError(f"track {row.track_id} has gaps in its frames; cannot make one demonstration")
        xy = g[["x", "y"]].to_numpy()[::stride]
        if len(xy) - 1 < min_steps:
            continue
        r = routes.index(row.route_id)
        s, _ = routes.paths[r].to_frenet(xy, extrapolate=True)
        states, controls = fit_longitudinal_states(routes.offsets[r] + s, dyn, jerk_weight=jerk_weight)
        theta = np.array([getattr(row, f"theta_{f}") for f in FEATURE_NAMES])
        out.append(Trajectory(states, controls, dt, {
            "track_id": int(row.track_id), "agent_id": row.agent_id, "route_id": row.route_id,
            "is_pirl": bool(row.is_pirl), "style": int(row.style), "style_name": row.style_name,
            "theta": theta, "interacted": None if pd.isna(row.interacted) else bool(row.interacted)}))
    return out


@dataclass(frozen=True, eq=False)
class RecordedRun:
    """A simulator run read back from its directory.

    Attributes
    ----------
    recording : ScenarioRecording
    config : object
        The simulator's scenario configuration, rebuilt from ``run.json``.
    routes : RouteSet
        The routes' reference paths, rebuilt from the configuration (or the network files of the run).
    model : RouteSetDriverModel
        The drivers' model (converged MPC settings) for learning and prediction.
    """

    recording: ScenarioRecording
    config: Any
    routes: RouteSet
    model: RouteSetDriverModel

    def demonstrations(self, **kwargs) -> list[Trajectory]:
        """:func:`recorded_demonstrations` of this run (keyword arguments as there)."""
        return recorded_demonstrations(self.recording, self.routes, **kwargs)
