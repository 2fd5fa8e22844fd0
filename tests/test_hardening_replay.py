"""Issue 15, items 1, 7, 8 (the replay's lenient reading) and 12: the replay's bad inputs and missing outputs."""

import warnings

import numpy as np
import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.experiments.replay_report import ReplayProtocol, run_replay, write_replay_results
from pirl_sim.cli.common import seconds_to_steps
from pirl_sim.io.interaction import write_tracks
from pirl_sim.scenarios.replay import load_replay

LANE_LENGTH = 500.0  # [m]
LANE_Y = {"A": 0.0, "B": 60.0}  # two parallel straight lanes, both +x, not linked
THETA = {"speed_dev": 1.0, "acc_sq": 2.0, "jerk_sq": 1.0}  # raw weights of the sidecars


def _track_rows(track_id, first_frame, x0, n, y, speed=10.0):
    frames = np.arange(first_frame, first_frame + n)
    return pd.DataFrame({"track_id": track_id, "frame_id": frames, "timestamp_ms": 100 * frames, "agent_type": "car",
                         "x": x0 + speed * 0.1 * np.arange(n), "y": float(y), "vx": speed, "vy": 0.0,
                         "psi_rad": 0.0, "length": 4.5, "width": 1.8})


def _scene_dir(d, n_tracks=8, n_frames=150, speed=10.0):
    """A map of two straight lanes and one track file of ``n_tracks`` tracks that never share a frame."""
    from pirl_sim.io.lanelet2_map import write_map

    d.mkdir(parents=True, exist_ok=True)
    x = np.linspace(0.0, LANE_LENGTH, 41)
    write_map({k: np.column_stack([x, np.full_like(x, y)]) for k, y in LANE_Y.items()}, {}, d / "map.osm")
    rows, frame = [], 1
    for i in range(n_tracks):
        rows.append(_track_rows(i + 1, frame, 5.0, n_frames, LANE_Y["AB"[i % 2]], speed))
        frame += n_frames + 10
    write_tracks(pd.concat(rows, ignore_index=True), d / "vehicle_tracks_000.csv")
    return d / "vehicle_tracks_000.csv", d / "map.osm"


def _sidecar(d, ids, styles, theta=THETA):
    """ground_truth.csv: a style >= 0 with weights for PIRL tracks, style -1 without weights for the others."""
    rows = [{"track_id": i, "style": s, **{f"theta_{k}": (v if s >= 0 else np.nan) for k, v in theta.items()}}
            for i, s in zip(ids, styles)]
    pd.DataFrame(rows).to_csv(d / "ground_truth.csv", index=False)


# item 1: the ground-truth sidecar


@pytest.mark.parametrize("content", [b"", b"\x00\xff\xfe\x81binary\x00", b"id,style\n1,0\n", b"track_id,style\n1,0\n1,1\n",
                                     b"track_id,style\n1.5,0\n", b"track_id,theta_acc_sq\n1,heavy\n"])
def test_an_unusable_ground_truth_sidecar_is_an_error_naming_it(tmp_path, content):
    tracks, osm = _scene_dir(tmp_path)
    (tmp_path / "ground_truth.csv").write_bytes(content)
    with pytest.raises(ValueError, match="ground_truth.csv"):
        load_replay([tracks], osm)


def test_a_duplicated_track_id_in_the_sidecar_names_the_duplicates(tmp_path):
    tracks, osm = _scene_dir(tmp_path)
    _sidecar(tmp_path, [1, 2, 2, 3], [0, 1, 1, 0])
    with pytest.raises(ValueError, match=r"ground_truth.csv: each track_id must appear once.*\[2\]"):
        load_replay([tracks], osm)


def test_each_directory_gets_its_own_ground_truth(tmp_path):
    """Files from two directories: the second never takes the first one's truth."""
    t1, osm = _scene_dir(tmp_path / "a", n_tracks=4)
    t2, _ = _scene_dir(tmp_path / "b", n_tracks=4)
    _sidecar(tmp_path / "a", [1, 2, 3, 4], [0, 0, 0, 0])
    # no sidecar in b: its tracks have no truth
    scene = load_replay([t1, t2], osm)
    by_dir = {d: [t for t in scene.trajectories if f"/{d}/" in t.metadata["file"]] for d in "ab"}
    assert by_dir["a"] and all(t.metadata["style"] == 0 and "theta" in t.metadata for t in by_dir["a"])
    assert by_dir["b"] and all("style" not in t.metadata and "theta" not in t.metadata for t in by_dir["b"])
    # an unusable sidecar in b is an error, not a's truth
    (tmp_path / "b" / "ground_truth.csv").write_text("")
    with pytest.raises(ValueError, match=r"b/ground_truth.csv"):
        load_replay([t1, t2], osm)
    # b's own truth (another style) goes to b's tracks
    _sidecar(tmp_path / "b", [1, 2, 3, 4], [2, 2, 2, 2])
    scene = load_replay([t1, t2], osm)
    styles = {(t.metadata["file"].split("/")[-2], t.metadata["style"]) for t in scene.trajectories}
    assert styles == {("a", 0), ("b", 2)}


# item 8: the replay reads a broken file with read_tracks_lenient


