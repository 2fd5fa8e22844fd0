"""The replay harness (issue 6): recorded format in, learners and baselines scored in metres."""

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.harness.replay import ReplayProtocol, run_replay
from pirl_sim.io.interaction import read_tracks
from pirl_sim.scenarios.passage import PassageConfig, generate, recording, write_scene
from pirl_sim.scenarios.replay import SelectionRule, interaction_flags, load_replay

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "interaction_format"


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate(PassageConfig(n_trajectories=160, n_train=130, seed=4))
    out = tmp_path_factory.mktemp("scene")
    write_scene(data, out)
    return out, data


def test_simulated_scene_round_trips_through_the_interaction_format(scene_dir):
    out, data = scene_dir
    tracks = recording(data).tracks.sort_values(["track_id", "time_s"])
    back = read_tracks(out / "vehicle_tracks_000.csv")
    np.testing.assert_allclose(back[["x", "y"]].to_numpy(), tracks[["x", "y"]].to_numpy(), atol=1e-6)
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm")
    assert scene.n_tracks == 160 and len(scene.trajectories) == 160 and not scene.skipped
    # positions rebuilt from the estimated states on the matched path follow the recording; the state
    # estimate smooths the Boltzmann-noisy jerks (least squares with a jerk penalty), hence decimetres
    for t in scene.trajectories[:20]:
        xy = scene.model.positions(t.states, t.metadata["d"])
        assert np.abs(xy - t.metadata["xy"]).max() < 0.3
    assert "theta" in t.metadata and "style" in t.metadata  # from the ground-truth sidecar


def test_replay_orders_learners_as_the_paper(scene_dir):
    out, _ = scene_dir
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm")
    specs = [
        ("TIRL", "tirl", {}),
        ("PIRL-GMM (k=3)", "pirl-gmm", {"n_components": 3, "random_state": 0}),
        ("PIRL-kNN (k=10)", "pirl-knn", {"n_neighbors": 10, "prior": "population", "stride": 2}),
    ]
    result = run_replay(scene, specs, ReplayProtocol(seeds=(0, 1)))
    med = result["rows"].groupby("method")["med"].mean()
    assert med["PIRL-kNN (k=10)"] < med["PIRL-GMM (k=3)"] < med["TIRL"]
    assert med["TIRL"] < med["CV (path)"] < med["CV (x, y)"]
    paired = result["paired"].set_index("method")
    assert paired.loc["PIRL-kNN (k=10)", "mean_difference"] < 0


@pytest.mark.skipif(not SHARED.exists(), reason="shared INTERACTION sample not found beside the repository")
def test_shared_interaction_sample_loads_end_to_end():
    scene = load_replay(
        [SHARED / "recorded_trackfiles" / "TestScenarioForScripts" / "vehicle_tracks_000.csv"],
        SHARED / "maps" / "TestScenarioForScripts.osm",
    )
    assert len(scene.trajectories) == 2 and not scene.skipped
    for t in scene.trajectories:
        assert t.dt == 0.2 and t.n_steps >= 30
        np.testing.assert_allclose(t.states[:, 1], 10.0, atol=1e-6)  # the sample drives at 10 m/s


def test_bad_files_are_counted_not_fatal(scene_dir, tmp_path):
    out, _ = scene_dir
    good = out / "vehicle_tracks_000.csv"
    truncated = tmp_path / "vehicle_tracks_001.csv"
    text = good.read_text().splitlines()
    truncated.write_text("\n".join(text[:50]) + "\n" + text[50][:12] + "\n")
    nan_file = tmp_path / "vehicle_tracks_002.csv"
    nan_file.write_text(text[0] + "\n" + text[1].replace(text[1].split(",")[4], "nan", 1) + "\n")
    far = read_tracks(good).query("track_id == 1").copy()
    far["x"] += 5000.0
    far_file = tmp_path / "vehicle_tracks_003.csv"
    from pirl_sim.io.interaction import write_tracks

    write_tracks(far, far_file)
    dup_file = tmp_path / "vehicle_tracks_004.csv"
    dup_file.write_text("\n".join(text[:200] + [text[5]]) + "\n")  # a repeated frame of track 1
    scene = load_replay([good, truncated, nan_file, far_file, dup_file], out / "map.osm")
    # a cut-off row, a NaN and a repeated frame each drop their own track only; the good file is untouched
    assert scene.skipped["invalid rows (track dropped)"] == 3
    assert "unreadable file" not in scene.skipped
    assert scene.skipped["no route on the map"] == 1
    files = [t.metadata["file"] for t in scene.trajectories]
    assert files.count(str(good)) == 160  # the good file's tracks are all still there
    assert files.count(str(dup_file)) >= 1
    broken_map = tmp_path / "broken.osm"
    broken_map.write_text((out / "map.osm").read_text()[:200])
    with pytest.raises(ValueError):
        load_replay([good], broken_map)


def test_interaction_rule_flags_a_close_follower():
    rows = []
    for frame in range(1, 30):
        for tid, x0 in ((1, 0.0), (2, 8.0), (3, 200.0)):
            rows.append({"track_id": tid, "frame_id": frame, "x": x0 + frame, "y": 0.0, "vx": 10.0, "vy": 0.0,
                         "psi_rad": 0.0})
    flags = interaction_flags(pd.DataFrame(rows), SelectionRule(time_gap=2.0, standstill=5.0))
    assert flags == {1: True, 2: False, 3: False}  # 1 follows 2 at 8 m < 5 m + 2 s * 10 m/s


def test_replay_cli_end_to_end(scene_dir, tmp_path, capsys):
    out, _ = scene_dir
    res = tmp_path / "res"
    assert main(["replay", "--tracks", str(out), "--map", str(out / "map.osm"), "--seeds", "2",
                 "--learners", "tirl,pirl-knn", "--knn-k", "3,10", "--out", str(res), "--quiet"]) == 0
    summary = pd.read_csv(res / "summary.csv")
    assert {"TIRL", "PIRL-kNN (k=3)", "PIRL-kNN (k=10)", "CV (path)", "CA (path)", "CV (x, y)"} <= set(summary["method"])
    for name in ("clusters.png", "s_t.png", "knn_k.png"):
        assert (res / name).stat().st_size > 0
    assert (res / "README.md").read_text().count("Tracks read: 160") == 1
    assert main(["replay", "--tracks", str(out), "--map", str(out / "map.osm"), "--learners", "svm",
                 "--out", str(res)]) == 2
    assert "unknown learners ['svm']" in capsys.readouterr().err
