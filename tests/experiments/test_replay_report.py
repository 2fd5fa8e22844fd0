"""The replay's run and report (pirl_sim.experiments.replay_report): learners ordered as in the paper, counts, one
kNN fit per split, IRL convergence notes, the desired speed per split, the lateral error decomposition, and the
outputs of a replay with background tracks."""

import warnings

import numpy as np
import pandas as pd
import pytest

from pirl_sim.experiments.replay_report import ReplayProtocol, run_replay, write_replay_results
from pirl_sim.io.interaction import write_tracks
from pirl_sim.scenarios.passage import PassageConfig, write_scene
from pirl_sim.scenarios.passage import generate as generate_passage
from pirl_sim.scenarios.replay import load_replay


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate_passage(PassageConfig(n_trajectories=160, n_train=130, seed=4))
    out = tmp_path_factory.mktemp("scene")
    write_scene(data, out)
    return out, data


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


def _small_scene(scene_dir, n=48):
    import dataclasses

    out, _ = scene_dir
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm")
    return dataclasses.replace(scene, trajectories=scene.trajectories[:n], n_tracks=n, track_table=None)


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


THETA = {"speed_dev": 1.0, "acc_sq": 2.0, "jerk_sq": 1.0}  # raw weights of the sidecars


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


def _weaving_scene(tmp_path, n_tracks=12):
    """Straight lane; every car weaves across it the same way along x (a route-consistent driven path)."""
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map

    x = np.linspace(0.0, 400.0, 41)
    write_map({"A": np.column_stack([x, np.zeros_like(x)])}, {}, tmp_path / "map.osm")
    rows, frame = [], 1
    for i in range(n_tracks):
        n = 200
        frames = np.arange(frame, frame + n)
        speed = 8.0 + 0.3 * i
        xx = 10.0 + 3.0 * i + speed * 0.1 * np.arange(n)
        y = 1.2 * np.sin(xx / 15.0) + 0.1 * (i % 3 - 1)
        psi = np.arctan(1.2 / 15.0 * np.cos(xx / 15.0))
        rows.append(pd.DataFrame({"track_id": i + 1, "frame_id": frames, "timestamp_ms": 100 * frames,
                                  "agent_type": "car", "x": xx, "y": y, "vx": speed, "vy": 0.0, "psi_rad": psi,
                                  "length": 4.5, "width": 1.8}))
        frame += n + 10
    write_tracks(pd.concat(rows, ignore_index=True), tmp_path / "vehicle_tracks_000.csv")
    return tmp_path / "vehicle_tracks_000.csv", tmp_path / "map.osm"


def test_mean_path_lateral_model_and_the_error_decomposition(tmp_path):
    tracks, osm = _weaving_scene(tmp_path)
    scene = load_replay([tracks], osm, smoothing=0.0)
    rows = {}
    for lateral in ("hold", "mean-path", "plane"):
        res = run_replay(scene, [], ReplayProtocol(seeds=(0, 1), test_fraction=0.34, lateral=lateral))
        rows[lateral] = res["rows"].set_index(["seed", "method"])
    hold, mean = rows["hold"], rows["mean-path"]
    for seed in (0, 1):  # one route: pooling in the plane finds the same weave
        assert rows["plane"].loc[(seed, "CA (path)"), "med"] < 0.5 * hold.loc[(seed, "CA (path)"), "med"]
    ca = "CA (path)"
    for seed in (0, 1):
        # the weave is the same for every car: following the training tracks' path beats holding the offset
        assert mean.loc[(seed, ca), "med"] < 0.5 * hold.loc[(seed, ca), "med"]
        # along the path (recorded offsets) nothing depends on the lateral model; the floor is below CA
        assert mean.loc[(seed, ca), "med_path"] == pytest.approx(hold.loc[(seed, ca), "med_path"])
        assert mean.loc[(seed, ca), "lateral_floor"] < hold.loc[(seed, ca), "lateral_floor"]
        assert hold.loc[(seed, ca), "lateral_floor"] <= hold.loc[(seed, ca), "med"] + 1e-9
        # constant speed: CA and CV along the path are almost exact
        assert hold.loc[(seed, ca), "med_path"] < 0.1


@pytest.fixture(scope="module")
def passage_root(tmp_path_factory):
    """A simulated roundabout scene laid out as an INTERACTION folder (recorded_trackfiles/NAME, maps/NAME.osm)."""
    from pirl_sim.scenarios.passage import PassageConfig, generate, write_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate(PassageConfig(n_trajectories=40, n_train=30, seed=4))
    root = tmp_path_factory.mktemp("root")
    scene = root / "recorded_trackfiles" / "SIM_Roundabout_A"
    scene.mkdir(parents=True)
    write_scene(data, scene)
    (root / "maps").mkdir()
    (scene / "map.osm").rename(root / "maps" / "SIM_Roundabout_A.osm")
    return root


def test_run_replay_fits_the_desired_speed_per_split(passage_root):
    name = "SIM_Roundabout_A"
    scene = load_replay([passage_root / "recorded_trackfiles" / name / "vehicle_tracks_000.csv"],
                        passage_root / "maps" / f"{name}.osm")
    proto = ReplayProtocol(seeds=(0, 1))
    fitted = run_replay(scene, [("TIRL", "tirl", {})], proto, desired_speed="fit")["rows"]
    assert fitted.groupby("seed")["a_lat"].nunique().eq(1).all()
    assert fitted["a_lat"].between(0.2, 8.0).all() and fitted["v_max"].between(2.0, 40.0).all()
    fixed = run_replay(scene, [("TIRL", "tirl", {})], proto, desired_speed=(2.0, 12.0))["rows"]
    assert set(fixed["a_lat"]) == {2.0} and set(fixed["v_max"]) == {12.0}
    default = run_replay(scene, [("TIRL", "tirl", {})], proto)["rows"]
    assert set(default["a_lat"]) == {scene.a_lat}
