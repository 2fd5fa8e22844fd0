"""The replay harness (issue 6): recorded format in, learners and baselines scored in metres."""

import warnings

import numpy as np
import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.experiments.replay_report import ReplayProtocol, run_replay
from pirl_sim.io.interaction import read_tracks
from pirl_sim.scenarios.passage import PassageConfig, generate, recording, write_scene
from pirl_sim.scenarios.replay import SelectionRule, _estimate, interaction_flags, load_replay

from shared_sample import DATA as SHARED, needs_sample  # noqa: E402


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
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm", estimate="speeds")
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


@needs_sample
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
    flags = interaction_flags(pd.DataFrame(rows), SelectionRule(time_gap=2.0, standstill=5.0, gap="centre"))
    assert flags == {1: True, 2: False, 3: False}  # 1 follows 2 at 8 m < 5 m + 2 s * 10 m/s


def test_replay_cli_end_to_end(scene_dir, tmp_path, capsys):
    out, _ = scene_dir
    res = tmp_path / "res"
    assert main(["replay", "--tracks", str(out), "--map", str(out / "map.osm"), "--seeds", "2",
                 "--learners", "tirl,pirl-knn", "--knn-k", "3,10", "--out", str(res), "--quiet"]) == 0
    summary = pd.read_csv(res / "summary.csv")
    assert {"TIRL", "PIRL-kNN (k=3)", "PIRL-kNN (k=10)", "CV (path)", "CA (path)", "CV (x, y)"} <= set(summary["method"])
    conv = summary.set_index("method")["irl_converged"]
    assert conv["TIRL"].endswith(" / 2")  # one group per fit, two split seeds
    assert conv["PIRL-kNN (k=3)"] == conv["PIRL-kNN (k=10)"]  # one shared fit per split
    assert "irl_converged" in (res / "README.md").read_text()
    for name in ("clusters.png", "s_t.png", "knn_k.png"):
        assert (res / name).stat().st_size > 0
    assert (res / "README.md").read_text().count("Tracks read: 160") == 1
    assert main(["replay", "--tracks", str(out), "--map", str(out / "map.osm"), "--learners", "svm",
                 "--out", str(res)]) == 2
    assert "unknown learners ['svm']" in capsys.readouterr().err


# ----------------------------------------------------------------------------------------------
# regressions from replaying real INTERACTION roundabout recordings
# ----------------------------------------------------------------------------------------------

LANE_LENGTH = 500.0  # [m]
LANE_Y = {"A": 0.0, "B": 60.0}  # two parallel straight lanes, both +x, no routing-graph link between them


def _track_rows(track_id, first_frame, x0, n, y, speed=10.0):
    frames = np.arange(first_frame, first_frame + n)
    x = x0 + speed * 0.1 * np.arange(n)
    yy = np.broadcast_to(np.asarray(y, dtype=float), (n,))
    return pd.DataFrame({"track_id": track_id, "frame_id": frames, "timestamp_ms": 100 * frames, "agent_type": "car",
                         "x": x, "y": yy, "vx": speed, "vy": 0.0, "psi_rad": 0.0, "length": 4.5, "width": 1.8})


def _straight_scene(tmp_path, tracks):
    """A map of the two lanes and one track file; tracks: list of (lane, x0 [m], frames, y override or None),
    each in its own frames (no two tracks share a frame: nobody interacts)."""
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map

    x = np.linspace(0.0, LANE_LENGTH, 41)
    write_map({k: np.column_stack([x, np.full_like(x, y)]) for k, y in LANE_Y.items()}, {}, tmp_path / "map.osm")
    rows, frame = [], 1
    for i, (lane, x0, n, y) in enumerate(tracks):
        rows.append(_track_rows(i + 1, frame, x0, n, LANE_Y[lane] if y is None else y))
        frame += n + 10
    write_tracks(pd.concat(rows, ignore_index=True), tmp_path / "vehicle_tracks_000.csv")
    return tmp_path / "vehicle_tracks_000.csv", tmp_path / "map.osm"


def test_composite_path_keeps_points_before_a_path_on_that_path():
    from pirl_sim.driving import CompositePath
    from pirl_sim.paths import ReferencePath

    x = np.linspace(0.0, 100.0, 11)
    a = ReferencePath.from_polyline(np.column_stack([x, np.zeros_like(x)]))
    b = ReferencePath.from_polyline(np.column_stack([x, np.full_like(x, 50.0)]))
    comp = CompositePath((a, b), gap=300.0)
    off = comp.offsets[1]
    s = np.array([off - 20.0, off - 149.0, a.length + 20.0, a.length + 149.0, -5.0, off + b.length + 400.0])
    np.testing.assert_array_equal(comp.segment_of(s), [1, 1, 0, 0, 0, 1])
    xy = comp.to_cartesian(s, np.zeros_like(s))
    expected = [[-20.0, 50.0], [-149.0, 50.0], [120.0, 0.0], [249.0, 0.0], [-5.0, 0.0], [500.0, 50.0]]
    np.testing.assert_allclose(xy, expected, atol=1e-6)  # each extrapolated straight from its own path
    # an explicit segment wins over the arc length
    np.testing.assert_allclose(comp.to_cartesian(off - 200.0, 0.0, segment=1), [-200.0, 50.0], atol=1e-6)
    assert comp.local_range(0) == (-np.inf, a.length + 150.0) and comp.local_range(1) == (-150.0, np.inf)
    with pytest.raises(ValueError, match="segment must be integer path indices"):
        comp.to_cartesian(0.0, 0.0, segment=2)


