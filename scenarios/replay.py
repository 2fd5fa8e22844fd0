"""Recorded driving in, trajectories out: INTERACTION-format tracks and a Lanelet2 map -> driver-model data.

For every vehicle track: match it to the lanelet route it drove (`pirl_sim.io.lanelet2_map.match_route`),
smooth that route's centerline into a `ReferencePath`, project the track into Frenet (s, d), resample the
10 Hz frames to the model's dt (0.2 s by default, as the paper), and estimate (s, v, a) and jerk by least
squares through the dynamics (`fit_longitudinal_states`) rather than from noisy finite differences. All routes
share one arc-length axis (`CompositePath`), so one driver model serves the whole scene.

Driver selection, as the paper ("drove independently without too much interaction"): a track *interacted*
when, at any of its frames, another vehicle was ahead of it (within 90 degrees of its heading), closer than
``standstill + time_gap * speed`` and driving in a similar direction (headings within ``max_heading_diff``).
Interacting tracks are kept but flagged; experiments use the others. Every track or file that cannot be used
is counted with its reason in ``skipped`` and logged; it never stops the others.

Route matching leaves out positions that no path through the routing graph joins to the rest of the route
(`RouteMatch.unconnected`). A run of at most ``MAX_BRIDGE`` such frames inside a track is bridged: its
Frenet (s, d) are interpolated between the frames either side (the recorded x, y stay as they are). Longer
runs cut the track there, and its longest connected part is kept (if it is still long enough); leading and
trailing runs are cut off. The counts are in ``ReplayScene.repairs``.

Simulated scenes written by pirl_sim carry a ``ground_truth.csv`` sidecar beside the tracks (track_id,
style, theta_<feature> ...); its values go into each trajectory's metadata.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from pirl_sim.driving import CompositePath, PathDriverModel, fit_longitudinal_states, roundabout_model
from pirl_sim.paths import ReferencePath
from pirl_sim.trajectory import Trajectory
from pirl_sim.validation import is_positive_int

__all__ = ["SelectionRule", "ReplayScene", "load_replay", "interaction_flags", "track_key", "FRAME_DT", "MAX_BRIDGE"]

log = logging.getLogger(__name__)

FRAME_DT = 0.1  #: [s] INTERACTION frame period
MAX_BRIDGE = 5  #: [frames] longest run of unconnected positions inside a track that is bridged (0.5 s)


@dataclass(frozen=True)
class SelectionRule:
    """When a track counts as interacting with another vehicle (see module doc).

    Attributes
    ----------
    time_gap : float [s]            headway below which a vehicle ahead counts as a leader
    standstill : float [m]          distance added to the headway
    max_heading_diff_deg : float    leaders drive within this angle of the track's heading
    min_duration : float [s]        shorter tracks are skipped
    agent_types : tuple of str      agent_type values that are replayed
    """

    time_gap: float = 2.0
    standstill: float = 5.0
    max_heading_diff_deg: float = 45.0
    min_duration: float = 4.0
    agent_types: tuple[str, ...] = ("car",)

    def __post_init__(self) -> None:
        for name in ("time_gap", "standstill", "max_heading_diff_deg", "min_duration"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be >= 0, got {v!r}")


@dataclass(frozen=True)
class ReplayScene:
    """Recorded tracks as driver-model trajectories.

    Attributes
    ----------
    model : PathDriverModel       on a `CompositePath` of every matched route
    trajectories : list of Trajectory
        (s, v, a) states with metadata ``track_id``, ``file``, ``route`` (lanelet ids), ``segment``,
        ``d`` (n + 1,) lateral offsets [m], ``xy`` (n + 1, 2) recorded positions [m] at the model's dt,
        ``interacted`` and, from a sidecar, ``theta`` (normalised) and ``style``.
        Long tracks are cut into several trajectories (``piece`` 0, 1, ... in metadata): there are more
        trajectories than tracks.
    skipped : dict {reason: number of tracks}
    n_tracks : int                tracks read (of the replayed agent types)
    repairs : dict {what: count}  route-matching repairs of kept tracks (see module doc)
    """

    model: PathDriverModel
    trajectories: list[Trajectory]
    skipped: dict = field(default_factory=dict)
    n_tracks: int = 0
    repairs: dict = field(default_factory=dict)

    @property
    def selected(self) -> list[Trajectory]:
        """Pieces of tracks that did not interact (the paper's selection)."""
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


def interaction_flags(df: pd.DataFrame, rule: SelectionRule) -> dict[int, bool]:
    """{track_id: interacted} for one track file (columns of the INTERACTION vehicle format)."""
    flags = {int(t): False for t in df["track_id"].unique()}
    cos_max = np.cos(np.deg2rad(rule.max_heading_diff_deg))
    for _, frame in df.groupby("frame_id", sort=False):
        if len(frame) < 2:
            continue
        ids = frame["track_id"].to_numpy()
        xy = frame[["x", "y"]].to_numpy()
        v = np.hypot(frame["vx"].to_numpy(), frame["vy"].to_numpy())
        psi = frame["psi_rad"].to_numpy() if "psi_rad" in frame else np.arctan2(frame["vy"], frame["vx"]).to_numpy()
        head = np.column_stack([np.cos(psi), np.sin(psi)])
        rel = xy[None, :, :] - xy[:, None, :]  # rel[i, j] = j seen from i
        dist = np.linalg.norm(rel, axis=-1)
        ahead = np.einsum("ijk,ik->ij", rel, head) > 0
        same_dir = head @ head.T >= cos_max
        close = dist < (rule.standstill + rule.time_gap * v)[:, None]
        hit = ahead & same_dir & close
        np.fill_diagonal(hit, False)
        for i in np.flatnonzero(hit.any(axis=1)):
            flags[int(ids[i])] = True
    return flags


def _lenient_tracks(file: Path) -> tuple[pd.DataFrame | None, int]:
    """Rows that parse, grouped by track; tracks with any unparseable, non-finite or repeated frame are
    dropped. Returns (frame or None when nothing is usable, number of dropped tracks)."""
    from pirl_sim.io.interaction import VEHICLE_COLUMNS

    try:
        raw = pd.read_csv(file, on_bad_lines="skip", dtype=str)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError):
        return None, 0
    if list(raw.columns) != list(VEHICLE_COLUMNS):
        return None, 0
    numeric = [c for c in VEHICLE_COLUMNS if c != "agent_type"]
    df = raw.copy()
    df[numeric] = df[numeric].apply(pd.to_numeric, errors="coerce")
    bad_rows = ~np.isfinite(df[numeric].to_numpy(dtype=float)).all(axis=1)
    bad_ids = set(df.loc[bad_rows, "track_id"].dropna().astype(int))
    df = df[~bad_rows]
    df = df.astype({"track_id": int, "frame_id": int, "timestamp_ms": int})
    dup = df.duplicated(["track_id", "frame_id"], keep=False)
    bad_ids |= set(df.loc[dup, "track_id"])
    df = df[~df["track_id"].isin(bad_ids)]
    if df.empty:
        return None, len(bad_ids)
    return df, len(bad_ids)


