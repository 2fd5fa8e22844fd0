"""The files beside a recording that the replay reads (pirl_sim.scenarios.replay): driver_steps.csv, run.json and
ground_truth.csv, each bad one a clear error naming the file and value (apart from tests/scenarios/test_replay.py,
whose scene helper makes more tracks)."""

import json
import logging

import numpy as np
import pandas as pd
import pytest

from pirl_sim.io.interaction import write_tracks
from pirl_sim.scenarios.replay import load_replay, recording_settings


# ------------------------------------------------------------------------------------------ replay inputs
LANE_LENGTH = 500.0  # [m]
LANE_Y = {"A": 0.0, "B": 60.0}  # two parallel straight lanes, both +x, not linked
THETA = {"speed_dev": 1.0, "acc_sq": 2.0, "jerk_sq": 1.0}


def _scene_dir(d, n_tracks=4, n_frames=150, speed=10.0):
    """A map of two straight lanes and one track file of ``n_tracks`` tracks that never share a frame."""
    from pirl_sim.io.lanelet2_map import write_map

    d.mkdir(parents=True, exist_ok=True)
    x = np.linspace(0.0, LANE_LENGTH, 41)
    write_map({k: np.column_stack([x, np.full_like(x, y)]) for k, y in LANE_Y.items()}, {}, d / "map.osm")
    rows, frame = [], 1
    for i in range(n_tracks):
        frames = np.arange(frame, frame + n_frames)
        rows.append(pd.DataFrame({
            "track_id": i + 1, "frame_id": frames, "timestamp_ms": 100 * frames, "agent_type": "car",
            "x": 5.0 + speed * 0.1 * np.arange(n_frames), "y": LANE_Y["AB"[i % 2]], "vx": speed, "vy": 0.0,
            "psi_rad": 0.0, "length": 4.5, "width": 1.8}))
        frame += n_frames + 10
    write_tracks(pd.concat(rows, ignore_index=True), d / "vehicle_tracks_000.csv")
    return d / "vehicle_tracks_000.csv", d / "map.osm"


def _sidecar(d, ids, styles, theta=THETA):
    rows = [{"track_id": i, "style": s, **{f"theta_{k}": (v if s >= 0 else np.nan) for k, v in theta.items()}}
            for i, s in zip(ids, styles)]
    pd.DataFrame(rows).to_csv(d / "ground_truth.csv", index=False)


def test_driver_steps_without_the_overridden_column_names_the_file_and_column(tmp_path):
    tracks, osm = _scene_dir(tmp_path)
    pd.DataFrame({"track_id": [1], "frame_id": [1], "commanded": [True], "collided": [False]}).to_csv(
        tmp_path / "driver_steps.csv", index=False)
    with pytest.raises(ValueError, match=r"driver_steps.csv: missing column\(s\) overridden"):
        load_replay([tracks], osm, selection="steps")


@pytest.mark.parametrize("step", [0, -0.1, "0.1"])
def test_run_json_with_a_bad_step_length_names_the_file_and_value(tmp_path, step):
    tracks, _ = _scene_dir(tmp_path)
    drivers = {"horizon": 30, "smoothing": 1.0, "speed_smoothing": 0.0, "a_lat": 2.0, "v_max": 14.0}
    (tmp_path / "run.json").write_text(json.dumps({"format": "pirl_sim scenario recording", "step_length_s": step,
                                                   "config": {"drivers": drivers}}))
    with pytest.raises(ValueError, match=rf"run.json: step_length_s must be .* > 0 .*got {step!r}"):
        recording_settings(tracks)


def test_ground_truth_without_a_theta_column_is_an_error(tmp_path):
    tracks, osm = _scene_dir(tmp_path)
    _sidecar(tmp_path, [1, 2, 3, 4], [0, 0, 1, 1], theta={"speed_dev": 1.0, "jerk_sq": 1.0})
    with pytest.raises(ValueError, match=r"ground_truth.csv: weights without the column\(s\) theta_acc_sq"):
        load_replay([tracks], osm)


def test_ground_truth_missing_a_track_row_is_an_error(tmp_path):
    tracks, osm = _scene_dir(tmp_path)
    _sidecar(tmp_path, [1, 2, 3, 99], [0, 0, 1, 1])
    with pytest.raises(ValueError, match=r"ground_truth.csv: no row for 1 track\(s\) .*\[4\]"):
        load_replay([tracks], osm)


def test_ground_truth_rows_matching_no_track_are_a_warning_naming_the_count(tmp_path, caplog):
    tracks, osm = _scene_dir(tmp_path)
    _sidecar(tmp_path, [1, 2, 3, 4, 98, 99], [0, 0, 1, 1, 0, 1])
    with caplog.at_level(logging.WARNING, logger="pirl_sim.scenarios.replay"):
        scene = load_replay([tracks], osm)
    assert "2 ground-truth row(s) match no track" in caplog.text
    assert all("theta" in t.metadata for t in scene.trajectories)


@pytest.mark.parametrize("value, match", [
    (-2.0, r"weights must be finite and > 0 .*theta_acc_sq = -2.0 for track 2"),
    (0.0, r"weights must be finite and > 0 .*theta_acc_sq = 0.0 for track 2"),
    (np.nan, r"track 2 has a style >= 0 or some weights but misses weights \(empty \['theta_acc_sq'\]\)"),
])
def test_ground_truth_with_a_bad_weight_is_an_error(tmp_path, value, match):
    tracks, osm = _scene_dir(tmp_path)
    _sidecar(tmp_path, [1, 2, 3, 4], [0, 0, 1, -1])
    gt = pd.read_csv(tmp_path / "ground_truth.csv")
    gt.loc[1, "theta_acc_sq"] = value
    gt.to_csv(tmp_path / "ground_truth.csv", index=False)
    with pytest.raises(ValueError, match=match):
        load_replay([tracks], osm)


def test_ground_truth_of_background_traffic_stays_empty(tmp_path):
    tracks, osm = _scene_dir(tmp_path)
    _sidecar(tmp_path, [1, 2, 3, 4], [0, 0, 1, -1])
    scene = load_replay([tracks], osm)
    assert sorted(t.metadata["track_id"] for t in scene.trajectories if "theta" in t.metadata) == [1, 2, 3]