def test_track_starting_before_its_route_stays_on_its_route(tmp_path):
    """Track 2 starts 20 m before lane B (its first 2 s off-map, at negative arc lengths of its route, the
    second path of the composite). Those steps were placed on lane A's extension, 300-400 m away."""
    tracks, osm = _straight_scene(tmp_path, [("A", 5.0, 150, None), ("B", -20.0, 150, None)])
    scene = load_replay([tracks], osm, max_steps=None)
    t = {tr.metadata["track_id"]: tr for tr in scene.trajectories}[2]
    assert t.metadata["segment"] == 1 and t.states[0, 0] < scene.model.path.offsets[1]
    xy = scene.model.positions(t.states, t.metadata["d"])
    assert np.abs(xy - t.metadata["xy"]).max() < 0.1
    # the replay scores on the same axis: CV along the path from the first window is exact on this track
    from pirl_sim.experiments.recorded import _errors

    proto = ReplayProtocol(history=2, horizon=10, fde_steps=(10,))
    x0 = t.states[2]
    s_pred = x0[0] + x0[1] * 0.2 * np.arange(1, 11)
    assert _errors(scene.model, [t], [(0, 2)], s_pred[None], proto).max() < 0.1


def test_counts_are_tracks_and_pieces_separately(tmp_path):
    """Long tracks are cut into 20 s pieces: the scene and the replay count tracks, pieces separately."""
    spec = [("A" if i % 2 else "B", 1.0, 450, None) for i in range(8)]  # 45 s each: 3 pieces of <= 20 s
    tracks, osm = _straight_scene(tmp_path, spec)
    scene = load_replay([tracks], osm)
    assert scene.n_converted == 8 and len(scene.trajectories) == 24 and scene.n_selected_tracks == 8
    result = run_replay(scene, [("TIRL", "tirl", {})], ReplayProtocol(seeds=(0,)))
    rows = result["rows"]
    assert set(rows["n_train"]) == {6} and set(rows["n_test"]) == {2}
    # the last piece of each track (24 steps) is shorter than history + horizon (25 steps): 2 pieces per track
    assert set(rows["n_train_pieces"]) == {12} and set(rows["n_test_pieces"]) == {4}
    assert result["selected"] == 8 and result["selected_pieces"] == 16
    from pirl_sim.experiments.replay_report import write_replay_results

    write_replay_results(result, scene, tmp_path / "res", "test")
    text = (tmp_path / "res" / "README.md").read_text()
    assert "converted: 8 (in 24 pieces)" in text and "used (not interacting, long enough): 8 (in 16 pieces)" in text


def test_ca_baseline_never_reverses():
    """The replay's CA along the path is the sweep's pseudo-learner (`KinematicModel`)."""
    from types import SimpleNamespace

    from pirl_sim.dynamics import longitudinal
    from pirl_sim.evaluation.baselines import KinematicModel

    x0 = np.array([
        [10.0, -0.5, -1.0],  # reversing estimate, braking: stays
        [10.0, 0.0, -2.0],   # stopped, braking: stays
        [10.0, -0.2, 0.0],   # reversing estimate, no acceleration: stays
        [10.0, 2.0, -1.0],   # braking: stops after 2 s at 12 m
        [10.0, -0.2, 1.0],   # starting from standstill
        [10.0, 5.0, 0.5],    # accelerating
    ])
    model = SimpleNamespace(dynamics=longitudinal(0.2), features=None)  # (s, v, a) states at dt 0.2 s
    s = KinematicModel(model, "ca").predict_states(x0, None, 15)[:, 1:, 0]
    t = 0.2 * np.arange(1, 16)
    np.testing.assert_allclose(s[0], 10.0)
    np.testing.assert_allclose(s[1], 10.0)
    np.testing.assert_allclose(s[2], 10.0)
    np.testing.assert_allclose(s[3], 10.0 + 2.0 * np.minimum(t, 2.0) - 0.5 * np.minimum(t, 2.0) ** 2)
    np.testing.assert_allclose(s[4], 10.0 + 0.5 * t**2)
    np.testing.assert_allclose(s[5], 10.0 + 5.0 * t + 0.25 * t**2)
    assert np.all(np.diff(np.column_stack([x0[:, :1], s]), axis=1) >= 0)


def _small_scene(scene_dir, n=48):
    import dataclasses

    out, _ = scene_dir
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm")
    return dataclasses.replace(scene, trajectories=scene.trajectories[:n], n_tracks=n, track_table=None)


