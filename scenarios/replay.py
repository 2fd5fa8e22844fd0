"""Recorded driving in, trajectories out: INTERACTION-format tracks and a Lanelet2 map -> driver-model data.

For every vehicle track (`load_replay`): match it to the lanelet route it drove
(`pirl_sim.io.lanelet2_map.match_route`), smooth that route's centerline into a `ReferencePath`, project the
track into Frenet (s, d), resample the 10 Hz frames to the model's dt (0.2 s by default) and estimate (s, v, a)
and jerk by least squares through the dynamics (``estimate``: `MEASURED_NOISE`, `SIMULATED_NOISE`). All routes
share one arc-length axis (`CompositePath`). Drivers are selected by whether they had a leader
(`SelectionRule`; ``selection`` = ``"tracks"``, ``"free"`` or ``"steps"``), repairs and skipped tracks are
counted (``ReplayScene.repairs``, ``skipped``), and a pirl_sim recording's ``ground_truth.csv`` and
``driver_steps.csv`` go into each trajectory's metadata.

Route matching, selection rules, sidecars and state estimates are explained in the documentation's
"Simulators and data" page (recorded tracks).
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from pirl_sim.driving import (
    DEFAULT_BOUNDS,
    ESTIMATE_SIGMA_A,
    ESTIMATE_SIGMA_J,
    ESTIMATE_SIGMA_S,
    ESTIMATE_SIGMA_V,
    FEATURE_SETS,
    CompositePath,
    PathDriverModel,
    SpeedProfile,
    estimate_longitudinal_states,
    fit_longitudinal_states,
    roundabout_features,
)
from pirl_sim.dynamics import following, longitudinal
from pirl_sim.paths import DEFAULT_A_LAT, DEFAULT_SMOOTHING, DEFAULT_V_MAX, TRACK_STEP, ReferencePath
from pirl_sim.trajectory import Trajectory
from pirl_sim.validation import is_positive_int, number

from .conflicts import ConflictRule, TrackMotion, yield_gaps
from .demonstrations import settled
from .leaders import NO_LEADER_GAP, frame_leaders, obstacle

__all__ = ["SelectionRule", "CENTRE_RULE", "GAPS", "leader_gaps", "leader_frames", "selection_counts", "ReplayScene", "HistoryEstimator", "EstimateNoise", "DriverSettings", "load_replay", "interaction_flags",
           "track_key", "recording_settings", "is_recording", "FRAME_DT", "MAX_BRIDGE", "MEASURED_NOISE", "SIMULATED_NOISE",
           "ESTIMATES", "SELECTIONS"]

log = logging.getLogger(__name__)

FRAME_DT = 0.1  #: [s] INTERACTION frame period
MAX_BRIDGE = 5  #: [frames] longest run of unconnected positions inside a track that is bridged (0.5 s)
ESTIMATES = ("positions", "speeds")  #: state estimate from positions only, or positions and recorded speeds
SELECTIONS = ("tracks", "steps", "free", "all")  #: whole non-interacting tracks, every PIRL track with per-step
#: masks, every track cut into its free-flow runs (steps without a leader), or every track whole (leaders and
#: all: for the ``following`` features, which see the vehicle ahead)
DRIVER_STEPS_FILE = "driver_steps.csv"  #: per-step driver flags of a pirl_sim recording, beside the tracks
RUN_INFO_FILE = "run.json"  #: a pirl_sim recording's run information (drivers' horizon, step, ...)
#: columns of ``driver_steps.csv`` that the replay reads
DRIVER_STEP_FLAGS = ("track_id", "frame_id", "commanded", "overridden", "collided")
#: feature sets whose states carry the vehicle ahead (`pirl_sim.dynamics.following`): ``following`` also yields at
#: conflict points (`pirl_sim.scenarios.conflicts`) in the same gap; ``interacting`` keeps the vehicle ahead
#: (`pirl_sim.scenarios.leaders`) and a standing obstacle before the conflict point apart, as the simulated drivers
#: who interact do
GAP_FEATURE_SETS = ("following", "interacting")


@dataclass(frozen=True)
class EstimateNoise:
    """Noise model of the speed-aware state estimate (see `pirl_sim.driving.estimate_longitudinal_states`).

    Attributes
    ----------
    sigma_s : float [m]        position noise
    sigma_v : float [m/s]      speed noise
    sigma_j : float [m/s^3]    prior standard deviation of the jerks
    sigma_a : float [m/s^2]    noise of a measured restart acceleration (recordings with driver steps)
    """

    sigma_s: float
    sigma_v: float
    sigma_j: float
    sigma_a: float = ESTIMATE_SIGMA_A

    def __post_init__(self) -> None:
        for name in ("sigma_s", "sigma_v", "sigma_j", "sigma_a"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")


#: measured tracks (INTERACTION: drone video, smoothed by the tracker): speeds trusted loosely, jerks damped.
#: On DR_USA_Roundabout_FT vehicle_tracks_000 (151 car tracks) hypot(vx, vy) differs from the central
#: difference of the positions by 0.03 m/s (1.4826 x MAD; median offset 0.009 m/s), and its second
#: differences are 0.005 m/s (MAD): smooth, consistent speeds whose error against the true speed is unknown.
MEASURED_NOISE = EstimateNoise(sigma_s=0.1, sigma_v=0.05, sigma_j=1.0)
#: pirl_sim recordings: exact simulator speeds (the measured defaults of `estimate_longitudinal_states`)
SIMULATED_NOISE = EstimateNoise(ESTIMATE_SIGMA_S, ESTIMATE_SIGMA_V, ESTIMATE_SIGMA_J, ESTIMATE_SIGMA_A)


@dataclass(frozen=True)
class DriverSettings:
    """The model settings of the drivers of a pirl_sim recording (``run.json``), for a replay that learns with
    the drivers' own model class.

    Attributes
    ----------
    horizon : int          MPC horizon [steps of ``dt``]
    dt : float [s]         re-planning step
    smoothing : float [m]  smoothing length of the reference paths' geometry
    speed_smoothing : float [m]  further smoothing of the curvature for the desired speed
    a_lat : float [m/s^2], v_max : float [m/s]   desired-speed parameters
    """

    horizon: int
    dt: float
    smoothing: float
    speed_smoothing: float
    a_lat: float
    v_max: float


def _run_info(tracks: str | Path) -> dict | None:
    import json

    path = Path(tracks)
    info = (path if path.is_dir() else path.parent) / RUN_INFO_FILE
    if not info.is_file():
        return None
    try:
        data = json.loads(info.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{info}: not UTF-8 JSON ({exc}); a recording's {RUN_INFO_FILE} is a JSON object "
                         f"(delete it to replay the tracks as real data)") from None
    if not isinstance(data, dict):
        raise ValueError(f"{info}: a recording's {RUN_INFO_FILE} is a JSON object, got a {type(data).__name__}")
    return data if data.get("format") == "pirl_sim scenario recording" else None


def is_recording(tracks: str | Path) -> bool:
    """Whether a track file (or a tracks directory) is a pirl_sim recording (a pirl_sim ``run.json`` beside it)."""
    return _run_info(tracks) is not None


def recording_settings(tracks: str | Path) -> DriverSettings | None:
    """`DriverSettings` from the ``run.json`` beside a track file (or in a tracks directory) when it is a
    recording of receding-horizon MPC drivers (SUMO, highway-env); None otherwise (real data, or scenes
    without such drivers)."""
    data = _run_info(tracks)
    info = (Path(tracks) if Path(tracks).is_dir() else Path(tracks).parent) / RUN_INFO_FILE
    if data is not None and not isinstance(data.get("config", {}), dict):
        raise ValueError(f"{info}: config must be a JSON object, got {data['config']!r}")
    if data is None or "drivers" not in data.get("config", {}) or "step_length_s" not in data:
        return None
    drv = data["config"]["drivers"]
    if not isinstance(drv, dict):
        raise ValueError(f"{info}: config.drivers must be a JSON object (the drivers' settings), got {drv!r}")
    step = data["step_length_s"]
    if isinstance(step, bool) or not isinstance(step, (int, float)) or not math.isfinite(step) or step <= 0:
        raise ValueError(f"{info}: step_length_s must be a finite number of seconds > 0 (the drivers' re-planning "
                         f"step), got {step!r}")
    horizon = drv.get("horizon")
    if isinstance(horizon, bool) or not isinstance(horizon, (int, float)) or not math.isfinite(horizon) \
            or horizon < 1 or horizon != int(horizon):
        raise ValueError(f"{info}: config.drivers.horizon must be a positive integer [steps], got {horizon!r}")
    # path smoothing lengths [m] >= 0, the desired speed's a_lat [m/s^2] and v_max [m/s] > 0
    values = {name: number(f"{info}: config.drivers.{name}", drv.get(name), low=0.0, allow_equal=zero)
              for name, zero in (("smoothing", True), ("speed_smoothing", True), ("a_lat", False), ("v_max", False))}
    return DriverSettings(horizon=int(drv["horizon"]), dt=float(data["step_length_s"]), **values)


GAPS = ("bumper", "centre")  #: distance to a leader: bumper to bumper (vehicle lengths), or centre to centre


@dataclass(frozen=True)
class SelectionRule:
    """When a vehicle ahead counts as a leader, and which tracks are replayed ("Simulators and data" page).

    Attributes
    ----------
    time_gap : float [s]            headway below which a vehicle ahead counts as a leader
    standstill : float [m]          gap added to the headway (bumper to bumper or centre to centre)
    max_heading_diff_deg : float    leaders drive within this angle of the track's heading
    min_duration : float [s]        shorter tracks are skipped
    agent_types : tuple of str      agent_type values that are replayed
    gap : {"bumper", "centre"}      centre distance minus half of each vehicle's length, or centre to centre
                                    (`CENTRE_RULE`, which misses standing queues)
    """

    time_gap: float = 1.5
    standstill: float = 3.0
    max_heading_diff_deg: float = 45.0
    min_duration: float = 4.0
    agent_types: tuple[str, ...] = ("car",)
    gap: str = "bumper"

    def __post_init__(self) -> None:
        for name in ("time_gap", "standstill", "max_heading_diff_deg", "min_duration"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be >= 0, got {v!r}")
        if self.gap not in GAPS:
            raise ValueError(f"gap must be one of {GAPS}, got {self.gap!r}")

    def describe(self) -> str:
        """A short name of the rule, e.g. ``bumper gap < 3 m + 2 s x v``."""
        return f"{self.gap} gap < {self.standstill:g} m + {self.time_gap:g} s x v"


#: a centre-to-centre selection rule, 5 m + 2 s, kept for comparison (counts are reported for it)
CENTRE_RULE = SelectionRule(time_gap=2.0, standstill=5.0, gap="centre")


@dataclass(frozen=True)
class HistoryEstimator:
    """The state estimate of `load_replay` applied to one window of a trajectory's own observations (its
    metadata's ``s_obs``, ``v_obs``): `Trajectory.history_window` calls it. The states of a whole piece come
    from a smoother whose states at a step also saw the steps after it; a window's own estimate is what an
    online observer of that window knows.

    Attributes
    ----------
    dt : float [s]                 the model step
    estimate : {"positions", "speeds"}, noise : EstimateNoise, jerk_weight : float   as in `load_replay`
    arc_length : {"fit", "observed"}  as in `load_replay`
    """

    dt: float
    estimate: str
    noise: EstimateNoise
    jerk_weight: float
    arc_length: str = "fit"

    def __call__(self, trajectory: Trajectory, start: int, stop: int | None = None) -> Trajectory:
        """``trajectory.window(start, stop)`` with (s, v, a) estimated from the window's observations alone;
        further state entries (the vehicle ahead) as recorded. Raises ValueError for a window of < 2 steps or a
        trajectory without ``s_obs``/``v_obs``."""
        if "s_obs" not in trajectory.metadata or "v_obs" not in trajectory.metadata:
            raise ValueError("a history estimate needs the observations s_obs and v_obs in the trajectory's metadata")
        window = trajectory.window(start, stop)
        a = int(window.metadata["window_start"]) - int(trajectory.metadata.get("window_start", 0))
        b = a + window.n_steps
        if b - a < 2:
            raise ValueError(f"a history estimate needs at least 2 steps, got [{start}, {stop})")
        meta = trajectory.metadata
        s_obs, v_obs = np.asarray(meta["s_obs"])[a : b + 1], np.asarray(meta["v_obs"])[a : b + 1]
        states, controls = _estimate(s_obs, {"v": v_obs}, None, self.dt, self.estimate, self.noise,
                                     self.jerk_weight, self.arc_length)
        states = np.column_stack([states, window.states[:, states.shape[1]:]])  # the vehicle ahead as recorded
        return Trajectory(states, controls, window.dt, window.metadata)


@dataclass(frozen=True)
class ReplayScene:
    """Recorded tracks as driver-model trajectories (metadata: "Simulators and data" page).

    Attributes
    ----------
    model : PathDriverModel       on a `CompositePath` of every matched route
    trajectories : list of Trajectory   (s, v, a) states; long tracks are cut into pieces (metadata ``piece``)
    skipped : dict {reason: number of tracks}
    n_tracks : int                tracks read (of the replayed agent types)
    repairs : dict {what: count}  route-matching repairs of kept tracks (see module doc)
    selection : {"tracks", "steps"}  how `selected` chooses (module doc)
    steps : dict {what: count}    with ``selection="steps"``: steps of dt kept and left out by the masks
    features : {"paper", "speed-level", "following", "interacting"}  the model's feature set (`pirl_sim.driving.roundabout_features`)
    """

    model: PathDriverModel
    trajectories: list[Trajectory]
    skipped: dict = field(default_factory=dict)
    n_tracks: int = 0
    repairs: dict = field(default_factory=dict)
    selection: str = "tracks"
    steps: dict = field(default_factory=dict)
    track_table: pd.DataFrame | None = None
    rule: SelectionRule | None = None
    profile_path: object = None
    speed_smoothing: float = 0.0
    a_lat: float = DEFAULT_A_LAT
    v_max: float = DEFAULT_V_MAX
    features: str = "paper"

    def history_window(self, trajectory: Trajectory, start: int, stop: int) -> Trajectory:
        """``trajectory.window(start, stop)`` with its states estimated again from the observations of steps
        ``start .. stop`` alone (`HistoryEstimator`): what an online predictor at step ``stop`` can know. The
        whole-piece estimate is a smoother whose states at ``stop`` also saw the steps after it.

        Raises
        ------
        ValueError
            A trajectory that was not read by `load_replay` (no estimator and observations in its metadata), or
            a window of < 2 steps.
        """
        if not isinstance(trajectory.metadata.get("estimator"), HistoryEstimator):
            raise ValueError("history_window needs a trajectory read by load_replay (its metadata's estimator "
                             "and s_obs/v_obs observations)")
        return trajectory.history_window(start, stop)

    def with_desired_speed(self, a_lat: float, v_max: float) -> PathDriverModel:
        """The scene's model with other desired-speed parameters [m/s^2, m/s] (same paths, dynamics and
        feature set)."""
        path = self.profile_path if self.profile_path is not None else self.model.path
        features = roundabout_features(SpeedProfile(path, float(a_lat), float(v_max)),  # type: ignore[arg-type]
                                       self.features)
        return PathDriverModel(self.model.dynamics, features, self.model.bounds, path=self.model.path)

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """The curvature [1/m] the desired speed sees at composite arc lengths s (smoothed by
        ``speed_smoothing``)."""
        path = self.profile_path if self.profile_path is not None else self.model.path
        return SpeedProfile(path, self.a_lat, self.v_max).curvature(  # type: ignore[arg-type]
            np.asarray(s, dtype=float))[0]

    @property
    def selected(self) -> list[Trajectory]:
        """``selection="tracks"``: pieces of tracks that did not interact (the paper's selection);
        ``"steps"``: every piece (PIRL tracks only, each with its ``step_mask``)."""
        if self.selection in ("steps", "free", "all"):
            return list(self.trajectories)
        return [t for t in self.trajectories if not t.metadata["interacted"]]

    @property
    def n_converted(self) -> int:
        """Tracks converted into trajectories (each one or more pieces)."""
        return len({track_key(t) for t in self.trajectories})

    @property
    def n_selected_tracks(self) -> int:
        """Tracks that did not interact."""
        return len({track_key(t) for t in self.selected})


def track_key(trajectory: Trajectory) -> tuple:
    """(file, track_id) of the recorded track a trajectory (piece) comes from."""
    return (trajectory.metadata.get("file"), trajectory.metadata.get("track_id"))


def _connected_frames(unconnected: np.ndarray, max_bridge: int) -> tuple[slice, np.ndarray]:
    """The longest run of frames whose unconnected points come in interior runs of <= max_bridge frames.

    Returns (slice of the kept frames, bool mask over the kept frames of the points to bridge).
    """
    n = len(unconnected)
    good = np.flatnonzero(~unconnected)
    if len(good) == 0:
        return slice(0, 0), np.zeros(0, dtype=bool)
    # consecutive connected frames separated by a run of more than max_bridge unconnected ones start a new part
    breaks = np.flatnonzero(np.diff(good) > max_bridge + 1)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(good) - 1]])
    spans = good[ends] - good[starts]
    best = int(np.argmax(spans))
    a, b = int(good[starts[best]]), int(good[ends[best]]) + 1
    assert 0 <= a < b <= n
    return slice(a, b), unconnected[a:b].copy()


def _project_track(path: ReferencePath, xy: np.ndarray, bridge: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frenet (s, d) [m] of one track's frames ``xy`` (n, 2) on its route: the connected frames projected as a
    track (`ReferencePath.to_frenet` with ``track``), the bridged ones (``bridge``, (n,)) interpolated between."""
    s, d = path.to_frenet(xy[~bridge], extrapolate=True, track=True)
    if not bridge.any():
        return s, d
    k = np.arange(len(xy))
    return np.interp(k, k[~bridge], s), np.interp(k, k[~bridge], d)


def _without_jumps(s: np.ndarray) -> slice:
    """The longest run of a track's frames whose arc length s (n,) [m] never changes by more than `TRACK_STEP`
    from one frame to the next (a jump: the track left its matched route and the projection found a far part of
    it)."""
    breaks = np.flatnonzero(np.abs(np.diff(s)) > TRACK_STEP)
    starts = np.concatenate([[0], breaks + 1])
    stops = np.concatenate([breaks + 1, [len(s)]])
    best = int(np.argmax(stops - starts))
    return slice(int(starts[best]), int(stops[best]))


def leader_gaps(df: pd.DataFrame, rule: SelectionRule) -> np.ndarray:
    """Per row of a track file (columns of the INTERACTION vehicle format): the gap [m] to the nearest vehicle
    ahead in a similar direction (``rule.gap``: bumper to bumper or centre to centre; inf when none), at the
    row's frame. Rows are in the order of ``df``."""
    return leader_gaps_and_speeds(df, rule)[0]


def leader_gaps_and_speeds(df: pd.DataFrame, rule: SelectionRule,
                           max_lateral: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`leader_gaps` and the speed [m/s] of that nearest vehicle ahead (NaN when none), per row of ``df``;
    with ``max_lateral`` [m] only vehicles within that distance of the car's heading line count (a car in
    the next lane is not in the way)."""
    if rule.gap == "bumper" and "length" not in df:
        raise ValueError("bumper-to-bumper gaps need the vehicles' length column; use SelectionRule(gap='centre')")
    out = np.full(len(df), np.inf)
    speed_out = np.full(len(df), np.nan)
    if not len(df):
        return out, speed_out
    vx, vy = df["vx"].to_numpy(dtype=float), df["vy"].to_numpy(dtype=float)
    speeds = np.hypot(vx, vy)
    frames = df["frame_id"].to_numpy()
    # columns as arrays once: indexing the frame's rows of a DataFrame cost 80 % of a file's load time
    xy_all = df[["x", "y"]].to_numpy(dtype=float)
    psi_all = df["psi_rad"].to_numpy(dtype=float) if "psi_rad" in df else np.arctan2(vy, vx)
    length_all = df["length"].to_numpy(dtype=float) if rule.gap == "bumper" else None
    for rows in pd.Series(np.arange(len(df))).groupby(frames, sort=False).indices.values():
        if len(rows) < 2:
            continue
        out[rows], speed_out[rows] = frame_leaders(
            xy_all[rows], psi_all[rows], speeds[rows], None if length_all is None else length_all[rows],
            max_heading_diff_deg=rule.max_heading_diff_deg, max_lateral=max_lateral)
    return out, speed_out


def leader_frames(df: pd.DataFrame, rule: SelectionRule) -> np.ndarray:
    """Per row of a track file: whether the track had a leader at that frame (bool, rows in the order of
    ``df``): a vehicle ahead in a similar direction closer than ``rule.standstill + rule.time_gap * v``."""
    v = np.hypot(df["vx"].to_numpy(dtype=float), df["vy"].to_numpy(dtype=float)) if len(df) else np.zeros(0)
    return leader_gaps(df, rule) < rule.standstill + rule.time_gap * v


def interaction_flags(df: pd.DataFrame, rule: SelectionRule) -> dict[int, bool]:
    """{track_id: interacted} for one track file (columns of the INTERACTION vehicle format): whether the
    track had a leader at any of its frames (`leader_frames`)."""
    lead = leader_frames(df, rule)
    ids = df["track_id"].to_numpy()
    flags = {int(t): False for t in np.unique(ids)}
    for t in np.unique(ids[lead]):
        flags[int(t)] = True
    return flags


GROUND_TRUTH_FILE = "ground_truth.csv"  #: a pirl_sim recording's per-track truth, beside the tracks


def _sidecar(track_file: Path) -> pd.DataFrame | None:
    """The ``ground_truth.csv`` beside a track file, indexed by ``track_id``; None when there is none.

    Raises ValueError naming the file when one is there but unusable (empty, not UTF-8 CSV, no
    ``track_id`` column, a ``track_id`` that is not a whole number or appears twice, a ``style`` that is not
    an integer >= -1, a ``theta_<feature>`` that is not a number > 0, a style >= 0 without weights): its truth
    would otherwise be wrong or missing unnoticed.
    """
    path = track_file.parent / GROUND_TRUTH_FILE
    if not path.is_file():
        return None
    try:
        table = pd.read_csv(path, encoding="utf-8")
    except (pd.errors.EmptyDataError, pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: unreadable ground-truth sidecar ({type(exc).__name__}: {exc}); a sidecar "
                         f"is a CSV with a track_id column (delete it to replay without ground truth)") from None
    if "track_id" not in table:
        raise ValueError(f"{path}: a ground-truth sidecar needs a track_id column, got {list(table.columns)}")
    ids = pd.to_numeric(table["track_id"], errors="coerce")
    bad = ~np.isfinite(ids.to_numpy(dtype=float)) | (ids.to_numpy(dtype=float) % 1 != 0)
    if bad.any():
        raise ValueError(f"{path}: track_id must be whole numbers, got {table['track_id'][bad].tolist()[:5]!r}")
    table["track_id"] = ids.astype(np.int64)
    dup = table["track_id"][table["track_id"].duplicated()]
    if len(dup):
        raise ValueError(f"{path}: each track_id must appear once, got duplicates {sorted(set(dup.tolist()))[:5]}")
    for col in [c for c in table.columns if c == "style" or str(c).startswith("theta_")]:
        values = pd.to_numeric(table[col], errors="coerce")
        wrong = values.isna() & table[col].notna()
        if wrong.any():
            raise ValueError(f"{path}: column {col} must hold numbers, got {table[col][wrong].tolist()[:5]!r}")
        table[col] = values
    style = table["style"].to_numpy(dtype=float) if "style" in table else np.full(len(table), np.nan)
    wrong = ~np.isnan(style) & ~(np.isfinite(style) & (style >= -1) & (np.floor(style) == style))
    if wrong.any():
        i = int(np.argmax(wrong))
        raise ValueError(f"{path}: style must be an integer >= 0 (a PIRL driver's), -1 (background traffic) or empty, "
                         f"got {float(style[i])!r} for track {int(table['track_id'].iloc[i])}")
    theta_cols = [c for c in table.columns if str(c).startswith("theta_")]
    if not theta_cols and (style >= 0).any():
        i = int(np.argmax(style >= 0))
        raise ValueError(f"{path}: track {int(table['track_id'].iloc[i])} has a style >= 0 but the sidecar has no "
                         f"theta_<feature> columns; a PIRL driver (style >= 0) needs its weights, background traffic "
                         f"(style -1) none")
    if theta_cols:
        theta = table[theta_cols].to_numpy(dtype=float)
        known = np.isfinite(theta)
        bad = ~np.isnan(theta) & ~(known & (theta > 0))  # -inf, inf, 0 or negative
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise ValueError(f"{path}: weights must be finite and > 0 (empty where unknown), got "
                             f"{theta_cols[j]} = {float(theta[i, j])!r} for track {int(table['track_id'].iloc[i])} "
                             f"({int(bad.any(axis=1).sum())} track(s) with such weights)")
        partly = known.any(axis=1) & ~known.all(axis=1)
        styled = style >= 0
        unknown = (partly | (styled & ~known.all(axis=1)))
        if unknown.any():
            i = int(np.argmax(unknown))
            raise ValueError(f"{path}: track {int(table['track_id'].iloc[i])} has a style >= 0 or some weights but "
                             f"misses weights (empty {[c for c, k in zip(theta_cols, known[i]) if not k]}); "
                             f"{int(unknown.sum())} track(s) so; a PIRL driver (style >= 0) needs every "
                             f"theta column, background traffic (style -1) none")
    return table.set_index("track_id")


def _check_truth_rows(path: Path, truth: pd.DataFrame, track_ids: np.ndarray) -> None:
    """ValueError naming the sidecar when a track of the file ``path`` has no row in it (its weight errors
    would silently leave it out)."""
    without_row = sorted(set(int(t) for t in np.unique(track_ids)) - set(int(t) for t in truth.index))
    if without_row:
        raise ValueError(f"{path.parent / GROUND_TRUTH_FILE}: no row for {len(without_row)} track(s) of "
                         f"{path.name} (e.g. {without_row[:5]}); the sidecar needs one row per track")


def _truth_ids(truth_ids: dict, file: Path, truth: pd.DataFrame) -> tuple[set, set, set, list]:
    """The entry of ``truth_ids`` (`load_replay`) of the sidecar beside ``file``, added when missing."""
    return truth_ids.setdefault(file.parent, (set(int(t) for t in truth.index), set(), set(), [0]))


def load_replay(
    track_files: Sequence[str | Path],
    map_path: str | Path,
    *,
    dt: float = 0.2,
    rule: SelectionRule = SelectionRule(),
    max_offset: float = 3.0,
    jerk_weight: float = 1e-2,
    max_steps: int | None = 100,
    estimate: str = "positions",
    noise: EstimateNoise = MEASURED_NOISE,
    selection: str = "tracks",
    min_usable_steps: int = 10,
    smoothing: float = DEFAULT_SMOOTHING,
    speed_smoothing: float = 0.0,
    a_lat: float = DEFAULT_A_LAT,
    v_max: float = DEFAULT_V_MAX,
    arc_length: str = "fit",
    settle_frames: int | None = None,
    features: str = "paper",
    conflicts: ConflictRule = ConflictRule(),
) -> ReplayScene:
    """Read track files recorded on one map into a `ReplayScene` ("Simulators and data" page: Recorded tracks into
    trajectories, and "In detail: load_replay" for every parameter in full).

    Parameters
    ----------
    track_files, map_path : paths of ``vehicle_tracks_*.csv`` (`pirl_sim.io.interaction.find_track_files`), OSM map
    dt, max_steps : float [s], int or None   model step (multiple of 0.1 s); longer tracks cut into pieces (``piece``)
    rule, max_offset, conflicts : SelectionRule, float [m], ConflictRule   interactions; route matching; yielding
    estimate, noise, jerk_weight : str, EstimateNoise, float   state estimate (`MEASURED_NOISE`; `SIMULATED_NOISE`)
    selection, min_usable_steps, settle_frames : str, int, int or None   ``"steps"``: ``driver_steps.csv`` masks
    smoothing, speed_smoothing, a_lat, v_max : float   [m] reference paths, v_des curvature; [m/s^2, m/s] v_des
    arc_length : {"fit", "observed"}   s from the estimate (real data) or the projected positions
    features : {"paper", "speed-level", "following", "interacting"}   the feature set (`pirl_sim.driving.roundabout_features`)
    """
    from .demonstrations import SETTLE_FRAMES

    settle_frames = SETTLE_FRAMES if settle_frames is None else settle_frames
    if isinstance(settle_frames, bool) or not isinstance(settle_frames, (int, np.integer)) or settle_frames < 0:
        raise ValueError(f"settle_frames must be a whole number of frames >= 0, got {settle_frames!r}")
    if features not in FEATURE_SETS:
        raise ValueError(f"features must be one of {FEATURE_SETS}, got {features!r}")
    if arc_length not in ("fit", "observed"):
        raise ValueError(f"arc_length must be one of ('fit', 'observed'), got {arc_length!r}")
    if estimate not in ESTIMATES:
        raise ValueError(f"estimate must be one of {ESTIMATES}, got {estimate!r}")
    if selection not in SELECTIONS:
        raise ValueError(f"selection must be one of {SELECTIONS}, got {selection!r}")
    if not isinstance(noise, EstimateNoise):
        raise TypeError(f"noise must be an EstimateNoise, got {type(noise).__name__}")
    if not is_positive_int(min_usable_steps):
        raise ValueError(f"min_usable_steps must be a positive integer, got {min_usable_steps!r}")
    for name, value in (("smoothing", smoothing), ("speed_smoothing", speed_smoothing)):
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"{name} must be >= 0 m, got {value!r}")
    from pirl_sim.io.interaction import read_tracks, read_tracks_lenient
    from pirl_sim.io.lanelet2_map import load_map, match_route

    stride = int(round(dt / FRAME_DT))
    if stride < 1 or not np.isclose(stride * FRAME_DT, dt):
        raise ValueError(f"dt must be a positive multiple of the {FRAME_DT} s frames, got {dt!r}")
    lmap = load_map(map_path)  # a map that fails to load is an error for the whole scene
    skipped: Counter = Counter()
    repairs: Counter = Counter()
    paths: dict[tuple[int, ...], int] = {}
    path_list: list[ReferencePath] = []
    pending = []  # (segment, s_local (n,), d (n,), xy (n, 2), meta)
    n_tracks = 0
    n_steps_counts: Counter = Counter()
    # sidecar directory -> (its track ids, ids of tracks read, names of the files read, tracks dropped as broken)
    truth_ids: dict[Path, tuple[set, set, set, list]] = {}
    for file in (Path(f) for f in track_files):
        steps_flags = None
        if selection == "steps":
            steps_flags = _driver_steps(file)
        truth = _sidecar(file)  # before the tracks: an unusable sidecar is an error, never another file's truth
        try:
            df = read_tracks(file)
        except FileNotFoundError as exc:
            skipped["unreadable file"] += 1
            log.warning("skipping %s: %s", file, exc)
            continue
        except ValueError as exc:
            # a bad row should not cost the file's good tracks: read leniently, drop the broken tracks
            log.warning("%s failed validation (%s); keeping its valid tracks", file, exc)
            df, n_bad = read_tracks_lenient(file)
            skipped["invalid rows (track dropped)"] += n_bad
            if truth is not None:
                _truth_ids(truth_ids, file, truth)[3][0] += max(n_bad, 1)
            if df is None:
                if not n_bad:
                    skipped["unreadable file"] += 1
                continue
        if truth is not None:
            _check_truth_rows(file, truth, df["track_id"].to_numpy())
            _, read, names, _ = _truth_ids(truth_ids, file, truth)
            read.update(int(t) for t in df["track_id"].unique())
            names.add(file.name)
        df = df[df["agent_type"].isin(rule.agent_types)].reset_index(drop=True)
        lead = leader_frames(df, rule)
        lead_centre = leader_frames(df, CENTRE_RULE)
        if features in GAP_FEATURE_SETS:
            gaps_all, lead_speed_all = leader_gaps_and_speeds(df, SelectionRule(gap="bumper"), max_lateral=2.0)
        ids = df["track_id"].to_numpy()
        flags = {int(t): bool(lead[ids == t].any()) for t in np.unique(ids)}
        flags_centre = {int(t): bool(lead_centre[ids == t].any()) for t in np.unique(ids)}
        for track_id, track in df.groupby("track_id", sort=True):
            n_tracks += 1
            track = track.sort_values("frame_id")
            if (len(track) - 1) * FRAME_DT < rule.min_duration:
                skipped["shorter than min_duration"] += 1
                continue
            frames = track["frame_id"].to_numpy()
            lead_t = lead[track.index.to_numpy()]
            if np.any(np.diff(frames) != 1):
                skipped["gap in frames"] += 1
                continue
            if steps_flags is not None and int(track_id) not in steps_flags:
                skipped["no driver steps (not a PIRL driver)"] += 1
                continue
            xy = track[["x", "y"]].to_numpy()
            try:
                match = match_route(lmap, xy, max_offset=max_offset, psi=track["psi_rad"].to_numpy())
            except ValueError as exc:
                skipped["no route on the map"] += 1
                log.info("track %s of %s skipped: %s", track_id, file.name, exc)
                continue
            keep, bridge = _connected_frames(match.unconnected, MAX_BRIDGE)
            if match.n_unconnected:
                cut = match.n_unconnected - int(bridge.sum())
                repairs["unconnected positions bridged"] += int(bridge.sum())
                if cut:
                    repairs["unconnected positions cut off"] += cut
                    repairs["tracks cut at a break in the route"] += 1
                log.info("track %s of %s: %d positions unconnected to its route (%d bridged)", track_id,
                         file.name, match.n_unconnected, int(bridge.sum()))
            if (keep.stop - keep.start - 1) * FRAME_DT < rule.min_duration:
                skipped["shorter than min_duration after cutting at a break in the route"] += 1
                continue
            xy = xy[keep]
            speed = np.hypot(track["vx"].to_numpy(), track["vy"].to_numpy())[keep]
            psi = track["psi_rad"].to_numpy(dtype=float)[keep]  # [rad] recorded heading (the miss rate's)
            usable = restart = None
            if steps_flags is not None:
                f = steps_flags[int(track_id)].reindex(frames[keep])
                usable = f["usable"].fillna(False).to_numpy(dtype=bool)
                restart = f["restart"].fillna(False).to_numpy(dtype=bool)
            key = tuple(match.lanelet_ids)
            if key not in paths:
                paths[key] = len(path_list)
                path_list.append(ReferencePath.from_polyline(match.centerline, smoothing=smoothing))
            try:
                s_local, d = _project_track(path_list[paths[key]], xy, bridge)
            except ValueError as exc:
                skipped["no route on the map"] += 1
                log.info("track %s of %s skipped: %s", track_id, file.name, exc)
                continue
            part = _without_jumps(s_local)
            if part != slice(0, len(xy)):
                repairs["tracks cut at a jump along their route"] += 1
                repairs["positions cut off at a jump along their route"] += len(xy) - (part.stop - part.start)
                log.info("track %s of %s: its arc length jumps by more than %g m (cut to frames %d-%d of %d)",
                         track_id, file.name, TRACK_STEP, part.start, part.stop, len(xy))
                if (part.stop - part.start - 1) * FRAME_DT < rule.min_duration:
                    skipped["shorter than min_duration after cutting at a jump along its route"] += 1
                    continue
                keep = slice(keep.start + part.start, keep.start + part.stop)
                xy, speed, psi, s_local, d = xy[part], speed[part], psi[part], s_local[part], d[part]
                if usable is not None:
                    usable, restart = usable[part], restart[part]  # type: ignore[index]
            sel = slice(0, None, stride)
            meta = {"track_id": int(track_id), "file": str(file), "route": key, "interacted": flags[int(track_id)],
                    "interacted_centre": flags_centre[int(track_id)]}
            if truth is not None and int(track_id) in truth.index:
                row = truth.loc[int(track_id)]
                meta["truth"] = row.to_dict()
            extra = {"v": speed[sel], "psi": psi[sel], "free": _free_steps(lead_t[keep], stride)}
            if features in GAP_FEATURE_SETS:
                rows_k = track.index.to_numpy()[keep]
                extra["gap"], extra["v_lead"] = obstacle(gaps_all[rows_k], lead_speed_all[rows_k], speed)
                extra["gap"], extra["v_lead"] = extra["gap"][sel], extra["v_lead"][sel]
            meta["_motion"] = TrackMotion(frames[keep], s_local, speed, xy,
                                          track["psi_rad"].to_numpy(dtype=float)[keep], path_list[paths[key]])
            if usable is not None:
                extra["usable"], extra["a_obs"] = _frame_steps(usable, restart, speed, stride)  # type: ignore[arg-type]
                extra["settled"] = _frame_steps(settled(usable, settle_frames),
                                                restart, speed, stride)[0]  # type: ignore[arg-type]
            pending.append((paths[key], s_local[sel], d[sel], xy[sel], dict(meta, _extra=extra)))
    for directory, (rows, read, names, dropped) in truth_ids.items():
        unmatched = sorted(rows - read)
        others = sorted({p.name for p in directory.glob("vehicle_tracks_*.csv")} - names)
        if unmatched and not others and not dropped[0]:  # every track beside the sidecar was read: its rows are wrong
            raise ValueError(f"{directory / GROUND_TRUTH_FILE}: {len(unmatched)} row(s) match no track of "
                             f"{', '.join(sorted(names))} (e.g. track_id {unmatched[:5]}); the sidecar holds one row "
                             "per track of the track file(s) beside it and no other")
        if unmatched:  # other files' tracks, or tracks dropped as broken: no truth goes missing
            log.warning("%s: %d ground-truth row(s) match no track read from this directory (e.g. %s; %s); ignored",
                        directory / GROUND_TRUTH_FILE, len(unmatched), unmatched[:5],
                        f"track files not read: {others[:3]}" if others else "tracks dropped as broken")
    if not pending:
        raise ValueError(f"no usable track in {len(list(track_files))} files (skipped: {dict(skipped)})")
    composite = CompositePath(tuple(path_list))
    placed = []
    for segment, s_local, d, xy, meta in pending:
        low, high = composite.local_range(segment)
        if s_local.min() < low or s_local.max() > high:  # would fall onto a neighbouring route's share
            skipped["runs more than half a route gap beyond its route's ends"] += 1
            log.info("track %s of %s skipped: local arc lengths [%.0f, %.0f] m outside [%.0f, %.0f] m",
                     meta["track_id"], Path(meta["file"]).name,  # type: ignore[arg-type]
                     s_local.min(), s_local.max(), low, high)
            continue
        placed.append((segment, s_local, d, xy, meta))
    pending = placed
    if not pending:
        raise ValueError(f"no usable track in {len(list(track_files))} files (skipped: {dict(skipped)})")
    _add_yield_gaps(pending, stride, conflicts if features == "following" else
                    dataclasses.replace(conflicts, obstacle="stop"),
                    "merge" if features == "following" else "separate" if features == "interacting" else "flag")
    model = _replay_model(composite, dt, speed_smoothing, a_lat, v_max, features)
    estimator = HistoryEstimator(float(dt), estimate, noise, jerk_weight, arc_length)
    names = model.features.names  # type: ignore[assignment]
    trajectories = []
    track_rows = []
    if max_steps is not None and not is_positive_int(max_steps):
        raise ValueError(f"max_steps must be a positive integer or None, got {max_steps!r}")
    pieces = []
    for segment, s_local, d, xy, meta in pending:
        n = len(s_local) - 1
        size = n if max_steps is None else max_steps
        starts = list(range(0, max(n - 1, 1), size))
        extra = meta.pop("_extra")  # type: ignore[assignment]
        for p, a in enumerate(starts):
            b = min(a + size, n)
            if b - a < 2:
                continue
            cut = {k: v[a : b + 1] for k,  # type: ignore[assignment]
                   v in extra.items() if k not in ("usable", "settled", "free")}
            cut["free"] = extra["free"][a:b]  # type: ignore[index]
            if "usable" in extra:
                cut["estimate_mask"], cut["step_mask"] = (extra["usable"][a:b],  # type: ignore[index]
                                                          extra["settled"][a:b])
            pieces.append((segment, s_local[a : b + 1], d[a : b + 1], xy[a : b + 1], dict(meta, piece=p), cut))
    for segment, s_local, d, xy, meta, cut in pieces:
        mask = cut.get("step_mask")  # type: ignore[attr-defined]
        if mask is not None:
            n_steps_counts["steps"] += len(mask)
            own = cut["estimate_mask"]  # type: ignore[index]
            n_steps_counts["steps not the driver's own (masked)"] += int((~own).sum())
            n_steps_counts["steps settling after a restart (masked)"] += int((own & ~mask).sum())
            if int(mask.sum()) < min_usable_steps:
                skipped["pieces with fewer than min_usable_steps driver's own steps"] += 1
                n_steps_counts["steps of pieces skipped for too few usable steps"] += len(mask)
                continue
        s = s_local + composite.offsets[segment]  # type: ignore[attr-defined]
        states, controls = _estimate(s, cut, cut.get("estimate_mask"), dt, estimate,  # type: ignore[attr-defined]
                                     noise, jerk_weight, arc_length)
        if features in GAP_FEATURE_SETS:  # the vehicle ahead as recorded (`pirl_sim.dynamics.following`)
            states = np.column_stack([states, cut["gap"], cut["v_lead"]])  # type: ignore[index]
            if "yield_gap" in cut:  # type: ignore[operator]  # features "interacting": the obstacle yielded to
                states = np.column_stack([states, *obstacle(cut["yield_gap"], np.zeros(len(states)),  # type: ignore
                                                            cut["v"])])  # type: ignore[index]
            yielding = cut["yielding"]  # type: ignore[index]
            meta = dict(meta, yielding=yielding)
            n_steps_counts["steps yielding at a conflict point"] += int(yielding[:-1].sum())
            n_steps_counts["steps behind a vehicle ahead"] += int(((cut["gap"] < NO_LEADER_GAP) &  # type: ignore[index]
                                                                   ~yielding)[:-1].sum())
        meta = dict(meta, segment=segment, d=np.asarray(d), xy=np.asarray(xy), s_obs=np.asarray(s),
                    yields=np.asarray(cut["yields"]),  # type: ignore[index]
                    v_obs=np.asarray(cut["v"]), psi_obs=np.asarray(cut["psi"]),  # type: ignore[index]
                    estimator=estimator)
        if mask is not None:
            meta["step_mask"] = mask
        truth = meta.pop("truth", None)
        given = [] if truth is None else [k for k in truth if str(k).startswith("theta_")]  # type: ignore[attr-defined]
        if given and not all(f"theta_{n}" in truth for n in names):  # type: ignore[operator]
            missing = [f"theta_{n}" for n in names if f"theta_{n}" not in truth]  # type: ignore[operator]
            raise ValueError(f"{Path(meta['file']).parent / GROUND_TRUTH_FILE}: "  # type: ignore[arg-type]
                             "weights without the column(s) "
                             f"{', '.join(missing)}; the replay's features need {', '.join(f'theta_{n}' for n in names)}")
        if truth is not None and all(f"theta_{n}" in truth for n in names):  # type: ignore[operator]
            theta = np.array([float(truth[f"theta_{n}"]) for n in names])  # type: ignore[index]
            if np.all(np.isfinite(theta)) and np.all(theta > 0):
                meta["theta"] = model.features.normalize(theta)
            if "style" in truth and np.isfinite(truth["style"]):  # type: ignore[index, operator]
                meta["style"] = int(truth["style"])  # type: ignore[index]
        free = cut["free"]  # type: ignore[index]
        track_rows.append({"file": meta["file"], "track_id": meta["track_id"], "piece": meta["piece"],
                           "n_steps": len(free), "interacted": meta["interacted"],
                           "interacted_centre": meta["interacted_centre"], "free_steps": int(free.sum()),
                           "longest_free_run": max((b - a for a, b in _runs(free)), default=0)})
        if selection == "free":
            n_steps_counts["steps"] += len(free)
            n_steps_counts["steps with a leader (left out)"] += int((~free).sum())
            for r, (a, b) in enumerate(_runs(free)):
                if b - a < 2:
                    n_steps_counts["free steps in runs shorter than 2 steps (left out)"] += b - a
                    continue
                cut_meta = {k: meta[k][a : b + 1]  # type: ignore[index]
                            for k in ("d", "xy", "yielding", "yields", "s_obs", "v_obs", "psi_obs") if k in meta}
                trajectories.append(Trajectory(states[a : b + 1], controls[a:b], dt,
                                               dict(meta, **cut_meta, free_run=r, free_start=a)))
            continue
        trajectories.append(Trajectory(states, controls, dt, meta))
    if not trajectories:
        raise ValueError(f"no usable track in {len(list(track_files))} files (skipped: {dict(skipped)})")
    if selection == "steps":
        n_steps_counts["steps kept (driver's own)"] = sum(int(t.metadata["step_mask"].sum()) for t in trajectories)
    for reason, count in skipped.items():
        log.warning("%d tracks skipped: %s", count, reason)
    for what, count in repairs.items():
        log.warning("route matching: %d %s", count, what)
    if selection == "free":
        n_steps_counts["steps kept (free flow)"] = sum(t.n_steps for t in trajectories)
    return ReplayScene(model, trajectories, dict(skipped), n_tracks, dict(repairs), selection, dict(n_steps_counts),
                       pd.DataFrame(track_rows), rule, _profile_path(model.path, speed_smoothing), speed_smoothing,
                       a_lat, v_max, features)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of every maximal run of True in a bool array."""
    f = np.concatenate([[False], np.asarray(flags, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(f.astype(int)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _free_steps(lead: np.ndarray, stride: int) -> np.ndarray:
    """Per step of ``stride`` frames: free flow (no leader at any of its frames, both ends included)."""
    n_steps = (len(lead) - 1) // stride
    idx = np.arange(n_steps)[:, None] * stride + np.arange(stride + 1)[None, :]
    return ~lead[idx].any(axis=1)


def selection_counts(scene: ReplayScene, min_steps: int) -> pd.DataFrame:
    """Matched car tracks usable under each selection rule: one row per rule with ``usable`` tracks (at least
    one piece of >= ``min_steps`` steps that the rule keeps: a whole piece without a leader, or a free-flow
    run), ``matched`` (tracks whose states were estimated) and ``share``. Rules: `CENTRE_RULE` on whole
    tracks, the scene's rule on whole tracks, and the scene's rule on free-flow runs."""
    t = scene.track_table
    if t is None or t.empty:
        return pd.DataFrame(columns=["rule", "selection", "usable", "matched", "share"])
    rule = scene.rule or SelectionRule()
    long_piece = t["n_steps"] >= min_steps
    key = ["file", "track_id"]
    matched = t[key].drop_duplicates().shape[0]
    cases = [(CENTRE_RULE.describe(), "whole tracks without a leader (the rule before)",
              long_piece & ~t["interacted_centre"]),
             (rule.describe(), "whole tracks without a leader", long_piece & ~t["interacted"]),
             (rule.describe(), "free-flow runs (steps with a leader left out)", t["longest_free_run"] >= min_steps),
             ("any", "whole tracks, leaders included (selection 'all')", long_piece)]
    rows = []
    for name, how, ok in cases:
        usable = t.loc[ok, key].drop_duplicates().shape[0]
        rows.append({"rule": name, "selection": how, "usable": usable, "matched": matched,
                     "share": usable / matched if matched else np.nan})
    return pd.DataFrame(rows)


def _profile_path(composite, speed_smoothing: float):
    """The path whose curvature the desired speed sees: ``composite`` with its curvature smoothed per path by
    ``speed_smoothing`` [m] (as `pirl_sim.scenarios.drivers.RouteSet`), or ``composite`` itself."""
    if speed_smoothing <= 0:
        return composite
    from .route_set import _smoothed

    kappa = composite.kappa.copy()
    for p, off in zip(composite.segments, composite.offsets):
        on = (composite.s >= off - 1e-9) & (composite.s <= off + p.length + 1e-9)
        kappa[on] = np.interp(composite.s[on] - off, p.s, _smoothed(p.s, p.kappa, speed_smoothing))
    profile_path = copy.copy(composite)  # same geometry; only the speed profile sees the smoothed kappa
    object.__setattr__(profile_path, "kappa", kappa)
    return profile_path


def _replay_model(composite: CompositePath, dt: float, speed_smoothing: float, a_lat: float,
                  v_max: float, features: str = "paper") -> PathDriverModel:
    """The roundabout model on ``composite`` (`pirl_sim.driving.roundabout_model`), its desired speed from
    the curvature smoothed per path by ``speed_smoothing`` [m] (as `pirl_sim.scenarios.drivers.RouteSet`)."""
    profile_path = _profile_path(composite, speed_smoothing)
    dynamics = (following(dt, obstacles=2) if features == "interacting" else following(dt)
                if features in GAP_FEATURE_SETS else longitudinal(dt))
    features = roundabout_features(SpeedProfile(profile_path, a_lat, v_max), features)  # type: ignore[assignment]
    return PathDriverModel(dynamics, features, DEFAULT_BOUNDS, path=composite)  # type: ignore[arg-type]


def _add_yield_gaps(pending, stride: int, rule: ConflictRule, mode: str = "merge") -> None:
    """Per recording file: what a car yields to (`pirl_sim.scenarios.conflicts.yield_gaps`), ``yields`` (its
    sampled steps with a conflict point to yield at) for every feature set, and with ``mode`` "merge" written
    into each pending track's sampled ``gap`` / ``v_lead`` where nearer than the vehicle ahead, with "separate"
    into ``yield_gap`` (inf where none), with "flag" nothing more."""
    by_file: dict[str, list] = {}
    for item in pending:
        by_file.setdefault(item[4]["file"], []).append(item)
    for items in by_file.values():
        motions = [it[4].pop("_motion") for it in items]
        which = [np.arange(0, len(m.frames), stride) for m in motions]
        gaps = yield_gaps(motions, rule, which)
        for it, (g, v), w in zip(items, gaps, which):
            extra = it[4]["_extra"]
            g, v = g[w], v[w]  # the frames the track is sampled at, as its extra["gap"]
            extra["yields"] = np.isfinite(g)
            if mode == "flag":
                continue
            if mode == "separate":
                extra["yield_gap"], extra["yielding"] = g, np.isfinite(g)
                continue
            nearer = g < extra["gap"]
            extra["gap"] = np.where(nearer, g, extra["gap"])
            extra["v_lead"] = np.where(nearer, v, extra["v_lead"])
            extra["yielding"] = nearer


def _driver_steps(track_file: Path) -> dict[int, pd.DataFrame]:
    """{track_id: per-frame flags with ``usable`` and ``restart``} from the ``driver_steps.csv`` beside a
    track file (as `pirl_sim.scenarios.demonstrations.recorded_demonstrations` reads them)."""
    from types import SimpleNamespace

    from .demonstrations import _frame_flags

    path = track_file.parent / DRIVER_STEPS_FILE
    if not path.is_file():
        raise ValueError(f"selection='steps' needs per-step driver flags ({DRIVER_STEPS_FILE}) beside "
                         f"{track_file}; real data have none: use selection='tracks'")
    from pirl_sim.io.tables import read_csv_table

    steps = read_csv_table(path, dtype={"track_id": np.int64, "frame_id": np.int64, "commanded": bool,
                                        "overridden": bool, "collided": bool})
    missing = [c for c in DRIVER_STEP_FLAGS if c not in steps.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)}; per-step driver flags need the columns "
                         f"{', '.join(DRIVER_STEP_FLAGS)}")
    return _frame_flags(SimpleNamespace(driver_steps=steps))  # type: ignore[arg-type]


def _frame_steps(usable: np.ndarray, restart: np.ndarray, speed: np.ndarray, stride: int):
    """Per step of ``stride`` frames: usable (all its frames are) and the measured restart acceleration per
    sampled frame (NaN where none), as `pirl_sim.scenarios.demonstrations.recorded_demonstrations`."""
    from .demonstrations import _A_HI, _A_LO

    n_steps = (len(usable) - 1) // stride
    mask = usable[: n_steps * stride].reshape(n_steps, stride).all(axis=1)
    restart = restart.copy()
    restart[0] = False
    k = np.flatnonzero(restart)
    a = np.full(len(usable), np.nan)
    a[k] = np.clip((speed[k] - speed[k - 1]) / FRAME_DT, _A_LO, _A_HI)
    stopped = k[speed[k] <= 0.0]
    a[stopped] = np.maximum(a[stopped], 0.0)
    return mask, a[::stride]


def _estimate(s, cut, mask, dt, estimate, noise, jerk_weight, arc_length="fit"):
    """(states, controls) of one piece (module doc): (s, v, a) at model step dt [s], whatever the model's
    further state entries; with ``arc_length="observed"`` the states' s is the observed one."""
    dyn = longitudinal(dt)
    if estimate == "speeds":
        states, controls = estimate_longitudinal_states(
            s, dyn, v_obs=cut["v"], sigma_s=noise.sigma_s, sigma_v=noise.sigma_v, sigma_j=noise.sigma_j,
            a_obs=cut.get("a_obs"), sigma_a=noise.sigma_a, step_mask=mask)
    elif mask is None or mask.all():
        states, controls = fit_longitudinal_states(s, dyn, jerk_weight=jerk_weight)
    else:
        states, controls = estimate_longitudinal_states(s, dyn, sigma_s=1.0, sigma_j=jerk_weight ** -0.5,
                                                        step_mask=mask)
    if arc_length == "observed":
        states = states.copy()
        states[:, 0] = s
    return states, controls
