"""One writer for every simulated scenario: INTERACTION tracks, a ground-truth sidecar and a Lanelet2 map.

Every simulator turns its run into a :class:`ScenarioRecording`; :func:`write_recording` writes it into a
directory (``vehicle_tracks_000.csv``, ``ground_truth.csv`` with :data:`GROUND_TRUTH_COLUMNS`, ``map.osm``,
``driver_steps.csv`` with :data:`DRIVER_STEP_COLUMNS` where the simulator reports it, and ``run.json``, written
last) and :func:`read_recording` reads it back. Every file is written atomically; a directory holds one
recording, and one without ``run.json`` is refused as incomplete. Units: SI (m, s, m/s, rad).

Files and columns are described in the documentation's "File formats" page (simulated recordings).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import pandas as pd

from pirl_sim.io.atomic import atomic_write_text
from pirl_sim.io.interaction import FRAME_DT_MS, VEHICLE_COLUMNS, read_tracks, write_tracks
from pirl_sim.io.tables import read_csv_table

__all__ = [
    "TRACK_COLUMNS",
    "GROUND_TRUTH_COLUMNS",
    "INTERACTING_GROUND_TRUTH_COLUMNS",
    "THETA_FEATURES",
    "INTERACTION_THETA_FEATURES",
    "STATUSES",
    "TRACKS_FILE",
    "GROUND_TRUTH_FILE",
    "MAP_FILE",
    "INFO_FILE",
    "FORMAT_VERSION",
    "DRIVER_STEPS_FILE",
    "DRIVER_STEP_COLUMNS",
    "ScenarioRecording",
    "RecordingFiles",
    "interaction_tracks",
    "write_recording",
    "read_recording",
]

TRACKS_FILE = "vehicle_tracks_000.csv"
GROUND_TRUTH_FILE = "ground_truth.csv"
MAP_FILE = "map.osm"
INFO_FILE = "run.json"
DRIVER_STEPS_FILE = "driver_steps.csv"
FORMAT_VERSION = 1
FRAME_DT_S = FRAME_DT_MS / 1000.0  # [s]
_GRID_TOL = 1e-6  # [frames] times must sit this close to the 100 ms grid

#: features whose ground-truth weights the sidecar holds (the roundabout driver model's, in its order)
THETA_FEATURES: tuple[str, ...] = ("speed_dev", "acc_sq", "jerk_sq")
#: and, after them, of drivers who interact (`pirl_sim.scenarios.population_config.INTERACTION_FEATURES`)
INTERACTION_THETA_FEATURES: tuple[str, ...] = ("headway", "yielding")
#: what became of a track: left at the end of its route, taken out early, or still driving at the end
STATUSES: tuple[str, ...] = ("arrived", "vanished", "running")

#: columns of :attr:`ScenarioRecording.tracks`: one row per track per frame
TRACK_COLUMNS: tuple[str, ...] = (
    "track_id", "time_s", "agent_type", "x", "y", "vx", "vy", "psi_rad", "length", "width",
)


def _ground_truth_columns(features: tuple[str, ...]) -> tuple[str, ...]:
    return ("track_id", "agent_id", "route_id", "is_pirl", "style", "style_name", *(f"theta_{f}" for f in features),
            "interacted", "collided", "removed_early", "overridden_fraction", "status", "n_frames")


#: columns of :attr:`ScenarioRecording.ground_truth` and ``ground_truth.csv``: one row per track
GROUND_TRUTH_COLUMNS: tuple[str, ...] = _ground_truth_columns(THETA_FEATURES)
#: the same with the interaction weights, for a population of drivers who interact
INTERACTING_GROUND_TRUTH_COLUMNS: tuple[str, ...] = _ground_truth_columns(THETA_FEATURES + INTERACTION_THETA_FEATURES)
_GT_DTYPES = {
    "track_id": "int64", "agent_id": "object", "route_id": "object", "is_pirl": "bool", "style": "int64",
    "style_name": "object", **{f"theta_{f}": "float64" for f in THETA_FEATURES + INTERACTION_THETA_FEATURES},
    "interacted": "boolean", "collided": "bool", "removed_early": "bool", "overridden_fraction": "float64",
    "status": "object", "n_frames": "int64",
}
#: columns of :attr:`ScenarioRecording.driver_steps` and ``driver_steps.csv``: one row per PIRL track per frame
DRIVER_STEP_COLUMNS: tuple[str, ...] = ("track_id", "frame_id", "commanded", "overridden", "collided",
                                        "command_error")
BACKGROUND_STYLE = -1  #: ``style`` of background traffic
BACKGROUND_STYLE_NAME = "background"  #: ``style_name`` of background traffic


@dataclass(frozen=True, eq=False)
class ScenarioRecording:
    """A simulated run in simulator-neutral form (validated on construction, ValueError; file-formats page).

    Attributes
    ----------
    tracks : pandas.DataFrame               `TRACK_COLUMNS`; ``time_s`` [s] on the 100 ms grid, >= 0.1 s; any row order
    ground_truth : pandas.DataFrame         `GROUND_TRUTH_COLUMNS` (`INTERACTING_GROUND_TRUTH_COLUMNS` for drivers who
                                            interact), one row per track, sorted by ``track_id``
    lanes : mapping str -> numpy.ndarray    lane centerlines (P, 2) [m] for the map
    successors : mapping str -> sequence of str   lane successors for the map
    info : mapping                          JSON-serialisable description of the run, without wall-clock times
    driver_steps : pandas.DataFrame or None   per-step flags of the PIRL drivers (`DRIVER_STEP_COLUMNS`), exactly
                                            the PIRL tracks' frames; None: not recorded
    """

    tracks: pd.DataFrame
    ground_truth: pd.DataFrame
    lanes: Mapping[str, np.ndarray]
    successors: Mapping[str, Sequence[str]]
    info: Mapping[str, Any]
    driver_steps: pd.DataFrame | None = None

    def __post_init__(self) -> None:
        tracks, gt = self.tracks, self.ground_truth
        interacting = isinstance(gt, pd.DataFrame) and tuple(gt.columns) == INTERACTING_GROUND_TRUTH_COLUMNS
        gt_cols = INTERACTING_GROUND_TRUTH_COLUMNS if interacting else GROUND_TRUTH_COLUMNS
        for label, df, cols in (("tracks", tracks, TRACK_COLUMNS), ("ground_truth", gt, gt_cols)):
            if not isinstance(df, pd.DataFrame):
                raise ValueError(f"{label} must be a pandas DataFrame, got {type(df).__name__}")
            if tuple(df.columns) != cols:
                missing = [c for c in cols if c not in df.columns]
                extra = [c for c in df.columns if c not in cols]
                raise ValueError(f"{label} must have the columns {', '.join(cols)} in this order; missing: "
                                 f"{missing or 'none'}, unknown: {extra or 'none'}")
        if len(tracks) == 0:
            raise ValueError("tracks has no rows: the run recorded no vehicle")
        frames = _frames(tracks["time_s"].to_numpy(dtype=float))
        ids = tracks["track_id"].to_numpy()
        if ids.dtype.kind not in "iu" or ids.min() < 1:
            raise ValueError("track_id must be integers >= 1")
        gt_ids = gt["track_id"].to_numpy()
        if len(set(gt_ids.tolist())) != len(gt_ids):
            raise ValueError("ground_truth repeats a track_id")
        if set(gt_ids.tolist()) != set(ids.tolist()):
            only_tracks = sorted(set(ids.tolist()) - set(gt_ids.tolist()))
            only_gt = sorted(set(gt_ids.tolist()) - set(ids.tolist()))
            raise ValueError(f"tracks and ground_truth must hold the same track ids; only in tracks: "
                             f"{only_tracks[:10]}, only in ground_truth: {only_gt[:10]}")
        if not np.all(np.diff(gt_ids) > 0):
            raise ValueError("ground_truth must be sorted by track_id")
        gt = gt.astype({c: _GT_DTYPES[c] for c in gt_cols})
        pirl = gt["is_pirl"].to_numpy()
        theta = gt[[f"theta_{f}" for f in self._theta_features(gt)]].to_numpy(dtype=float)
        bad = pirl & ((gt["style"].to_numpy() < 0) | ~np.all(np.isfinite(theta) & (theta > 0), axis=1))
        if bad.any():
            raise ValueError(f"PIRL tracks need a style >= 0 and positive weights; track "
                             f"{int(gt_ids[np.argmax(bad)])} has style {int(gt['style'].iloc[np.argmax(bad)])} "
                             f"and theta {theta[np.argmax(bad)].tolist()}")
        bad = ~pirl & ((gt["style"].to_numpy() != BACKGROUND_STYLE) | np.isfinite(theta).any(axis=1))
        if bad.any():
            raise ValueError(f"background tracks have style {BACKGROUND_STYLE} and no weights; track "
                             f"{int(gt_ids[np.argmax(bad)])} does not")
        unknown = sorted(set(gt["status"]) - set(STATUSES))
        if unknown:
            raise ValueError(f"unknown status {unknown}; allowed: {STATUSES}")
        counts = pd.Series(frames).groupby(ids).size()
        n = gt.set_index("track_id")["n_frames"]
        if not (counts.reindex(n.index).to_numpy() == n.to_numpy()).all():
            raise ValueError("ground_truth n_frames must equal each track's number of frames")
        try:
            json.dumps(dict(self.info), allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"info must be JSON-serialisable without NaN: {exc}") from None
        if self.driver_steps is not None:
            on_pirl = pirl[np.searchsorted(gt_ids, ids)]  # per track row
            object.__setattr__(self, "driver_steps", _checked_driver_steps(self.driver_steps, ids[on_pirl],
                                                                           frames[on_pirl]))
        object.__setattr__(self, "ground_truth", gt)
        object.__setattr__(self, "lanes", MappingProxyType(dict(self.lanes)))
        object.__setattr__(self, "successors", MappingProxyType({k: tuple(v) for k, v in self.successors.items()}))
        object.__setattr__(self, "info", MappingProxyType(dict(self.info)))

    @staticmethod
    def _theta_features(gt: pd.DataFrame) -> tuple[str, ...]:
        return THETA_FEATURES + tuple(f for f in INTERACTION_THETA_FEATURES if f"theta_{f}" in gt.columns)

    @property
    def theta_features(self) -> tuple[str, ...]:
        """The features whose true weights the ground truth holds: `THETA_FEATURES`, then
        `INTERACTION_THETA_FEATURES` for drivers who interact."""
        return self._theta_features(self.ground_truth)

    @property
    def pirl_track_ids(self) -> np.ndarray:
        """Track ids driven by PIRL drivers."""
        gt = self.ground_truth
        return gt.loc[gt["is_pirl"], "track_id"].to_numpy()


def _checked_driver_steps(steps, track_ids: np.ndarray, frames: np.ndarray) -> pd.DataFrame:
    """``steps`` validated against the PIRL tracks' (track id, frame) pairs, sorted, with exact dtypes."""
    if not isinstance(steps, pd.DataFrame):
        raise ValueError(f"driver_steps must be a pandas DataFrame or None, got {type(steps).__name__}")
    if tuple(steps.columns) != DRIVER_STEP_COLUMNS:
        raise ValueError(f"driver_steps must have the columns {', '.join(DRIVER_STEP_COLUMNS)} in this order, got "
                         f"{', '.join(map(str, steps.columns))}")
    out = {}
    for c in ("track_id", "frame_id"):
        col = steps[c].to_numpy()
        if col.dtype.kind not in "iu":
            raise ValueError(f"driver_steps.{c} must be integers, got {col.dtype}")
        out[c] = col.astype(np.int64)
    for c in ("commanded", "overridden", "collided"):
        col = steps[c]
        if col.isna().any() or col.to_numpy().dtype != bool:
            raise ValueError(f"driver_steps.{c} must be booleans without missing values, got {col.dtype}")
        out[c] = col.to_numpy(dtype=bool)
    try:
        err = steps["command_error"].to_numpy(dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"driver_steps.command_error must be numbers [m/s] (empty where unknown), got "
                         f"{steps['command_error'].dtype}") from None
    if np.any(err < 0) or np.any(np.isinf(err)) or np.any(~np.isnan(err) & ~out["commanded"]):
        raise ValueError("driver_steps.command_error must be >= 0 and finite where commanded, empty elsewhere")
    out["command_error"] = err
    df = pd.DataFrame(out, columns=list(DRIVER_STEP_COLUMNS)).sort_values(["track_id", "frame_id"], kind="stable")
    df = df.reset_index(drop=True)
    have = pd.MultiIndex.from_arrays([df["track_id"], df["frame_id"]])
    want = pd.MultiIndex.from_arrays([track_ids.astype(np.int64), frames.astype(np.int64)]).sort_values()
    if have.has_duplicates:
        raise ValueError("driver_steps repeats a (track_id, frame_id) pair")
    if len(have) != len(want) or not (have == want).all():
        extra = have.difference(want)
        missing = want.difference(have)
        raise ValueError(f"driver_steps must hold one row per frame of every PIRL track and nothing else; "
                         f"{len(missing)} missing (e.g. {list(missing[:3])}), {len(extra)} not PIRL track frames "
                         f"(e.g. {list(extra[:3])})")
    bad = df["overridden"].to_numpy() & ~df["commanded"].to_numpy()
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"driver_steps: track {int(df['track_id'].iloc[k])} frame {int(df['frame_id'].iloc[k])} is "
                         "overridden but not commanded")
    return df