def test_replay_drops_a_fractional_track_id_and_backwards_timestamps(tmp_path):
    tracks, osm = _scene_dir(tmp_path, n_tracks=6)
    df = pd.read_csv(tracks, dtype=str)
    t6 = df["track_id"] == "6"
    df.loc[df.index[t6][-1], "track_id"] = "6.5"  # the last row of track 6: a track id of 6.5
    t5 = df.index[df["track_id"] == "5"]
    df.loc[t5, "timestamp_ms"] = df.loc[t5, "timestamp_ms"].astype(int).to_numpy()[::-1].astype(str)  # backwards
    df.to_csv(tracks, index=False)
    scene = load_replay([tracks], osm)
    # one row that belongs to no track (6.5) and one track (5) whose timestamps run backwards
    assert scene.skipped["invalid rows (track dropped)"] == 2
    ids = {t.metadata["track_id"] for t in scene.trajectories}
    assert ids == {1, 2, 3, 4, 6}
    # track 6 keeps its own rows only: 6.5 was not read as 6
    last_x6 = max(t.metadata["xy"][-1, 0] for t in scene.trajectories if t.metadata["track_id"] == 6)
    assert last_x6 < 5.0 + 10.0 * 0.1 * 148 + 1e-6


# item 7: durations that would be clamped to one step


@pytest.mark.parametrize("option,value", [("--history", "-5"), ("--history", "0"), ("--horizon", "-3"),
                                          ("--horizon", "nan"), ("--history", "abc")])
def test_replay_cli_rejects_durations_that_are_not_positive(tmp_path, capsys, option, value):
    tracks, osm = _scene_dir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(["replay", "--tracks", str(tracks), "--map", str(osm), option, value, "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert option in err and "> 0" in err and value in err


def test_replay_cli_rejects_a_duration_shorter_than_a_step(tmp_path, capsys):
    tracks, osm = _scene_dir(tmp_path)
    code = main(["replay", "--tracks", str(tracks), "--map", str(osm), "--history", "0.05", "--quiet",
                 "--out", str(tmp_path / "o")])
    assert code == 2 and "--history 0.05 s is less than one model step" in capsys.readouterr().err


@pytest.mark.parametrize("seconds", [-5.0, 0.0, -3, float("nan"), float("inf"), 0.09, True, "2"])
def test_seconds_to_steps_rejects_what_would_be_clamped(seconds):
    with pytest.raises(ValueError, match="--history"):
        seconds_to_steps(seconds, 0.2, "--history")


def test_seconds_to_steps_rounds_to_steps():
    assert seconds_to_steps(2.0, 0.2, "--history") == 10 and seconds_to_steps(0.15, 0.2, "--horizon") == 1


@pytest.mark.parametrize("name", ["history", "horizon"])
@pytest.mark.parametrize("value", [0, -5])
def test_protocol_rejects_steps_that_are_not_positive(name, value):
    with pytest.raises(ValueError, match=name):
        ReplayProtocol(**{name: value})


# item 12: outputs of a replay with background tracks


@pytest.fixture(scope="module")
def mixed_result(tmp_path_factory):
    """8 tracks, 6 of them PIRL drivers of two styles with weights, 2 background tracks (style -1)."""
    d = tmp_path_factory.mktemp("mixed")
    tracks, osm = _scene_dir(d, n_tracks=8, n_frames=130)
    _sidecar(d, range(1, 9), [0, 1, 0, 1, 0, 1, -1, -1])
    scene = load_replay([tracks], osm)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_replay(scene, [("TIRL", "tirl", {}), ("PIRL-GMM (k=2)", "pirl-gmm", {"n_components": 2,
                                                                                          "random_state": 0})],
                            ReplayProtocol(history=10, horizon=10, fde_steps=(10,), seeds=(0, 1)))
    return scene, result


def test_background_tracks_keep_the_weight_error_columns(mixed_result, tmp_path):
    scene, result = mixed_result
    rows = result["rows"]
    learners = rows[rows["method"].isin(["TIRL", "PIRL-GMM (k=2)"])]
    assert "weight_error" in rows and "irl_weight_error" in rows
    assert learners["irl_weight_error"].notna().all()  # every split trains on PIRL tracks with weights
    write_replay_results(result, scene, tmp_path, "test")
    assert "weight_error_mean" in pd.read_csv(tmp_path / "summary.csv")
    assert "weight_error" in pd.read_csv(tmp_path / "rows.csv")


def test_replay_writes_summary_md(mixed_result, tmp_path):
    scene, result = mixed_result
    write_replay_results(result, scene, tmp_path, "pirl-sim replay --test")
    text = (tmp_path / "summary.md").read_text()
    assert "`pirl-sim replay --test`" in text and "| method |" in text and "PIRL-GMM (k=2)" in text


def test_cluster_figure_uses_gmm_k_and_marks_background_tracks(mixed_result, tmp_path, monkeypatch):
    import pirl_sim.learners as learners
    from pirl_sim.evaluation import figures

    scene, result = mixed_result
    seen = {}
    real_gmm, real_fig = learners.PIRLGMM, figures.feature_clusters

    class Recorder(real_gmm):
        def cluster_labels(self, trajectories):
            seen["k"] = self.n_components
            return super().cluster_labels(trajectories)

    def fig(values, names, labels, true_styles=None, style_names=None):
        seen["styles"], seen["names"] = true_styles, style_names
        return real_fig(values, names, labels, true_styles, style_names)

    monkeypatch.setattr(learners, "PIRLGMM", Recorder)
    monkeypatch.setattr(figures, "feature_clusters", fig)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        write_replay_results(result, scene, tmp_path, "test")
    assert seen["k"] == 2 == result["gmm_k"]
    assert seen["styles"] is not None and set(seen["styles"].tolist()) == {-1, 0, 1}
    assert seen["names"][-1] == "background (no style)"
    assert (tmp_path / "clusters.png").stat().st_size > 0
