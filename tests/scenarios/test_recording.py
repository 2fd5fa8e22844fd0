"""The one recording writer: INTERACTION tracks, ground-truth and driver-steps sidecars, Lanelet2 map, atomic and
complete."""

import json
import math

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("lanelet2")

from pirl_sim.io.interaction import VEHICLE_COLUMNS, read_tracks  # noqa: E402
from pirl_sim.io.lanelet2_map import load_map, match_route  # noqa: E402
from pirl_sim.scenarios import recording as rec_mod  # noqa: E402
from pirl_sim.scenarios.recording import (  # noqa: E402
    DRIVER_STEP_COLUMNS,
    DRIVER_STEPS_FILE,
    GROUND_TRUTH_COLUMNS,
    INFO_FILE,
    TRACK_COLUMNS,
    ScenarioRecording,
    interaction_tracks,
    read_recording,
    write_recording,
)

from replay_scenes import make_recording, recording_lanes  # noqa: E402


def _distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance [m] of each point to the polyline."""
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.clip(np.einsum("psk,sk->ps", points[:, None] - a[None], ab) / np.einsum("sk,sk->s", ab, ab), 0, 1)
    foot = a[None] + t[..., None] * ab[None]
    return np.min(np.hypot(*(points[:, None] - foot).transpose(2, 0, 1)), axis=1)


def test_write_read_round_trip(tmp_path):
    rec = make_recording()
    files = write_recording(rec, tmp_path / "run")
    assert sorted(p.name for p in files.directory.iterdir()) == [
        "ground_truth.csv", "map.osm", "run.json", "vehicle_tracks_000.csv"]
    back = read_recording(tmp_path / "run")

    def by_track(df):
        df = df.assign(frame=np.round(df["time_s"] * 10).astype(int))
        return df.sort_values(["track_id", "frame"]).reset_index(drop=True)

    a, b = by_track(back.tracks), by_track(rec.tracks)
    pd.testing.assert_frame_equal(a.drop(columns="time_s"), b.drop(columns="time_s"))
    np.testing.assert_allclose(a["time_s"], b["time_s"], atol=1e-9)
    pd.testing.assert_frame_equal(back.ground_truth, rec.ground_truth)
    assert back.info == {"simulator": "test", "seed": 1}
    assert dict(back.successors) == {"approach": ("curve",)}
    for name, line in rec.lanes.items():  # lanelet2 recomputes centerlines from the boundaries: same curves
        got = back.lanes[name]
        np.testing.assert_allclose(got[[0, -1]], line[[0, -1]], atol=1e-6)
        assert _distance_to_polyline(got, line).max() < 0.01
        assert _distance_to_polyline(line, got).max() < 0.01


def test_tracks_are_interaction_format_with_100ms_frames(tmp_path):
    files = write_recording(make_recording(), tmp_path)
    df = read_tracks(files.tracks, kind="vehicle")
    assert tuple(df.columns) == VEHICLE_COLUMNS
    first = df[df["track_id"] == 2].iloc[0]
    assert first["frame_id"] == 5 and first["timestamp_ms"] == 500
    assert (df["timestamp_ms"] == 100 * df["frame_id"]).all()
    assert df["frame_id"].min() == 1
    assert list(df["track_id"]) == sorted(df["track_id"])  # grouped by track, as INTERACTION files are


def test_map_loads_with_lanelet2_and_tracks_match_it(tmp_path):
    files = write_recording(make_recording(), tmp_path)
    lmap = load_map(files.map)
    ids = lmap.ids_by_name()
    assert set(ids) == {"approach", "curve"}
    ll = lmap.map.laneletLayer[ids["approach"]]
    assert [f.id for f in lmap.routing_graph.following(ll)] == [ids["curve"]]
    xy = make_recording().tracks.query("track_id == 1")[["x", "y"]].to_numpy()
    m = match_route(lmap, xy)
    assert m.lanelet_ids[0] == ids["approach"] and m.fraction_within == 1.0


def test_ground_truth_csv_has_the_documented_columns_and_empty_background_weights(tmp_path):
    files = write_recording(make_recording(), tmp_path)
    text = files.ground_truth.read_text().splitlines()
    assert text[0] == ",".join(GROUND_TRUTH_COLUMNS)
    assert text[3].startswith("3,veh2,r,False,-1,background,,,,,False,False,,arrived,25")
    info = json.loads(files.info.read_text())
    assert info["n_tracks"] == 3 and info["n_pirl_tracks"] == 2 and info["format_version"] == 1


def test_same_recording_same_bytes(tmp_path):
    a = write_recording(make_recording(), tmp_path / "a")
    b = write_recording(make_recording(), tmp_path / "b")
    for name in ("tracks", "ground_truth", "map", "info"):
        assert getattr(a, name).read_bytes() == getattr(b, name).read_bytes(), name


def test_a_crash_while_writing_leaves_no_half_file_and_an_incomplete_directory(tmp_path, monkeypatch):
    out = tmp_path / "run"
    write_recording(make_recording(), out)  # a complete previous recording
    old_tracks = (out / "vehicle_tracks_000.csv").read_bytes()

    def crash(*args, **kwargs):
        raise KeyboardInterrupt("simulated crash while writing the map")

    monkeypatch.setattr("pirl_sim.io.lanelet2_map.write_map", crash)
    with pytest.raises(KeyboardInterrupt):
        write_recording(make_recording(), out)
    assert not (out / "run.json").exists()
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary files left
    assert (out / "vehicle_tracks_000.csv").read_bytes() == old_tracks  # complete (same recording again)
    with pytest.raises(ValueError, match="no run.json: the recording is incomplete"):
        read_recording(out)



@pytest.mark.parametrize("name, content, match", [
    ("ground_truth.csv", b"track_id,agent_id\n1,\xe9\n", r"ground_truth.csv: not a UTF-8 CSV table \(UnicodeDecode"),
    ("ground_truth.csv", b"", r"ground_truth.csv: not a UTF-8 CSV table \(EmptyDataError"),
    ("run.json", b'{"format": "\xe9"}', r"run.json: not UTF-8 JSON \('utf-8' codec can't decode byte 0xe9"),
    ("run.json", b"{", r"run.json: not UTF-8 JSON \(Expecting property name"),
    ("run.json", b"[]", r"run.json: a recording's run.json is a JSON object, got a list"),
])
def test_an_unreadable_sidecar_is_a_value_error_naming_the_file(tmp_path, name, content, match):
    write_recording(make_recording(), tmp_path)
    (tmp_path / name).write_bytes(content)
    with pytest.raises(ValueError, match=match):
        read_recording(tmp_path)

def test_interaction_tracks_sorted_by_track_then_frame():
    df = interaction_tracks(make_recording().tracks)
    assert list(df.columns) == list(VEHICLE_COLUMNS)
    assert df.groupby("track_id")["frame_id"].apply(lambda f: bool(np.all(np.diff(f) == 1))).all()


def _tracks_gt():
    rec = make_recording()
    return rec.tracks.copy(), rec.ground_truth.copy()


@pytest.mark.parametrize("change, match", [
    (lambda t, g: (t.assign(time_s=t["time_s"] + 0.03), g), "must lie on the 100 ms grid"),
    (lambda t, g: (t.assign(time_s=t["time_s"] - 0.1), g), r"time_s must be >= 0.1 s"),
    (lambda t, g: (t, g.iloc[:2]), r"same track ids; only in tracks: \[3\]"),
    (lambda t, g: (t.drop(columns="width"), g), "missing: \\['width'\\]"),
    (lambda t, g: (t, g.assign(theta_acc_sq=[0.31, np.nan, np.nan])), "PIRL tracks need a style >= 0"),
    (lambda t, g: (t, g.assign(style=[0, 2, 1])), "background tracks have style -1"),
    (lambda t, g: (t, g.assign(status=["arrived", "gone", "arrived"])), "unknown status"),
    (lambda t, g: (t, g.assign(n_frames=[30, 21, 25])), "n_frames must equal"),
])
def test_invalid_recordings_are_rejected(change, match):
    tracks, gt = change(*_tracks_gt())
    lanes, succ = recording_lanes()
    with pytest.raises(ValueError, match=match):
        ScenarioRecording(tracks, gt, lanes, succ, {})


def test_info_must_be_json():
    tracks, gt = _tracks_gt()
    lanes, succ = recording_lanes()
    with pytest.raises(ValueError, match="JSON-serialisable"):
        ScenarioRecording(tracks, gt, lanes, succ, {"x": math.nan})
    with pytest.raises(ValueError, match="JSON-serialisable"):
        ScenarioRecording(tracks, gt, lanes, succ, {"x": object()})


def test_module_constants():
    assert rec_mod.TRACKS_FILE == "vehicle_tracks_000.csv"
    assert TRACK_COLUMNS[:2] == ("track_id", "time_s")


def _with_steps(rec: ScenarioRecording, steps) -> ScenarioRecording:
    return ScenarioRecording(rec.tracks, rec.ground_truth, rec.lanes, rec.successors, rec.info, steps)


def _steps_for(rec: ScenarioRecording, seed=0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    t = rec.tracks[rec.tracks["track_id"].isin(rec.pirl_track_ids)]
    n = len(t)
    commanded = rng.random(n) < 0.9
    return pd.DataFrame({"track_id": t["track_id"].to_numpy(), "frame_id": np.round(t["time_s"] * 10).astype(np.int64),
                         "commanded": commanded, "overridden": commanded & (rng.random(n) < 0.2),
                         "collided": np.zeros(n, dtype=bool)}, columns=list(DRIVER_STEP_COLUMNS))


def test_sidecar_round_trip_and_determinism(small_recording, tmp_path):
    rec = _with_steps(small_recording, _steps_for(small_recording))
    files = write_recording(rec, tmp_path / "a")
    assert files.driver_steps == tmp_path / "a" / DRIVER_STEPS_FILE
    back = read_recording(tmp_path / "a")
    pd.testing.assert_frame_equal(back.driver_steps, rec.driver_steps)
    write_recording(_with_steps(small_recording, _steps_for(small_recording)), tmp_path / "b")
    for name in (DRIVER_STEPS_FILE, INFO_FILE):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    # a recording without steps written over it leaves no stale sidecar, and reads back with None
    write_recording(small_recording, tmp_path / "a")
    assert not (tmp_path / "a" / DRIVER_STEPS_FILE).exists()
    assert read_recording(tmp_path / "a").driver_steps is None


def test_sidecar_validation(small_recording):
    steps = _steps_for(small_recording)
    with pytest.raises(ValueError, match="one row per frame of every PIRL track and nothing else; 1 missing"):
        _with_steps(small_recording, steps.iloc[1:])
    bg = small_recording.tracks[small_recording.tracks["track_id"] == 3].iloc[:1]
    extra = pd.concat([steps, pd.DataFrame({"track_id": [3], "frame_id": np.round(bg["time_s"] * 10).astype(np.int64),
                                            "commanded": [True], "overridden": [False], "collided": [False]})])
    with pytest.raises(ValueError, match="1 not PIRL track frames"):
        _with_steps(small_recording, extra)
    bad = steps.assign(commanded=False, overridden=True)
    with pytest.raises(ValueError, match="overridden but not commanded"):
        _with_steps(small_recording, bad)
    with pytest.raises(ValueError, match="driver_steps must have the columns"):
        _with_steps(small_recording, steps[["track_id", "frame_id", "commanded", "overridden"]])
    with pytest.raises(ValueError, match="driver_steps.commanded must be booleans"):
        _with_steps(small_recording, steps.assign(commanded=steps["commanded"].astype(int)))


def _interacting(gt: pd.DataFrame, headway) -> pd.DataFrame:
    at = list(gt.columns).index("theta_jerk_sq") + 1
    weights = pd.DataFrame({"theta_headway": headway, "theta_yielding": headway}, index=gt.index)
    return pd.concat([gt.iloc[:, :at], weights, gt.iloc[:, at:]], axis=1)


def test_drivers_who_interact_keep_their_headway_weight(tmp_path):
    tracks, gt = _tracks_gt()
    pirl = gt["is_pirl"].to_numpy()
    gt = _interacting(gt, np.where(pirl, 4.0, np.nan))
    lanes, succ = recording_lanes()
    rec = ScenarioRecording(tracks, gt, lanes, succ, {"simulator": "test"})
    assert rec.theta_features == ("speed_dev", "acc_sq", "jerk_sq", "headway", "yielding")
    assert make_recording().theta_features == ("speed_dev", "acc_sq", "jerk_sq")
    write_recording(rec, tmp_path / "run")
    back = read_recording(tmp_path / "run")
    pd.testing.assert_frame_equal(back.ground_truth, rec.ground_truth)
    with pytest.raises(ValueError, match="PIRL tracks need a style >= 0 and positive weights"):
        ScenarioRecording(tracks, _interacting(_tracks_gt()[1], np.where(pirl, -1.0, np.nan)), lanes, succ, {})
    bad = gt.rename(columns={"theta_headway": "theta_gap"})
    bad.to_csv(tmp_path / "run" / "ground_truth.csv", index=False)
    with pytest.raises(ValueError, match="theta_headway and theta_yielding after theta_jerk_sq for drivers who interact"):
        read_recording(tmp_path / "run")