def _frames(time_s: np.ndarray) -> np.ndarray:
    f = time_s / FRAME_DT_S
    frames = np.round(f).astype(np.int64)
    off = np.abs(f - frames) > _GRID_TOL
    if off.any():
        raise ValueError(f"time_s must lie on the {FRAME_DT_MS} ms grid of the INTERACTION format; "
                         f"{time_s[np.argmax(off)]!r} s does not (resample the run first)")
    if len(frames) and frames.min() < 1:
        raise ValueError(f"time_s must be >= {FRAME_DT_S} s (frame_id 1 is the first frame), got "
                         f"{time_s.min()!r} s")
    return frames


def interaction_tracks(tracks: pd.DataFrame) -> pd.DataFrame:
    """Tracks in the INTERACTION vehicle format (columns :data:`pirl_sim.io.interaction.VEHICLE_COLUMNS`).

    ``frame_id = time_s / 0.1 s`` and ``timestamp_ms = 100 * frame_id``; rows sorted by track, then frame
    (the order of the INTERACTION files).
    """
    frames = _frames(tracks["time_s"].to_numpy(dtype=float))
    out = pd.DataFrame({
        "track_id": tracks["track_id"].to_numpy(dtype=np.int64),
        "frame_id": frames,
        "timestamp_ms": FRAME_DT_MS * frames,
        "agent_type": tracks["agent_type"].astype(str).to_numpy(),
        **{c: tracks[c].to_numpy(dtype=float) for c in ("x", "y", "vx", "vy", "psi_rad", "length", "width")},
    }, columns=list(VEHICLE_COLUMNS))
    return out.sort_values(["track_id", "frame_id"], kind="stable").reset_index(drop=True)