def _sidecar(track_file: Path) -> pd.DataFrame | None:
    path = track_file.parent / "ground_truth.csv"
    if not path.exists():
        return None
    table = pd.read_csv(path)
    if "track_id" not in table:
        raise ValueError(f"{path}: a ground-truth sidecar needs a track_id column, got {list(table.columns)}")
    return table.set_index("track_id")


def load_replay(
    track_files: Sequence[str | Path],
    map_path: str | Path,
    *,
    dt: float = 0.2,
    rule: SelectionRule = SelectionRule(),
    max_offset: float = 3.0,
    jerk_weight: float = 1e-2,
    max_steps: int | None = 100,
) -> ReplayScene:
    """Read track files recorded on one map into a `ReplayScene`.

    Parameters
    ----------
    track_files : paths of ``vehicle_tracks_*.csv`` files (see `pirl_sim.io.interaction.find_track_files`)
    map_path : the Lanelet2 OSM map
    dt : float [s]        model step, a multiple of the 0.1 s frames
    rule : SelectionRule
    max_offset : float [m]  route matching tolerance
    jerk_weight : float   smoothing of the state estimate (see `fit_longitudinal_states`)
    max_steps : int or None
        Longer tracks are cut into consecutive pieces of at most this many steps (metadata ``piece``); the
        per-demonstration IRL costs O(steps^3), and a 20 s piece holds a whole roundabout passage.
        Experiments split train and test by track, never by piece.
    """
    from pirl_sim.io.interaction import read_tracks
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
    for file in (Path(f) for f in track_files):
        try:
            truth = _sidecar(file)
            df = read_tracks(file)
        except FileNotFoundError as exc:
            skipped["unreadable file"] += 1
            log.warning("skipping %s: %s", file, exc)
            continue
        except ValueError as exc:
            # a bad row should not cost the file's good tracks: read leniently, drop the broken tracks
            log.warning("%s failed validation (%s); keeping its valid tracks", file, exc)
            df, n_bad = _lenient_tracks(file)
            skipped["invalid rows (track dropped)"] += n_bad
            if df is None:
                if not n_bad:
                    skipped["unreadable file"] += 1
                continue
        df = df[df["agent_type"].isin(rule.agent_types)]
        flags = interaction_flags(df, rule) if len(df) else {}
        for track_id, track in df.groupby("track_id", sort=True):
            n_tracks += 1
            track = track.sort_values("frame_id")
            if (len(track) - 1) * FRAME_DT < rule.min_duration:
                skipped["shorter than min_duration"] += 1
                continue
            frames = track["frame_id"].to_numpy()
            if np.any(np.diff(frames) != 1):
                skipped["gap in frames"] += 1
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
            key = tuple(match.lanelet_ids)
            if key not in paths:
                paths[key] = len(path_list)
                path_list.append(ReferencePath.from_polyline(match.centerline))
            try:
                s_local, d = path_list[paths[key]].to_frenet(xy, extrapolate=True)
            except ValueError as exc:
                skipped["no route on the map"] += 1
                log.info("track %s of %s skipped: %s", track_id, file.name, exc)
                continue
            if bridge.any():
                frames_k = np.arange(len(xy))
                s_local = np.interp(frames_k, frames_k[~bridge], s_local[~bridge])
                d = np.interp(frames_k, frames_k[~bridge], d[~bridge])
            sel = slice(0, None, stride)
            meta = {"track_id": int(track_id), "file": str(file), "route": key, "interacted": flags[int(track_id)]}
            if truth is not None and int(track_id) in truth.index:
                row = truth.loc[int(track_id)]
                meta["truth"] = row.to_dict()
            pending.append((paths[key], s_local[sel], d[sel], xy[sel], meta))
    if not pending:
        raise ValueError(f"no usable track in {len(list(track_files))} files (skipped: {dict(skipped)})")
    composite = CompositePath(tuple(path_list))
    placed = []
    for segment, s_local, d, xy, meta in pending:
        low, high = composite.local_range(segment)
        if s_local.min() < low or s_local.max() > high:  # would fall onto a neighbouring route's share
            skipped["runs more than half a route gap beyond its route's ends"] += 1
            log.info("track %s of %s skipped: local arc lengths [%.0f, %.0f] m outside [%.0f, %.0f] m",
                     meta["track_id"], Path(meta["file"]).name, s_local.min(), s_local.max(), low, high)
            continue
        placed.append((segment, s_local, d, xy, meta))
    pending = placed
    if not pending:
        raise ValueError(f"no usable track in {len(list(track_files))} files (skipped: {dict(skipped)})")
    model = roundabout_model(composite, dt=dt)
    names = model.features.names
    trajectories = []
    if max_steps is not None and not is_positive_int(max_steps):
        raise ValueError(f"max_steps must be a positive integer or None, got {max_steps!r}")
    pieces = []
    for segment, s_local, d, xy, meta in pending:
        n = len(s_local) - 1
        size = n if max_steps is None else max_steps
        starts = list(range(0, max(n - 1, 1), size))
        for p, a in enumerate(starts):
            b = min(a + size, n)
            if b - a < 2:
                continue
            pieces.append((segment, s_local[a : b + 1], d[a : b + 1], xy[a : b + 1], dict(meta, piece=p)))
    for segment, s_local, d, xy, meta in pieces:
        s = s_local + composite.offsets[segment]
        states, controls = fit_longitudinal_states(s, model.dynamics, jerk_weight=jerk_weight)
        meta = dict(meta, segment=segment, d=np.asarray(d), xy=np.asarray(xy))
        truth = meta.pop("truth", None)
        if truth is not None and all(f"theta_{n}" in truth for n in names):
            theta = np.array([float(truth[f"theta_{n}"]) for n in names])
            if np.all(np.isfinite(theta)) and np.all(theta > 0):
                meta["theta"] = model.features.normalize(theta)
            if "style" in truth and np.isfinite(truth["style"]):
                meta["style"] = int(truth["style"])
        trajectories.append(Trajectory(states, controls, dt, meta))
    for reason, count in skipped.items():
        log.warning("%d tracks skipped: %s", count, reason)
    for what, count in repairs.items():
        log.warning("route matching: %d %s", count, what)
    return ReplayScene(model, trajectories, dict(skipped), n_tracks, dict(repairs))
