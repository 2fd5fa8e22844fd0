"""Bad inputs of the sweep config, the replay's recordings and ground truth, the SUMO network and the highway-env
roundabout env: each a clear error naming the value and what is allowed, raised before any work starts."""

import json
import logging

import numpy as np
import pandas as pd
import pytest

from pirl_sim.engine.config import parse_config
from pirl_sim.io.interaction import write_tracks
from pirl_sim.scenarios.replay import load_replay, recording_settings

# ------------------------------------------------------------------------------------------ sweep config


def _config(params=None, learner="tirl"):
    return {"seeds": [0], "experiments": [{
        "scenario": "synthetic", "params": {"n_trajectories": 20, "n_train": 10, **(params or {})},
        "protocols": [{"kind": "paper"}], "learners": [learner]}]}


@pytest.mark.parametrize("params, match", [
    ({"weighting": "distanse"}, r"weighting must be one of \('distance', 'likelihood'\), got 'distanse'"),
    ({"target": "nxt"}, r"target must be one of \('demo', 'next'\), got 'nxt'"),
    ({"aggregate": "mean"}, r"aggregate must be one of .*'weights'.*got 'mean'"),
])
def test_sweep_config_rejects_unknown_knn_choices(params, match):
    with pytest.raises(ValueError, match=match):
        parse_config(_config(learner={"name": "pirl-knn", "params": params}))


def test_sweep_config_accepts_the_knn_choices():
    cfg = parse_config(_config(learner={"name": "pirl-knn", "params": {"weighting": "likelihood"}}))
    assert cfg.cells[0].learner_params["weighting"] == "likelihood"


def test_sweep_config_bounds_n_trajectories_without_allocating():
    with pytest.raises(ValueError, match=r"n_trajectories must be in \[2, 1000000\], got 1000000000000"):
        parse_config(_config({"n_trajectories": 10**12, "n_train": 10}))


@pytest.mark.parametrize("name", ["position_range", "velocity_range"])
def test_sweep_config_bounds_the_start_ranges(name):
    with pytest.raises(ValueError, match=rf"{name} must lie within \[-1e\+06, 1e\+06\], got \(1e\+300, 1e\+300\)"):
        parse_config(_config({name: [1e300, 1e300]}))


@pytest.mark.parametrize("field, value, match", [
    ("weight", 1e300, r"style 'a': weight must be in \(0, 1e\+06\], got 1e\+300"),
    ("mean", {"state_sq": 1e300}, r"style 'a': mean of 'state_sq' must be in \(0, 1e\+06\], got 1e\+300"),
    ("std", {"state_sq": 1e300}, r"style 'a': std of 'state_sq' must be in \[0, 1e\+06\], got 1e\+300"),
])
def test_sweep_config_bounds_style_weights(field, value, match):
    style = {"name": "a", "weight": 1.0, "mean": {"state_sq": 4.0}, "std": {"state_sq": 1.0}, field: value}
    with pytest.raises(ValueError, match=match):
        parse_config(_config({"styles": [style]}))


def test_population_config_bounds_style_weights():
    from pirl_sim.scenarios.population_config import StyleConfig

    with pytest.raises(ValueError, match=r"style 'a': weight must be in \(0, 1e\+06\], got 1e\+300"):
        StyleConfig("a", 1e300, {"speed_dev": 1.0, "acc_sq": 1.0})
    with pytest.raises(ValueError, match=r"mean\['acc_sq'\] must be in \(0, 1e\+06\]"):
        StyleConfig("a", 1.0, {"speed_dev": 1.0, "acc_sq": 1e300})


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


# ------------------------------------------------------------------------------------------ simulators
@pytest.mark.parametrize("kwargs, match", [
    ({"radius": 1e7}, r"radius must be in \[5, 500\] m, got 10000000.0"),
    ({"approach_length": 1e7}, r"approach_length must be in \[1, 2000\] m"),
    ({"lanes": 50, "radius": 400.0}, r"lanes must be in \[1, 6\], got 50"),
    ({"n_arms": 40, "radius": 400.0, "ring_segments": 64}, r"n_arms must be in \[3, 12\], got 40"),
])
def test_sumo_roundabout_geometry_is_bounded(kwargs, match):
    from pirl_sim.scenarios.sumo.network import RoundaboutSpec

    with pytest.raises(ValueError, match=match):
        RoundaboutSpec(**kwargs)


def test_env_ego_start_beyond_the_route_is_an_error_naming_its_length():
    pytest.importorskip("highway_env")
    from pirl_sim.envs.roundabout import PirlRoundaboutEnv

    with pytest.raises(ValueError, match=r"ego_start must be in \[0, 279.5\] m on route 'arm0_to_arm2' \(its "
                                         r"length 289.5 m less 10 m\), got 1000000.0"):
        PirlRoundaboutEnv(config={"ego_start": 1e6})