@dataclass(frozen=True)
class RecordingFiles:
    """Paths written by :func:`write_recording`."""

    directory: Path
    tracks: Path
    ground_truth: Path
    map: Path
    info: Path
    driver_steps: Path | None = None


def _ground_truth_csv(gt: pd.DataFrame) -> str:
    return gt.to_csv(index=False, lineterminator="\n", na_rep="")


def write_recording(recording: ScenarioRecording, out_dir, *, lane_width: float = 3.5) -> RecordingFiles:
    """Write a recording into ``out_dir`` (the files and their order: the file-formats page, Simulated recordings).

    Parameters
    ----------
    recording : ScenarioRecording
    out_dir : str or os.PathLike     created if missing; a previous recording there is replaced
    lane_width : float               lane width [m] of the map's lanelets

    Returns
    -------
    files : RecordingFiles           ValueError when the map cannot be written (then ``run.json`` is not written)
    """
    if not isinstance(recording, ScenarioRecording):
        raise TypeError(f"recording must be a ScenarioRecording, got {type(recording).__name__}")
    from pirl_sim.io.lanelet2_map import write_map  # lanelet2 is an optional extra

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = RecordingFiles(out, out / TRACKS_FILE, out / GROUND_TRUTH_FILE, out / MAP_FILE, out / INFO_FILE)
    files.info.unlink(missing_ok=True)  # the directory is incomplete until run.json is back
    write_tracks(interaction_tracks(recording.tracks), files.tracks, kind="vehicle")
    atomic_write_text(files.ground_truth, _ground_truth_csv(recording.ground_truth))
    write_map(dict(recording.lanes), {k: list(v) for k, v in recording.successors.items()}, files.map,
              lane_width=lane_width)
    listed = {"tracks": TRACKS_FILE, "ground_truth": GROUND_TRUTH_FILE, "map": MAP_FILE}
    steps_path = out / DRIVER_STEPS_FILE
    if recording.driver_steps is not None:
        atomic_write_text(steps_path, recording.driver_steps.to_csv(index=False, lineterminator="\n"))
        listed["driver_steps"] = DRIVER_STEPS_FILE
        files = RecordingFiles(out, files.tracks, files.ground_truth, files.map, files.info, steps_path)
    else:
        steps_path.unlink(missing_ok=True)  # not a leftover of a previous recording
    info = {"format": "pirl_sim scenario recording", "format_version": FORMAT_VERSION,
            "files": listed,
            "n_tracks": int(len(recording.ground_truth)),
            "n_pirl_tracks": int(recording.ground_truth["is_pirl"].sum()),
            **dict(recording.info)}
    atomic_write_text(files.info, json.dumps(info, indent=2, sort_keys=True, allow_nan=False) + "\n")
    return files


