"""The files beside a recording that the replay reads (pirl_sim.scenarios.replay): driver_steps.csv, run.json and
ground_truth.csv, each bad one a clear error naming the file and value (apart from tests/scenarios/test_replay.py,
whose scenes have more tracks)."""

import json
import logging
from functools import partial

import numpy as np
import pandas as pd
import pytest

from pirl_sim.scenarios.replay import load_replay, recording_settings

from replay_scenes import THETA, two_lane_scene_dir, write_ground_truth

# ------------------------------------------------------------------------------------------ replay inputs
_scene_dir = partial(two_lane_scene_dir, n_tracks=4)  # four tracks on the two straight lanes


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


_DRIVERS = {"horizon": 30, "smoothing": 1.0, "speed_smoothing": 0.0, "a_lat": 2.0, "v_max": 14.0}


@pytest.mark.parametrize("content, match", [
    (b"{not json", r"run.json: not UTF-8 JSON \(Expecting property name"),
    (b'{"format": "\xff"}', r"run.json: not UTF-8 JSON \('utf-8' codec can't decode byte 0xff"),
    (b"[1, 2]", r"run.json: a recording's run.json is a JSON object, got a list"),
    ({"config": 5}, r"run.json: config must be a JSON object, got 5"),
    ({"config": {"drivers": [1]}}, r"run.json: config.drivers must be a JSON object .*got \[1\]"),
    ({"config": {"drivers": {k: v for k, v in _DRIVERS.items() if k != "smoothing"}}},
     r"run.json: config.drivers.smoothing must be a finite number >= 0, got None"),
    ({"config": {"drivers": dict(_DRIVERS, speed_smoothing=float("nan"))}},
     r"run.json: config.drivers.speed_smoothing must be a finite number >= 0, got nan"),
    ({"config": {"drivers": dict(_DRIVERS, a_lat="2")}}, r"run.json: config.drivers.a_lat must be a finite number > 0, "
                                                         r"got '2'"),
    ({"config": {"drivers": dict(_DRIVERS, v_max=0)}}, r"run.json: config.drivers.v_max must be a finite number > 0, "
                                                       r"got 0"),
], ids=["not-json", "not-utf8", "list", "config", "drivers", "no-smoothing", "nan", "string", "zero-speed"])
def test_a_bad_run_json_is_an_error_naming_the_file_and_value(tmp_path, content, match):
    tracks, _ = _scene_dir(tmp_path)
    if isinstance(content, dict):
        content = json.dumps({"format": "pirl_sim scenario recording", "step_length_s": 0.1, **content}).encode()
    (tmp_path / "run.json").write_bytes(content)
    with pytest.raises(ValueError, match=match):
        recording_settings(tracks)


@pytest.mark.parametrize("track_ids, styles, theta, match", [
    ([1, 2, 2, 3], [0, 1, 1, 0], THETA, r"ground_truth.csv: each track_id must appear once.*\[2\]"),  # duplicates
    ([1, 2, 3, 4], [0, 0, 1, 1], {"speed_dev": 1.0, "jerk_sq": 1.0},
     r"ground_truth.csv: weights without the column\(s\) theta_acc_sq"),  # a theta column missing
    ([1, 2, 3, 99], [0, 0, 1, 1], THETA, r"ground_truth.csv: no row for 1 track\(s\) .*\[4\]"),  # a track's row
], ids=["duplicated-track-id", "no-theta-column", "missing-track-row"])
def test_a_bad_ground_truth_sidecar_is_an_error_naming_the_fault(tmp_path, track_ids, styles, theta, match):
    tracks, osm = _scene_dir(tmp_path)
    write_ground_truth(tmp_path, track_ids, styles, theta)
    with pytest.raises(ValueError, match=match):
        load_replay([tracks], osm)


def test_ground_truth_rows_matching_no_track_are_an_error_when_every_track_file_was_read(tmp_path):
    tracks, osm = _scene_dir(tmp_path)
    write_ground_truth(tmp_path, [1, 2, 3, 4, 98, 99], [0, 0, 1, 1, 0, 1])
    with pytest.raises(ValueError, match=r"ground_truth.csv: 2 row\(s\) match no track of vehicle_tracks_000.csv "
                                         r"\(e.g. track_id \[98, 99\]\); the sidecar holds one row per track"):
        load_replay([tracks], osm)


