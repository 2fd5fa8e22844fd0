"""Recorded simulator runs back to demonstrations for the learners (simulator-neutral).

:func:`recorded_demonstrations` turns the tracks of a :class:`~pirl_sim.scenarios.recording.ScenarioRecording`
(any simulator's) into longitudinal demonstrations on the routes' global arc-length axis
(:class:`~pirl_sim.scenarios.drivers.RouteSet`): by default whole PIRL tracks without interaction
(``selection="tracks"``), or every PIRL track with a per-step mask of the steps whose control is the
driver's own (``selection="steps"``, needs the recording's ``driver_steps``); :func:`step_selection_summary`
counts what each rule removes. :class:`RecordedRun` is a run read back from its directory (each simulator's
``load_*_run``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from pirl_sim.driving import (
    DEFAULT_BOUNDS,
    ESTIMATE_SIGMA_A,
    ESTIMATE_SIGMA_J,
    ESTIMATE_SIGMA_S,
    ESTIMATE_SIGMA_V,
    estimate_longitudinal_states,
    fit_longitudinal_states,
)
from pirl_sim.dynamics import longitudinal
from pirl_sim.trajectory import Trajectory

from .drivers import RouteSet, RouteSetDriverModel
from .leaders import frame_leaders, obstacle
from .yielding import ConflictTable, yield_gaps
from .population_config import FEATURE_NAMES
from .recording import FRAME_DT_S, ScenarioRecording

__all__ = ["ESTIMATES", "SELECTIONS", "recorded_demonstrations", "step_selection_summary", "RecordedRun"]

#: how states are estimated: from positions and speeds, or from positions only (the earlier default)
ESTIMATES: tuple[str, ...] = ("speeds", "positions")
#: where the states' arc length comes from: the projected positions, or the estimate
ARC_LENGTHS: tuple[str, ...] = ("observed", "fit")
#: steps after a restart that leave the likelihood while the drivers' real-time MPC re-converges
SETTLE_FRAMES = 5
#: [m/s] a command counts as carried out exactly when the speed one frame on is this close to it
EXACT_TOL = 1e-6
#: which data are kept: whole tracks without interaction, or every PIRL track with a per-step mask
SELECTIONS: tuple[str, ...] = ("tracks", "steps")
_A_LO, _A_HI = DEFAULT_BOUNDS.state["a [m/s^2]"]  # [m/s^2] the drivers' MPC moves its start into these


def _stride(dt: float) -> int:
    stride = round(dt / FRAME_DT_S)
    if stride < 1 or not math.isclose(stride * FRAME_DT_S, dt, rel_tol=1e-9):
        raise ValueError(f"dt must be a whole multiple of {FRAME_DT_S} s, got {dt!r}")
    return stride


def _frame_flags(recording: ScenarioRecording, exact_tol: float = EXACT_TOL) -> dict[int, pd.DataFrame]:
    """track id -> driver steps indexed by frame, with ``usable`` (the frame's step k -> k + 1 carries the
    driver's own command: commanded, not overridden, carried out to within ``exact_tol`` [m/s] where the
    recording has the command error, no collision at k or k + 1), ``altered`` (commanded and not overridden,
    but carried out less exactly than ``exact_tol``) and ``restart`` (the driver re-started from a measured
    acceleration at k: its step k - 1 was not commanded or overridden)."""
    steps = recording.driver_steps
    out = {}
    for tid, g in steps.groupby("track_id", sort=True):  # type: ignore[union-attr]
        g = g.set_index("frame_id")
        own = g["commanded"].to_numpy() & ~g["overridden"].to_numpy()
        altered = own & (g["command_error"].to_numpy(dtype=float) > exact_tol)  # NaN (unknown): not altered
        col = g["collided"].to_numpy()
        usable = own & ~altered & ~col & ~np.concatenate([col[1:], [True]])  # the last frame has no step
        restart = np.concatenate([[False], ~own[:-1]])
        out[int(tid)] = g.assign(usable=usable, restart=restart, altered=altered)
    return out


def _step_mask(usable: np.ndarray, stride: int, n_steps: int) -> np.ndarray:
    """Per demonstration step (``stride`` frames each): usable only if all of its frames are."""
    return usable[: n_steps * stride].reshape(n_steps, stride).all(axis=1)  # type: ignore[return-value]


def settled(mask: np.ndarray, settle: int) -> np.ndarray:
    """``mask`` (n,) without the first ``settle`` usable entries after each unusable one."""
    out = mask.copy()
    for k in np.flatnonzero(~mask):
        out[k + 1 : k + 1 + settle] = False
    return out


def recorded_demonstrations(recording: ScenarioRecording, routes: RouteSet, *, dt: float = FRAME_DT_S,
                            pirl_only: bool = True, non_interacting: bool = True, min_steps: int = 10,
                            selection: str = "tracks", estimate: str = "speeds",
                            jerk_weight: float = 1e-2, sigma_s: float = ESTIMATE_SIGMA_S,
                            sigma_v: float = ESTIMATE_SIGMA_V, sigma_j: float = ESTIMATE_SIGMA_J,
                            sigma_a: float = ESTIMATE_SIGMA_A, arc_length: str = "observed",
                            settle_frames: int = SETTLE_FRAMES, exact_tol: float = EXACT_TOL) -> list[Trajectory]:
    """Recorded tracks as longitudinal demonstrations (s, v, a; jerk) on the routes' global axis ("Weight recovery on
    simulated runs" page: What counts as a step; "In detail: recorded_demonstrations" has how, and every option).

    Parameters
    ----------
    recording, routes : ScenarioRecording, RouteSet   the run, and reference paths holding every selected track's route
    dt : float                             [s], a whole multiple of the 0.1 s frames
    pirl_only, non_interacting, min_steps, selection : bool, bool, int, {"tracks", "steps"}   which tracks and steps
    estimate, jerk_weight, sigma_s, sigma_v, sigma_j, sigma_a, arc_length : the state estimate (see the page)
    settle_frames, exact_tol : int, float   re-plans, and [m/s] inexact commands, that also leave ``step_mask``

    Returns
    -------
    demonstrations : list of Trajectory   in track order, metadata as the page lists; ValueError for bad options
    """
    stride = _stride(dt)
    if selection not in SELECTIONS:
        raise ValueError(f"selection must be one of {SELECTIONS}, got {selection!r}")
    if estimate not in ESTIMATES:
        raise ValueError(f"estimate must be one of {ESTIMATES}, got {estimate!r}")
    if isinstance(settle_frames, bool) or not isinstance(settle_frames, (int, np.integer)) or settle_frames < 0:
        raise ValueError(f"settle_frames must be a whole number of frames >= 0, got {settle_frames!r}")
    if not (isinstance(exact_tol, (int, float, np.floating)) and not isinstance(exact_tol, bool)
            and math.isfinite(exact_tol) and exact_tol >= 0):
        raise ValueError(f"exact_tol must be a number of m/s >= 0, got {exact_tol!r}")
    if arc_length not in ARC_LENGTHS:
        raise ValueError(f"arc_length must be one of {ARC_LENGTHS}, got {arc_length!r}")
    if selection == "steps":
        if recording.driver_steps is None:
            raise ValueError("selection='steps' needs the recording's driver_steps (driver_steps.csv); this "
                             "recording has none (recorded before they were written?)")
        if not pirl_only:
            raise ValueError("selection='steps' keeps PIRL tracks only (background traffic has no driver "
                             "steps); pass pirl_only=True")
    gt = recording.ground_truth
    keep = np.ones(len(gt), dtype=bool)
    if pirl_only:
        keep &= gt["is_pirl"].to_numpy()
    if non_interacting and selection == "tracks":
        keep &= ~(gt["interacted"].fillna(False).to_numpy(dtype=bool) | gt["collided"].to_numpy()
                  | gt["removed_early"].to_numpy())
    flags = _frame_flags(recording, exact_tol) if recording.driver_steps is not None else {}
    dyn = longitudinal(dt)
    features = recording.theta_features
    lead = _recorded_obstacles(recording, routes) if len(features) > len(FEATURE_NAMES) else None
    by_track = {tid: g for tid, g in recording.tracks.groupby("track_id", sort=True)}
    out = []
    for row in gt[keep].itertuples(index=False):
        g = by_track[row.track_id].sort_values("time_s", kind="stable")
        frames = np.round(g["time_s"].to_numpy() / FRAME_DT_S).astype(np.int64)
        if np.any(np.diff(frames) != 1):
            raise ValueError(f"track {row.track_id} has gaps in its frames; cannot make one demonstration")
        xy = g[["x", "y"]].to_numpy()[::stride]
        n_steps = len(xy) - 1
        if n_steps < min_steps:
            continue
        f = flags.get(int(row.track_id))
        mask = a_obs = None
        if f is not None:
            f = f.reindex(frames)
            mask = _step_mask(f["usable"].to_numpy(dtype=bool), stride, n_steps)
            if selection == "steps" and int(mask.sum()) < min_steps:
                continue
        r = routes.index(row.route_id)
        s, _ = routes.paths[r].to_frenet(xy, extrapolate=True)
        s = routes.offsets[r] + s
        if estimate == "speeds":
            v_all = np.hypot(g["vx"].to_numpy(dtype=float), g["vy"].to_numpy(dtype=float))
            if not np.all(np.isfinite(v_all)):
                raise ValueError(f"track {row.track_id}: the recording has no usable speeds (vx, vy missing or not "
                                 f"finite in {int(np.sum(~np.isfinite(v_all)))} frames); estimate='speeds' needs "
                                 "them, estimate='positions' estimates the states from positions only")
            if f is not None:  # the driver's start acceleration after a step that was not its own
                restart = f["restart"].to_numpy(dtype=bool, copy=True)
                restart[0] = False
                k = np.flatnonzero(restart)
                a_meas = np.full(len(frames), np.nan)
                a_meas[k] = np.clip((v_all[k] - v_all[k - 1]) / FRAME_DT_S, _A_LO, _A_HI)
                a_meas[k[v_all[k] <= 0.0]] = np.maximum(a_meas[k[v_all[k] <= 0.0]], 0.0)
                a_obs = a_meas[::stride]
            states, controls = estimate_longitudinal_states(
                s, dyn, v_obs=v_all[::stride], sigma_s=sigma_s, sigma_v=sigma_v, sigma_j=sigma_j,
                a_obs=a_obs, sigma_a=sigma_a, step_mask=mask)
        elif mask is None:
            states, controls = fit_longitudinal_states(s, dyn, jerk_weight=jerk_weight)
        else:
            states, controls = estimate_longitudinal_states(s, dyn, sigma_s=1.0, sigma_j=jerk_weight ** -0.5,
                                                            step_mask=mask)
        if arc_length == "observed":
            states = states.copy()
            states[:, 0] = s
        if lead is not None:  # what the drivers who interact saw ahead (`pirl_sim.dynamics.following`, 2 obstacles)
            at = lead.loc[g.index.to_numpy()[::stride]]
            speed = np.hypot(g["vx"].to_numpy(dtype=float), g["vy"].to_numpy(dtype=float))[::stride]
            states = np.column_stack([states, *obstacle(at["gap"].to_numpy(), at["v_lead"].to_numpy(), speed),
                                      *obstacle(at["yield_gap"].to_numpy(), np.zeros(len(at)), speed)])
        theta = np.array([getattr(row, f"theta_{f}") for f in features])
        meta: dict[str, Any] = {
            "track_id": int(row.track_id), "agent_id": row.agent_id, "route_id": row.route_id,
            "is_pirl": bool(row.is_pirl), "style": int(row.style), "style_name": row.style_name,
            "theta": theta, "interacted": None if pd.isna(row.interacted) else bool(row.interacted),
            "first_frame": int(frames[0])}
        if mask is not None:
            meta["step_mask"] = _step_mask(
                settled(f["usable"].to_numpy(dtype=bool), settle_frames), stride, n_steps)  # type: ignore[index]
        out.append(Trajectory(states, controls, dt, meta))
    return out


def _recorded_obstacles(recording: ScenarioRecording, routes: RouteSet) -> pd.DataFrame:
    """Per row of a recording's tracks (same index): ``gap`` [m] to the vehicle ahead and its speed ``v_lead``
    [m/s] (`pirl_sim.scenarios.leaders.frame_leaders`), and ``yield_gap`` [m] to the obstacle a PIRL track
    yields to (`pirl_sim.scenarios.yielding.yield_gaps`; inf where none), over the vehicles of the row's frame:
    the rules the drivers who interact planned with."""
    tracks = recording.tracks
    xy = tracks[["x", "y"]].to_numpy(dtype=float)
    psi, length = tracks["psi_rad"].to_numpy(dtype=float), tracks["length"].to_numpy(dtype=float)
    speed = np.hypot(tracks["vx"].to_numpy(dtype=float), tracks["vy"].to_numpy(dtype=float))
    gt = recording.ground_truth.set_index("track_id")
    ids = tracks["track_id"].to_numpy()
    known = {rid: (routes.route_ids.index(rid) if rid in routes.route_ids else -1) for rid in gt["route_id"].unique()}
    route = gt["route_id"].map(known).reindex(ids).to_numpy(dtype=np.int64)
    pirl = gt["is_pirl"].reindex(ids).to_numpy(dtype=bool)
    s = np.full(len(tracks), np.nan)
    for rows in pd.Series(np.arange(len(tracks))).groupby(ids, sort=False).indices.values():
        r = route[rows[0]]
        if r >= 0:  # the drivers' projection (`RouteSet.project`), started at the path's own foot points
            guess = routes.paths[r].to_frenet(xy[rows], extrapolate=True)[0]
            s[rows] = routes.project(np.full(len(rows), r), xy[rows], guess)
    table = ConflictTable(routes)
    gap, v_lead, yield_gap = np.full(len(tracks), np.inf), np.full(len(tracks), np.nan), np.full(len(tracks), np.inf)
    frames = np.round(tracks["time_s"].to_numpy(dtype=float) / FRAME_DT_S).astype(np.int64)
    for rows in pd.Series(np.arange(len(tracks))).groupby(frames, sort=False).indices.values():
        gap[rows], v_lead[rows] = frame_leaders(xy[rows], psi[rows], speed[rows], length[rows])
        egos = np.flatnonzero(pirl[rows])
        yield_gap[rows[egos]] = yield_gaps(table, route[rows], s[rows], speed[rows], xy[rows], psi[rows], egos)
    return pd.DataFrame({"gap": gap, "v_lead": v_lead, "yield_gap": yield_gap}, index=tracks.index)


def step_selection_summary(recording: ScenarioRecording, *, dt: float = FRAME_DT_S,
                           min_steps: int = 10, settle_frames: int = SETTLE_FRAMES,
                           exact_tol: float = EXACT_TOL) -> pd.DataFrame:
    """How many steps and tracks each selection rule removes, per style (PIRL tracks only; ValueError without driver
    steps or for a ``dt`` off the frame grid).

    Counts are in steps of ``dt`` (a step counts under a rule if any of its frames does); the rules overlap.

    Returns
    -------
    pandas.DataFrame
        One row per style name (sorted) and ``"all"``; columns ``tracks``, ``steps``, ``not_commanded``,
        ``overridden``, ``altered`` (below ``exact_tol``), ``collided``, ``settling`` (``settle_frames``),
        ``usable``, ``tracks_few_usable``, ``steps_kept`` / ``tracks_kept`` (``selection="steps"``) and, for
        comparison, ``tracks_interacted`` and ``steps_tracks_selection`` (``selection="tracks"``).
    """
    stride = _stride(dt)
    if recording.driver_steps is None:
        raise ValueError("the recording has no driver_steps: no per-step information to count")
    gt = recording.ground_truth.set_index("track_id")
    rows = []
    for tid, f in _frame_flags(recording, exact_tol).items():
        n_steps = (len(f) - 1) // stride
        if n_steps < min_steps:
            continue

        def per_step(flag: np.ndarray) -> int:
            return int(flag[: n_steps * stride].reshape(n_steps, stride).any(axis=1).sum())

        col = f["collided"].to_numpy()
        own = _step_mask(f["usable"].to_numpy(), stride, n_steps)
        mask = _step_mask(settled(f["usable"].to_numpy(dtype=bool), settle_frames), stride, n_steps)
        usable = int(mask.sum())
        g = gt.loc[tid]
        dropped = bool(g["interacted"]) or bool(g["collided"]) or bool(g["removed_early"])
        rows.append({
            "style_name": g["style_name"], "tracks": 1, "steps": n_steps,
            "not_commanded": per_step(~f["commanded"].to_numpy()),
            "overridden": per_step(f["overridden"].to_numpy()),
            "collided": per_step(col | np.concatenate([col[1:], [False]])),
            "altered": per_step(f["altered"].to_numpy()),
            "settling": int((own & ~mask).sum()),
            "usable": usable, "tracks_few_usable": int(usable < min_steps),
            "steps_kept": usable if usable >= min_steps else 0, "tracks_kept": int(usable >= min_steps),
            "tracks_interacted": int(dropped), "steps_tracks_selection": 0 if dropped else n_steps,
        })
    cols = ["tracks", "steps", "not_commanded", "overridden", "altered", "collided", "settling", "usable", "tracks_few_usable",
            "steps_kept", "tracks_kept", "tracks_interacted", "steps_tracks_selection"]
    df = pd.DataFrame(rows, columns=["style_name", *cols])
    table = df.groupby("style_name", sort=True)[cols].sum()
    table.loc["all"] = table.sum() if len(table) else 0
    return table.astype(np.int64)


@dataclass(frozen=True, eq=False)
class RecordedRun:
    """A simulator run read back from its directory.

    Attributes
    ----------
    recording : ScenarioRecording
    config : object
        The simulator's scenario configuration, rebuilt from ``run.json`` (``drivers.horizon``,
        ``population.control_noise``, ...).
    routes : RouteSet
        The routes' reference paths, rebuilt from the configuration (or the network files of the run).
    model : RouteSetDriverModel
        The drivers' model (converged MPC settings) for learning and prediction.
    """

    recording: ScenarioRecording
    config: Any
    routes: RouteSet
    model: RouteSetDriverModel

    @property
    def horizon(self) -> int:
        """The PIRL drivers' MPC horizon [steps of :attr:`dt`] (``drivers.horizon`` of the run)."""
        return int(self.config.drivers.horizon)

    @property
    def dt(self) -> float:
        """The drivers' re-planning step = the simulation step [s] (``step_length_s`` of the run)."""
        return float(self.recording.info["step_length_s"])

    @property
    def control_noise(self) -> float:
        """Standard deviation [m/s^3] of the Gaussian noise added to every applied jerk."""
        return float(self.config.population.control_noise)

    def demonstrations(self, **kwargs) -> list[Trajectory]:
        """:func:`recorded_demonstrations` of this run (keyword arguments as there)."""
        return recorded_demonstrations(self.recording, self.routes, **kwargs)

    def step_selection_summary(self, **kwargs) -> pd.DataFrame:
        """:func:`step_selection_summary` of this run (keyword arguments as there)."""
        return step_selection_summary(self.recording, **kwargs)