def test_knn_with_another_k_equals_refitting(scene_dir):
    from pirl_sim.learners import PIRLKNN

    scene = _small_scene(scene_dir)
    train, test = scene.trajectories[:36], scene.trajectories[36:]
    histories = [t.window(10, 20) for t in test]
    params = dict(model=scene.model, window=10, prior="population", stride=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        base = PIRLKNN(n_neighbors=1, **params).fit(train)
        for k in (3, 10):
            refit = PIRLKNN(n_neighbors=k, **params).fit(train)
            derived = base.with_neighbors(k)
            assert derived.get_params()["n_neighbors"] == k and base.n_neighbors == 1
            np.testing.assert_array_equal(derived.infer_weights(histories), refit.infer_weights(histories))
    with pytest.raises(ValueError, match="larger than the number of training samples"):
        base.with_neighbors(10_000)


def test_replay_fits_knn_once_per_split_for_all_k(scene_dir, monkeypatch):
    from pirl_sim.learners import PIRLKNN

    scene = _small_scene(scene_dir)
    proto = ReplayProtocol(seeds=(0, 1))
    specs = [(f"PIRL-kNN (k={k})", "pirl-knn", {"n_neighbors": k, "prior": "population", "stride": 2})
             for k in (10, 3)]
    alone = run_replay(scene, [specs[0]], proto)["rows"].set_index(["seed", "method"])
    calls = []
    original = PIRLKNN._fit
    monkeypatch.setattr(PIRLKNN, "_fit", lambda self, *a: calls.append(self.n_neighbors) or original(self, *a))
    rows = run_replay(scene, specs, proto)["rows"]
    assert calls == [3, 3]  # one IRL per split, with the smallest k; k=10 reuses it
    assert list(rows["method"].unique()) == ["CV (path)", "CA (path)", "PIRL-kNN (k=10)", "PIRL-kNN (k=3)",
                                             "CV (x, y)"]
    both = rows.set_index(["seed", "method"])
    for seed in proto.seeds:
        key = (seed, "PIRL-kNN (k=10)")
        assert both.loc[key, "med"] == alone.loc[key, "med"]  # identical to refitting with k=10
        assert both.loc[key, "irl_from"] == "PIRL-kNN (k=3)"
        assert both.loc[key, "irl_converged"] == alone.loc[key, "irl_converged"]


def test_replay_reports_irl_convergence_and_passes_other_warnings_on(scene_dir, monkeypatch):
    from pirl_sim.experiments.replay_report import summarize
    from pirl_sim.irl import IRLConvergenceWarning
    from pirl_sim.learners import TIRL

    scene = _small_scene(scene_dir)
    original = TIRL._fit

    def noisy_fit(self, *args):
        original(self, *args)
        warnings.warn("not an IRL diagnostic", UserWarning)
        warnings.warn("stand-in for a non-converged group", IRLConvergenceWarning)

    monkeypatch.setattr(TIRL, "_fit", noisy_fit)
    with pytest.warns(UserWarning, match="not an IRL diagnostic"):  # was silenced by a blanket filter
        result = run_replay(scene, [("TIRL", "tirl", {})], ReplayProtocol(seeds=(0, 1)))
    tirl = result["rows"].query("method == 'TIRL'")
    assert list(tirl["irl_convergence_warnings"]) == [1, 1] and list(tirl["irl_groups"]) == [1, 1]
    summary = summarize(result).set_index("method")
    n_conv = int(tirl["irl_converged"].sum())
    assert summary.loc["TIRL", "irl_converged"] == f"{n_conv} / 2"
    assert summary.loc["TIRL", "irl_convergence_warnings"] == 2
    assert summary.loc["CV (path)", "irl_converged"] == ""


def test_unconnected_positions_are_bridged_or_cut_not_fatal(tmp_path):
    """Lanes A and B have no routing-graph link. Track 1 drives A with one frame recorded on B (a stray
    position); track 2 drives A for 8 s, then B for 3 s (a break). Each was dropped as 'no route on the map'."""
    stray = np.zeros(150)
    stray[70] = LANE_Y["B"]
    jump = np.where(np.arange(110) < 80, LANE_Y["A"], LANE_Y["B"])
    tracks, osm = _straight_scene(tmp_path, [("A", 5.0, 150, stray), ("A", 5.0, 110, jump), ("B", 5.0, 100, None)])
    scene = load_replay([tracks], osm, max_steps=None)
    assert not scene.skipped
    by_id = {t.metadata["track_id"]: t for t in scene.trajectories}
    assert set(by_id) == {1, 2, 3}
    assert scene.repairs == {"unconnected positions bridged": 1, "unconnected positions cut off": 30,
                             "tracks cut at a break in the route": 1}
    t1, t2 = by_id[1], by_id[2]
    assert t1.n_steps == 74 and t2.n_steps == 39  # 150 frames -> 75 samples; the 80 frames on A -> 40
    np.testing.assert_allclose(t1.states[:, 1], 10.0, atol=0.05)  # the bridged frame does not disturb the speed
    assert np.all(t2.metadata["xy"][:, 1] == LANE_Y["A"])


def test_replay_cli_runs_through_the_sweep_engine_alike_in_one_or_two_processes(scene_dir, tmp_path):
    """``pirl-sim replay`` keeps one cell per (split seed, method) in OUT/cells/ and gives the rows of the in-process
    `run_replay` on the same scene, with one worker process or two."""
    import json

    out, _ = scene_dir
    args = ["replay", "--tracks", str(out), "--map", str(out / "map.osm"), "--seeds", "3", "--learners",
            "tirl,pirl-knn", "--knn-k", "3", "--lateral", "neighbours", "--quiet", "--out"]
    assert main(args + [str(tmp_path / "one")]) == 0
    assert main(args + [str(tmp_path / "two"), "--workers", "2"]) == 0
    cells = [json.loads(p.read_text()) for p in (tmp_path / "one" / "cells").glob("*.json")]
    assert sorted((c["cell"]["seed"], c["cell"]["learner"]) for c in cells) == sorted(
        (seed, m) for seed in range(3) for m in ("cv", "ca", "tirl", "pirl-knn", "cv-xy"))
    from pirl_sim.experiments.recorded import load_scene

    scene = load_scene(cells[0]["cell"]["scenario_params"])  # as the cells read it (a pirl_sim recording)
    direct = run_replay(scene, [("TIRL", "tirl", {}), ("PIRL-kNN (k=3)", "pirl-knn",
                                                       {"n_neighbors": 3, "prior": "population", "stride": 2,
                                                        "irl_max_iter": 400})],
                        ReplayProtocol(seeds=(0, 1, 2), lateral="neighbours"))["rows"]
    cols = ["seed", "method", "med", "med_path", "n_windows", "lateral_floor", "irl_converged", "de@3.0s"]
    one, two = (pd.read_csv(tmp_path / d / "rows.csv") for d in ("one", "two"))
    pd.testing.assert_frame_equal(one[cols], two[cols])
    pd.testing.assert_frame_equal(one[cols], direct[cols].astype(one[cols].dtypes.to_dict()), rtol=1e-5)  # %.6g
    with pytest.raises(SystemExit):
        main(args + [str(tmp_path / "none"), "--workers", "0"])


def test_an_interrupted_replay_resumes_from_its_finished_cells(scene_dir, tmp_path, monkeypatch, capsys):
    """The sweep engine stores each split seed's cells as they finish (``OUT/cells/``); a replay interrupted in
    its last seed runs only that seed again and writes the same results as an uninterrupted run (timings
    aside)."""
    import json

    import pirl_sim.experiments.recorded as recorded

    out, _ = scene_dir
    args = ["replay", "--tracks", str(out), "--map", str(out / "map.osm"), "--seeds", "3", "--learners",
            "tirl,pirl-knn", "--knn-k", "3", "--quiet", "--out"]
    run_seed, ran = recorded.replay_seed, []

    def interrupted(scene, seed, *a, **kw):
        if seed == 2:
            raise KeyboardInterrupt
        return run_seed(scene, seed, *a, **kw)

    monkeypatch.setattr(recorded, "replay_seed", interrupted)
    assert main(args + [str(tmp_path / "resumed")]) == 130
    cells = tmp_path / "resumed" / "cells"
    stored = {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json")}
    assert sorted({json.loads(p.read_text())["cell"]["seed"] for p in cells.glob("*.json")}) == [0, 1]
    assert not (tmp_path / "resumed" / "rows.csv").exists()
    capsys.readouterr()
    assert main(args + [str(tmp_path / "resumed"), "--dry-run"]) == 0  # counts, runs nothing
    dry = capsys.readouterr().out
    assert not (tmp_path / "resumed" / "rows.csv").exists()
    monkeypatch.setattr(recorded, "replay_seed", lambda scene, seed, *a, **kw: ran.append(seed)
                        or run_seed(scene, seed, *a, **kw))
    assert main(args + [str(tmp_path / "resumed")]) == 0
    if len({json.loads(p.read_text())["code_version"] for p in cells.glob("*.json")}) > 1:
        pytest.skip("the code changed while the test ran (a shared working tree): every seed ran again")
    assert ran == [2]
    assert "15 cells, 10 already in" in dry and "5 to run" in dry  # CV, CA, TIRL, PIRL-kNN, CV (x, y) x 3 seeds
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json") if p.name in stored} == stored
    assert main(args + [str(tmp_path / "fresh")]) == 0
    assert ran == [2, 0, 1, 2]
    for name in ("rows.csv", "summary.csv", "paired.csv", "paired_ca.csv"):
        a, b = (pd.read_csv(tmp_path / d / name) for d in ("resumed", "fresh"))
        timings = [c for c in a.columns if c.startswith(("fit_s", "predict_s"))]
        pd.testing.assert_frame_equal(a.drop(columns=timings), b.drop(columns=timings))


def test_replay_cells_are_keyed_by_the_data_files_and_the_settings(scene_dir, tmp_path):
    import argparse
    import shutil

    from pirl_sim.cli.replay import add_parser, replay_config, replay_settings
    from pirl_sim.experiments.recorded import recorded_fingerprint

    out, _ = scene_dir
    scene = tmp_path / "scene"
    shutil.copytree(out, scene)
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())

    def keys(*extra):
        args = parser.parse_args(["replay", "--tracks", str(scene), "--map", str(scene / "map.osm"), *extra])
        return [c.key("code") for c in replay_config(args, replay_settings(args), args.tracks, args.map).cells]

    first = keys("--seeds", "2")
    assert len(set(first)) == len(first) == 2 * 6  # CV, CA, TIRL, PIRL-GMM, PIRL-kNN, CV (x, y) per seed
    assert set(first) < set(keys("--seeds", "3"))  # another seed adds cells, the others are reused
    assert not set(first) & set(keys("--seeds", "2", "--estimate", "positions"))  # loading settings
    assert not set(first) & set(keys("--seeds", "2", "--start", "track"))
    assert not set(first) & set(keys("--seeds", "2", "--lateral", "plane"))  # replay settings
    params = {"tracks": str(scene), "map": str(scene / "map.osm"), "files": 0}
    fingerprints = [recorded_fingerprint(params)]
    for name in ("ground_truth.csv", "map.osm", "vehicle_tracks_000.csv"):  # sidecar, map, tracks
        with open(scene / name, "a") as f:
            f.write("\n")
        fingerprints.append(recorded_fingerprint(params))
    assert len(set(fingerprints)) == 4
    assert not set(first) & set(keys("--seeds", "2"))


def test_replay_cli_refuses_a_scene_with_too_few_tracks_before_any_cell(tmp_path, capsys):
    tracks, osm = _straight_scene(tmp_path, [("A", 5.0, 150, None), ("B", 5.0, 150, None), ("A", 9.0, 150, None)])
    out = tmp_path / "out"
    assert main(["replay", "--tracks", str(tracks), "--map", str(osm), "--quiet", "--out", str(out)]) == 2
    assert "only 3 selected tracks" in capsys.readouterr().err
    assert not (out / "cells").exists()


def test_a_sweep_config_runs_the_recorded_scenario_into_the_tidy_table(scene_dir, tmp_path):
    """The replay's scenario is a sweep scenario like the others: a config of its own gives the tidy table's MED and
    FDE of the in-process replay."""
    from pirl_sim.engine import load_config, run_sweep
    from pirl_sim.experiments.recorded import load_scene

    out, _ = scene_dir
    cfg = tmp_path / "recorded.toml"
    cfg.write_text(f"""
seeds = [0, 1]
[[experiments]]
scenario = "recorded"
params = {{ tracks = "{out}", map = "{out / 'map.osm'}", replay = {{ fde_steps = [5, 15] }} }}
protocols = [{{ kind = "rolling", history_steps = 10, horizon = 15, stride = 5 }}]
learners = [{{ name = "cv", label = "CV (path)" }}, {{ name = "ca", label = "CA (path)" }}, "tirl"]
""")
    config = load_config(cfg)
    run = run_sweep(config, tmp_path / "out", workers=0, progress=False)
    assert not run.failed and len(run.table) == 6
    direct = run_replay(load_scene(dict(config.cells[0].scenario_params)), [("TIRL", "tirl", {})],
                        ReplayProtocol(seeds=(0, 1), fde_steps=(5, 15)))["rows"].set_index(["seed", "method"])
    for _, r in run.table.iterrows():
        expected = direct.loc[(r["seed"], r["learner_label"])]
        assert r["med"] == expected["med"] and r["fde"] == expected["de@3.0s"]
        assert r["n_predictions"] == expected["n_windows"] and r["n_test"] == expected["n_test"]
    assert (tmp_path / "out" / "table.csv").is_file()


def test_history_start_states_see_no_step_after_the_window(scene_dir):
    """A prediction at step k starts from states estimated from the history's observations alone: changing
    the recording after k leaves them as they were, while the whole-track estimate (a smoother) moves."""
    out, _ = scene_dir
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm")
    t = max(scene.trajectories, key=lambda tr: tr.n_steps)
    start, stop = 5, 15
    hist = scene.history_window(t, start, stop)
    assert hist.states.shape == (stop - start + 1, 3) and hist.metadata["window_start"] == start
    np.testing.assert_allclose(hist.states[:, 0], t.states[start : stop + 1, 0], atol=0.2)  # same motion
    bent = dict(t.metadata, s_obs=t.metadata["s_obs"].copy(), v_obs=t.metadata["v_obs"].copy())
    bent["s_obs"][stop + 1 :] += np.linspace(0.0, 20.0, t.n_steps - stop)  # the car sped off after step `stop`
    np.testing.assert_array_equal(scene.history_window(t.with_metadata(**bent), start, stop).states, hist.states)
    own = _estimate(t.metadata["s_obs"][start : stop + 1], {"v": None}, None, 0.2, "positions", None, 1e-2)
    np.testing.assert_allclose(hist.states, own[0], atol=1e-9)  # the window's own estimate ...
    assert not np.allclose(hist.states, t.states[start : stop + 1], atol=1e-3)  # ... not the smoother's
    refit = _estimate(bent["s_obs"], {"v": bent["v_obs"]}, None, 0.2, "positions", None, 1e-2)[0]
    assert abs(refit[stop, 2] - t.states[stop, 2]) > 0.05  # the smoother's acceleration at `stop` moved


def test_replay_start_option_is_checked_and_changes_the_start_states(scene_dir):
    out, _ = scene_dir
    with pytest.raises(ValueError, match="start must be one of"):
        ReplayProtocol(start="smoothed")
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm")
    specs = [("TIRL", "tirl", {})]
    rows = {start: run_replay(scene, specs, ReplayProtocol(seeds=(0,), start=start))["rows"].set_index("method")
            for start in ("history", "track")}
    assert rows["history"].loc["CA (path)", "med"] != rows["track"].loc["CA (path)", "med"]
    # the lateral floor uses recorded arc lengths, not the start states
    assert rows["history"].loc["TIRL", "lateral_floor"] == rows["track"].loc["TIRL", "lateral_floor"]


def test_next_step_knn_looks_up_training_histories_as_an_online_query_sees_them(scene_dir):
    """lookup_history=True: the training histories' look-up keys are their own estimates (the same as a query
    of that history gets), not the smoothed track's; without an estimator (simulated states) nothing changes."""
    from pirl_sim.learners import PIRLKNN

    out, _ = scene_dir
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm", estimate="speeds")
    train = scene.trajectories[:30]
    kw = dict(model=scene.model, window=10, n_neighbors=1, prior="population", stride=5, target="next",
              target_steps=15, state_features=(1, 2), lookup_features=False, aggregate="futures")
    causal = PIRLKNN(lookup_history=True, **kw).fit(train)
    smoothed = PIRLKNN(**kw).fit(train)
    np.testing.assert_array_equal(causal.demo_theta_, smoothed.demo_theta_)  # same next-steps costs
    t = train[0]
    own = scene.history_window(t, 0, 10)
    key = causal.scaler_.transform(own.states[-1:, 1:3])
    dist, _ = causal.neighbors_.kneighbors(key, n_neighbors=1)
    assert dist[0, 0] < 1e-9  # the first training history's key is its own estimate's last speed and acceleration
    assert smoothed.neighbors_.kneighbors(smoothed.scaler_.transform(own.states[-1:, 1:3]), 1)[0][0, 0] > 1e-6
    plain = [tr.with_metadata(estimator=None) for tr in train]
    np.testing.assert_array_equal(PIRLKNN(lookup_history=True, **kw).fit(plain).neighbors_._fit_X,
                                  smoothed.neighbors_._fit_X)
    with pytest.raises(ValueError, match="target='next' only"):
        PIRLKNN(model=scene.model, lookup_history=True).fit(train)


def test_a_track_that_leaves_its_route_for_a_far_part_of_it_is_cut_at_the_jump():
    """A U-shaped route: out along y = 0, a turn, back along y = 15 m. A vehicle drives out to x = 60 m, then cuts
    across to the return leg (not on its route, as a car on a bypass lane its matched route does not take) and
    drives back on it. Its arc length along the route jumps by the skipped turn; the track is cut there and the
    longer part kept."""
    from pirl_sim.paths import TRACK_STEP, ReferencePath
    from pirl_sim.scenarios.replay import _project_track, _without_jumps

    th = np.linspace(-np.pi / 2, np.pi / 2, 40)
    out = np.column_stack([np.linspace(0.0, 100.0, 50), np.zeros(50)])
    turn = np.column_stack([100.0 + 7.5 * np.cos(th[1:-1]), 7.5 + 7.5 * np.sin(th[1:-1])])
    back = np.column_stack([np.linspace(100.0, 0.0, 50), np.full(50, 15.0)])
    route = ReferencePath.from_polyline(np.vstack([out, turn, back]))
    x_out = np.arange(0.0, 60.0, 0.8)  # 75 frames out, then 10 frames across, then 40 back
    across = np.column_stack([np.full(10, 60.0), np.linspace(1.5, 13.5, 10)])
    xy = np.vstack([np.column_stack([x_out, np.zeros_like(x_out)]), across,
                    np.column_stack([np.arange(59.2, 27.0, -0.8), np.full(41, 15.0)])])
    s, d = _project_track(route, xy, np.zeros(len(xy), dtype=bool))
    assert np.abs(np.diff(s)).max() > TRACK_STEP  # the jump onto the return leg
    part = _without_jumps(s)
    assert part.start == 0 and 75 <= part.stop < 85  # out and part of the way across
    np.testing.assert_allclose(s[:75], x_out, atol=1e-6)
    assert np.all(np.abs(np.diff(s[part])) <= TRACK_STEP)


def test_a_recorded_sweep_config_reads_history_starts_with_speeds(scene_dir):
    """A hand-written ``recorded`` config that names no ``load.estimate`` replays with history starts (the
    default) and gets the speed-aided estimate, as ``pirl-sim replay`` does; with ``start = "track"`` (or an
    explicit estimate) it is read as asked."""
    from pirl_sim.experiments.recorded import load_scene

    out, _ = scene_dir
    params = {"tracks": str(out), "map": str(out / "map.osm"), "files": 0, "load": {}, "replay": {}}
    first = load_scene(params).trajectories[0].metadata["estimator"]
    assert first.estimate == "speeds"
    track = load_scene({**params, "replay": {"start": "track"}}).trajectories[0].metadata["estimator"]
    assert track.estimate == "positions"
    asked = load_scene({**params, "load": {"estimate": "positions"}}).trajectories[0].metadata["estimator"]
    assert asked.estimate == "positions"


def test_next_segments_restarted_at_the_history_estimate_follow_the_track(scene_dir):
    """segment_start="history": every training segment whose cost the IRL fits starts exactly at its history's
    own estimate (the state an online prediction starts from) and follows the track's positions and speeds; the
    look-up keys are unchanged, the costs differ; it needs lookup_history."""
    from pirl_sim.learners import PIRLKNN

    out, _ = scene_dir
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm", estimate="speeds")
    train = scene.trajectories[:30]
    kw = dict(model=scene.model, window=10, n_neighbors=1, stride=5, target="next", target_steps=15,
              state_features=(1, 2), lookup_features=False, aggregate="futures", lookup_history=True)
    restarted = PIRLKNN(segment_start="history", **kw)
    restarted.state_idx_ = restarted._check_target(scene.model)
    hist, seg, groups, truth = restarted._next_pairs(scene.model, train)
    plain_seg = PIRLKNN(**kw)._next_pairs(scene.model, train)[1]
    np.testing.assert_array_equal(truth, np.stack([p.states[1:, 0] for p in plain_seg]))
    assert groups.shape == (len(seg),) and groups.dtype.kind == "i"
    starts = np.stack([h.states[-1] for h in hist])
    np.testing.assert_array_equal(np.stack([s.states[0] for s in seg]), starts)
    assert np.abs(np.stack([s.states[0] for s in plain_seg]) - starts).max() > 1e-3  # the smoother's differ
    gap = np.abs(np.stack([s.states[1:, 0] - p.states[1:, 0] for s, p in zip(seg, plain_seg)]))
    assert gap.mean() < 0.1 and gap.max() < 1.0, (gap.mean(), gap.max())  # [m]: it follows the track
    for s in seg:  # trajectories of the model's dynamics
        np.testing.assert_allclose(scene.model.dynamics.residual(s.states, s.controls), 0.0, atol=1e-9)
    a, b = PIRLKNN(segment_start="history", **kw).fit(train), PIRLKNN(**kw).fit(train)
    np.testing.assert_array_equal(a.neighbors_._fit_X, b.neighbors_._fit_X)
    assert not np.allclose(a.demo_theta_, b.demo_theta_)
    with pytest.raises(ValueError, match="lookup_history=True"):
        PIRLKNN(**{**kw, "lookup_history": False}, segment_start="history").fit(train)
    with pytest.raises(ValueError, match="segment_start must be one of"):
        PIRLKNN(**kw, segment_start="smoothed").fit(train)


def test_the_road_ahead_enters_the_look_up(scene_dir):
    """lookup_ahead: |curvature| of the model's speed profile at those distances beyond each window's end are
    look-up keys, standardised with the rest."""
    from pirl_sim.learners import PIRLKNN
    from pirl_sim.model import synthetic_model
    from pirl_sim.trajectory import Trajectory

    out, _ = scene_dir
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm", estimate="speeds")
    train = scene.trajectories[:20]
    kw = dict(model=scene.model, window=10, n_neighbors=1, stride=5, target="next", target_steps=15,
              state_features=(1, 2), lookup_features=False, aggregate="futures")
    ahead = PIRLKNN(lookup_ahead=(0.0, 20.0), **kw).fit(train)
    hist = [t.window(0, 10) for t in train[:5]]
    s_end = np.array([h.states[-1, 0] for h in hist])
    raw = np.column_stack([np.stack([h.states[-1, 1:3] for h in hist]),
                           scene.model.curvature(s_end[:, None] + np.array([0.0, 20.0]))])
    np.testing.assert_allclose(ahead._lookup(hist), ahead.scaler_.transform(raw))
    assert raw[:, 2:].max() > 0.01 and np.all(raw[:, 2:] >= 0)  # [1/m]: the scene's roundabout bends
    assert ahead.predict_states(hist, 15).shape == (5, 16, 3)
    for bad, error in (((-1.0,), ValueError), ((np.inf,), ValueError), ("far", TypeError), ((True,), ValueError)):
        with pytest.raises(error, match="lookup_ahead"):
            PIRLKNN(**{**kw, "lookup_ahead": bad}).fit(train)
    with pytest.raises(ValueError, match="lookup_ahead needs a model along a path"):
        synth = synthetic_model()
        PIRLKNN(model=synth, window=10, lookup_ahead=(5.0,), target="next", target_steps=5,
                state_features=(1,), lookup_features=False).fit(
                    [Trajectory(np.zeros((31, 2)), np.zeros((30, 1)), 0.1)])


def test_several_road_weights_are_chosen_on_held_out_windows_of_other_tracks(scene_dir):
    """ahead_weights with several candidates: each scored by the look-up's error along the path on held-out
    training windows whose neighbours come from other tracks; the best is used, also after with_neighbors."""
    from pirl_sim.learners import PIRLKNN

    out, _ = scene_dir
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm", estimate="speeds")
    train = scene.trajectories[:30]
    kw = dict(model=scene.model, window=10, n_neighbors=3, stride=5, target="next", target_steps=15,
              state_features=(1, 2), lookup_features=False, aggregate="futures", lookup_ahead=(0.0, 20.0))
    chosen = PIRLKNN(ahead_weights=(0.0, 1.0, 3.0), **kw).fit(train)
    scores = chosen.ahead_scores_
    assert set(scores) == {0.0, 1.0, 3.0} and all(np.isfinite(v) and v > 0 for v in scores.values())
    assert chosen.ahead_weight_ == min(scores, key=scores.get)
    np.testing.assert_array_equal(chosen.key_scale_, [1.0, 1.0, chosen.ahead_weight_, chosen.ahead_weight_])
    for w in (0.0, 3.0):  # one weight: no selection, and its look-up is the selection's with that weight
        single = PIRLKNN(ahead_weights=(w,), **kw).fit(train)
        assert not hasattr(single, "ahead_scores_") and single.ahead_weight_ == w
        np.testing.assert_allclose(single.neighbors_._fit_X, chosen.lookup_z_ * [1.0, 1.0, w, w])
    # the score by hand: k nearest windows of other tracks, inverse-distance mean of their futures
    val, Z = chosen.ahead_validation_, chosen.lookup_z_ * [1.0, 1.0, 3.0, 3.0]
    errs = []
    for m, i in enumerate(val["pick"]):
        d = np.linalg.norm(Z - Z[i], axis=1)
        d[val["groups"] == val["groups"][i]] = np.inf
        near = np.argsort(d, kind="stable")[:3]
        v = 1.0 / d[near] / np.sum(1.0 / d[near])
        fut = scene.model.predict_states(np.repeat(val["x0"][m : m + 1], 3, axis=0), chosen.demo_theta_[near], 15)
        errs.append(np.abs(v @ fut[:, 1:, 0] - val["truth"][m]).mean())
    assert scores[3.0] == pytest.approx(np.mean(errs), rel=1e-6)
    # with_neighbors chooses again for its k, as a fit with that k does
    five = chosen.with_neighbors(5)
    refit = PIRLKNN(ahead_weights=(0.0, 1.0, 3.0), **{**kw, "n_neighbors": 5}).fit(train)
    assert five.ahead_scores_ == pytest.approx(refit.ahead_scores_) and five.ahead_weight_ == refit.ahead_weight_
    for bad, error in (((), ValueError), ((1.0, 1.0), ValueError), ((-1.0, 1.0), ValueError), ("x", TypeError)):
        with pytest.raises(error, match="ahead_weights"):
            PIRLKNN(**{**kw, "ahead_weights": bad}).fit(train)
    with pytest.raises(ValueError, match="need target='next'"):
        PIRLKNN(model=scene.model, window=10, lookup_ahead=(5.0,), ahead_weights=(0.0, 1.0)).fit(train)


def test_a_next_learner_with_restarted_segments_and_the_road_ahead_saves_and_loads(scene_dir, tmp_path):
    from pirl_sim.learners import PIRLKNN
    from pirl_sim.learners.model_io import load_learner, save_learner

    out, _ = scene_dir
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm", estimate="speeds")
    train = scene.trajectories[:30]
    fitted = PIRLKNN(model=scene.model, window=10, n_neighbors=3, stride=5, target="next", target_steps=15,
                     state_features=(1, 2), lookup_features=False, aggregate="futures", lookup_history=True,
                     segment_start="history", lookup_ahead=(0.0, 20.0), ahead_weights=(0.0, 1.0)).fit(train)
    loaded = load_learner(save_learner(fitted, tmp_path / "next.npz"))
    hist = [t.window(0, 10) for t in train[:4]]
    np.testing.assert_array_equal(loaded.predict_states(hist, 15), fitted.predict_states(hist, 15))
    assert loaded.ahead_scores_ == fitted.ahead_scores_ and loaded.ahead_weight_ == fitted.ahead_weight_
    np.testing.assert_array_equal(loaded.with_neighbors(5).predict_states(hist, 15),
                                  fitted.with_neighbors(5).predict_states(hist, 15))