def test_ground_truth_rows_of_track_files_not_read_are_a_warning_naming_the_count(tmp_path, caplog):
    tracks, osm = _scene_dir(tmp_path)
    write_ground_truth(tmp_path, [1, 2, 3, 4, 98, 99], [0, 0, 1, 1, 0, 1])
    (tmp_path / "vehicle_tracks_001.csv").write_text(tracks.read_text())  # the other tracks' file, not replayed
    with caplog.at_level(logging.WARNING, logger="pirl_sim.scenarios.replay"):
        scene = load_replay([tracks], osm)
    assert "2 ground-truth row(s) match no track" in caplog.text and "vehicle_tracks_001.csv" in caplog.text
    assert all("theta" in t.metadata for t in scene.trajectories)



def test_ground_truth_rows_of_tracks_dropped_as_broken_are_a_warning(tmp_path, caplog):
    tracks, osm = _scene_dir(tmp_path)
    write_ground_truth(tmp_path, [1, 2, 3, 4], [0, 0, 1, 1])
    df = pd.read_csv(tracks)
    df.loc[df["track_id"] == 4, "length"] = -4.0  # track 4 is dropped by the lenient reading
    df.to_csv(tracks, index=False)
    with caplog.at_level(logging.WARNING, logger="pirl_sim.scenarios.replay"):
        scene = load_replay([tracks], osm)
    assert "1 ground-truth row(s) match no track" in caplog.text and "tracks dropped as broken" in caplog.text
    assert sorted({t.metadata["track_id"] for t in scene.trajectories}) == [1, 2, 3]

@pytest.mark.parametrize("style, match", [
    (-5, r"style must be an integer >= 0 \(a PIRL driver's\), -1 \(background traffic\) or empty, got -5.0 for "
         r"track 2"),
    (0.5, r"style must be an integer >= 0 .* got 0.5 for track 2"),
    (np.inf, r"style must be an integer >= 0 .* got inf for track 2"),
])
def test_ground_truth_with_a_bad_style_is_an_error(tmp_path, style, match):
    tracks, osm = _scene_dir(tmp_path)
    write_ground_truth(tmp_path, [1, 2, 3, 4], [0, 0, 1, 1])
    gt = pd.read_csv(tmp_path / "ground_truth.csv")
    gt["style"] = gt["style"].astype(float)
    gt.loc[1, "style"] = style
    gt.to_csv(tmp_path / "ground_truth.csv", index=False)
    with pytest.raises(ValueError, match=rf"ground_truth.csv: {match}"):
        load_replay([tracks], osm)


def test_ground_truth_styles_without_any_weight_column_are_an_error(tmp_path):
    tracks, osm = _scene_dir(tmp_path)
    pd.DataFrame({"track_id": [1, 2, 3, 4], "style": [-1, 0, 1, 1]}).to_csv(tmp_path / "ground_truth.csv", index=False)
    with pytest.raises(ValueError, match=r"ground_truth.csv: track 2 has a style >= 0 but the sidecar has no "
                                         r"theta_<feature> columns"):
        load_replay([tracks], osm)


@pytest.mark.parametrize("value, match", [
    (-2.0, r"weights must be finite and > 0 .*theta_acc_sq = -2.0 for track 2"),
    (0.0, r"weights must be finite and > 0 .*theta_acc_sq = 0.0 for track 2"),
    (np.nan, r"track 2 has a style >= 0 or some weights but misses weights \(empty \['theta_acc_sq'\]\)"),
])
def test_ground_truth_with_a_bad_weight_is_an_error(tmp_path, value, match):
    tracks, osm = _scene_dir(tmp_path)
    write_ground_truth(tmp_path, [1, 2, 3, 4], [0, 0, 1, -1])
    gt = pd.read_csv(tmp_path / "ground_truth.csv")
    gt.loc[1, "theta_acc_sq"] = value
    gt.to_csv(tmp_path / "ground_truth.csv", index=False)
    with pytest.raises(ValueError, match=match):
        load_replay([tracks], osm)


def test_ground_truth_of_background_traffic_stays_empty(tmp_path):
    tracks, osm = _scene_dir(tmp_path)
    write_ground_truth(tmp_path, [1, 2, 3, 4], [0, 0, 1, -1])
    scene = load_replay([tracks], osm)
    assert sorted(t.metadata["track_id"] for t in scene.trajectories if "theta" in t.metadata) == [1, 2, 3]