def read_recording(directory) -> ScenarioRecording:
    """Read a recording written by :func:`write_recording` (tracks, ground truth, map lanes, info).

    Returns
    -------
    ScenarioRecording
        ``tracks`` with ``time_s = frame_id * 0.1``; ``lanes`` from the map's lanelet centerlines by lane
        name and ``successors`` from its routing graph.

    Raises
    ------
    FileNotFoundError
        If the directory or one of its files is missing.
    ValueError
        If ``run.json`` is missing (an incomplete recording) or a file is malformed.
    """
    from pirl_sim.io.lanelet2_map import load_map

    d = Path(directory)
    if not d.is_dir():
        raise FileNotFoundError(f"recording directory not found: {d}")
    info_path = d / INFO_FILE
    if not info_path.is_file():
        raise ValueError(f"{d}: no {INFO_FILE}: the recording is incomplete (a run that crashed while "
                         "writing) or not a pirl_sim recording")
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{info_path}: not UTF-8 JSON ({exc}); a recording's {INFO_FILE} is a JSON object") from None
    if not isinstance(info, dict):
        raise ValueError(f"{info_path}: a recording's {INFO_FILE} is a JSON object, got a {type(info).__name__}")
    if "step_length_s" in info:
        step = info["step_length_s"]
        if isinstance(step, bool) or not isinstance(step, (int, float)) or not math.isfinite(step) or step <= 0:
            raise ValueError(f"{info_path}: step_length_s must be a finite number of seconds > 0 (the simulation "
                             f"step), got {step!r}")
    raw = read_tracks(d / TRACKS_FILE, kind="vehicle")
    tracks = pd.DataFrame({
        "track_id": raw["track_id"], "time_s": raw["frame_id"] * FRAME_DT_S, "agent_type": raw["agent_type"],
        **{c: raw[c] for c in ("x", "y", "vx", "vy", "psi_rad", "length", "width")},
    }, columns=list(TRACK_COLUMNS))
    gt_path = d / GROUND_TRUTH_FILE
    if not gt_path.is_file():
        raise FileNotFoundError(f"ground truth not found: {gt_path}")
    try:
        gt = pd.read_csv(gt_path, dtype={"agent_id": str, "route_id": str, "style_name": str, "status": str},
                         keep_default_na=False, na_values={c: [""] for c in INTERACTING_GROUND_TRUTH_COLUMNS
                                                           if c not in ("agent_id", "route_id", "style_name",
                                                                        "status")}, encoding="utf-8")
    except (UnicodeDecodeError, pd.errors.EmptyDataError, pd.errors.ParserError) as exc:
        raise ValueError(f"{gt_path}: not a UTF-8 CSV table ({type(exc).__name__}: {exc}); the ground truth has the "
                         f"columns {', '.join(GROUND_TRUTH_COLUMNS)}") from None
    if tuple(gt.columns) not in (GROUND_TRUTH_COLUMNS, INTERACTING_GROUND_TRUTH_COLUMNS):
        raise ValueError(f"{gt_path}: expected the columns {', '.join(GROUND_TRUTH_COLUMNS)} (theta_headway and "
                         f"theta_yielding after theta_jerk_sq for drivers who interact), found {', '.join(map(str, gt.columns))}")
    gt["interacted"] = gt["interacted"].map({True: True, False: False, "True": True, "False": False},
                                            na_action="ignore").astype("boolean")
    lmap = load_map(d / MAP_FILE)
    names = {int(ll.id): ll.attributes["name"] for ll in lmap.map.laneletLayer}
    lanes = {names[i]: np.array(line) for i, line in sorted(lmap.centerlines.items())}
    successors = {}
    for ll in lmap.map.laneletLayer:
        nxt = sorted(names[int(f.id)] for f in lmap.routing_graph.following(ll))
        if nxt:
            successors[names[int(ll.id)]] = nxt
    steps = None
    steps_name = info.get("files", {}).get("driver_steps")
    if steps_name is not None:
        steps_path = d / steps_name
        if not steps_path.is_file():
            raise FileNotFoundError(f"driver steps listed in {INFO_FILE} not found: {steps_path}")
        steps = read_csv_table(steps_path, dtype={"track_id": np.int64, "frame_id": np.int64, "commanded": bool,
                                                  "overridden": bool, "collided": bool, "command_error": float})
        missing = [c for c in DRIVER_STEP_COLUMNS if c not in steps.columns and c != "command_error"]
        if missing:
            raise ValueError(f"{steps_path}: missing column(s) {', '.join(missing)}; driver steps need the columns "
                             f"{', '.join(DRIVER_STEP_COLUMNS)}")
        if "command_error" not in steps.columns:  # written before the column existed
            steps["command_error"] = np.nan
    keep = {k: v for k, v in info.items() if k not in ("format", "format_version", "files", "n_tracks",
                                                       "n_pirl_tracks")}
    return ScenarioRecording(tracks, gt, lanes, dict(sorted(successors.items())), keep, steps)
