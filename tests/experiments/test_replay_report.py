"""The replay's run and report (pirl_sim.experiments.replay_report): learners ordered as in the paper, counts, one
kNN fit per split, IRL convergence notes, the desired speed per split, the lateral error decomposition, and the
outputs of a replay with background tracks."""

import warnings

import numpy as np
import pandas as pd
import pytest

from pirl_sim.experiments.replay_report import ReplayProtocol, write_replay_results

from replay_scenes import (
    replay_with_engine,
    roundabout_files,
    straight_scene,
    two_lane_scene_dir,
    write_ground_truth,
)
from weaving import weaving_scene


def test_replay_orders_learners_as_the_paper(passage_scene, tmp_path):
    out, _ = passage_scene
    learners = [
        "tirl",
        {"name": "pirl-gmm", "params": {"n_components": 3, "random_state": 0}},
        {"name": "pirl-knn", "params": {"n_neighbors": 10, "prior": "population", "stride": 2}},
    ]
    result = replay_with_engine(out / "vehicle_tracks_000.csv", out / "map.osm", learners,
                                ReplayProtocol(seeds=(0, 1)), tmp_path / "out", estimate="speeds")
    med = result["rows"].groupby("method")["med"].mean()
    assert med["PIRL-kNN (k=10)"] < med["PIRL-GMM (k=3)"] < med["TIRL"]
    assert med["TIRL"] < med["CV (path)"] < med["CV (x, y)"]
    paired = result["paired"].set_index("method")
    assert paired.loc["PIRL-kNN (k=10)", "mean_difference"] < 0


def test_counts_are_tracks_and_pieces_separately(tmp_path):
    """Long tracks are cut into 20 s pieces: the scene and the replay count tracks, pieces separately."""
    spec = [("A" if i % 2 else "B", 1.0, 450, None) for i in range(8)]  # 45 s each: 3 pieces of <= 20 s
    tracks, osm = straight_scene(tmp_path, spec)
    result = replay_with_engine(tracks, osm, ["tirl"], ReplayProtocol(seeds=(0,)), tmp_path / "out")
    scene = result["scene"]  # load_replay([tracks], osm)
    assert scene.n_converted == 8 and len(scene.trajectories) == 24 and scene.n_selected_tracks == 8
    rows = result["rows"]
    assert set(rows["n_train"]) == {6} and set(rows["n_test"]) == {2}
    # the last piece of each track (24 steps) is shorter than history + horizon (25 steps): 2 pieces per track
    assert set(rows["n_train_pieces"]) == {12} and set(rows["n_test_pieces"]) == {4}
    assert result["selected"] == 8 and result["selected_pieces"] == 16
    write_replay_results(result, scene, tmp_path / "res", "test")
    text = (tmp_path / "res" / "README.md").read_text()
    assert "converted: 8 (in 24 pieces)" in text and "used (not interacting, long enough): 8 (in 16 pieces)" in text


def test_replay_fits_knn_once_per_split_for_all_k(passage_root, tmp_path, monkeypatch):
    from pirl_sim.learners import PIRLKNN

    tracks, osm = roundabout_files(passage_root)  # a small scene (40 tracks)
    proto = ReplayProtocol(seeds=(0, 1))

    def knn(*k):
        return [{"name": "pirl-knn", "params": {"prior": "population", "stride": 2}, "grid": {"n_neighbors": list(k)}}]

    alone = replay_with_engine(tracks, osm, knn(10), proto, tmp_path / "alone")["rows"].set_index(["seed", "method"])
    calls = []
    original = PIRLKNN._fit
    monkeypatch.setattr(PIRLKNN, "_fit", lambda self, *a: calls.append(self.n_neighbors) or original(self, *a))
    rows = replay_with_engine(tracks, osm, knn(10, 3), proto, tmp_path / "both")["rows"]
    assert calls == [3, 3]  # one IRL per split, with the smallest k; k=10 reuses it
    assert list(rows["method"].unique()) == ["CV (path)", "CA (path)", "PIRL-kNN (k=10)", "PIRL-kNN (k=3)",
                                             "CV (x, y)"]
    both = rows.set_index(["seed", "method"])
    for seed in proto.seeds:
        key = (seed, "PIRL-kNN (k=10)")
        assert both.loc[key, "med"] == alone.loc[key, "med"]  # identical to refitting with k=10
        assert both.loc[key, "irl_from"] == "PIRL-kNN (k=3)"
        assert both.loc[key, "irl_converged"] == alone.loc[key, "irl_converged"]


def test_replay_reports_irl_convergence_and_passes_other_warnings_on(passage_root, tmp_path, monkeypatch):
    from pirl_sim.experiments.replay_report import summarize
    from pirl_sim.irl import IRLConvergenceWarning
    from pirl_sim.learners import TIRL

    tracks, osm = roundabout_files(passage_root)  # a small scene (40 tracks)
    original = TIRL._fit

    def noisy_fit(self, *args):
        original(self, *args)
        warnings.warn("not an IRL diagnostic", UserWarning)
        warnings.warn("stand-in for a non-converged group", IRLConvergenceWarning)

    monkeypatch.setattr(TIRL, "_fit", noisy_fit)
    result = replay_with_engine(tracks, osm, ["tirl"], ReplayProtocol(seeds=(0, 1)), tmp_path / "out")
    # the other warning is passed on to the engine, which keeps it with the cells (was silenced by a blanket filter)
    records = result["run"].records.values()
    assert all("UserWarning: not an IRL diagnostic" in r["warnings"] for r in records if r["cell"]["learner"] == "tirl")
    tirl = result["rows"].query("method == 'TIRL'")
    assert list(tirl["irl_convergence_warnings"]) == [1, 1] and list(tirl["irl_groups"]) == [1, 1]
    summary = summarize(result).set_index("method")
    n_conv = int(tirl["irl_converged"].sum())
    assert summary.loc["TIRL", "irl_converged"] == f"{n_conv} / 2"
    assert summary.loc["TIRL", "irl_convergence_warnings"] == 2
    assert summary.loc["CV (path)", "irl_converged"] == ""


@pytest.fixture(scope="module")
def mixed_result(tmp_path_factory):
    """8 tracks, 6 of them PIRL drivers of two styles with weights, 2 background tracks (style -1)."""
    d = tmp_path_factory.mktemp("mixed")
    tracks, osm = two_lane_scene_dir(d, n_tracks=8, n_frames=130)
    write_ground_truth(d, range(1, 9), [0, 1, 0, 1, 0, 1, -1, -1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = replay_with_engine(tracks, osm, ["tirl", {"name": "pirl-gmm", "params": {"n_components": 2,
                                                                                         "random_state": 0}}],
                                    ReplayProtocol(history=10, horizon=10, fde_steps=(10,), seeds=(0, 1)),
                                    tmp_path_factory.mktemp("mixed_out"))
    return result["scene"], result


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


def test_mean_path_lateral_model_and_the_error_decomposition(tmp_path):
    tracks, osm = weaving_scene(tmp_path)
    rows = {}
    for lateral in ("hold", "mean-path", "plane"):
        res = replay_with_engine(tracks, osm, [], ReplayProtocol(seeds=(0, 1), test_fraction=0.34, lateral=lateral),
                                 tmp_path / lateral, smoothing=0.0)
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


def test_replay_fits_the_desired_speed_per_split(passage_root, tmp_path):
    tracks, osm = roundabout_files(passage_root)
    proto = ReplayProtocol(seeds=(0, 1))
    fitted = replay_with_engine(tracks, osm, ["tirl"], proto, tmp_path / "fit", desired_speed="fit")["rows"]
    assert fitted.groupby("seed")["a_lat"].nunique().eq(1).all()
    assert fitted["a_lat"].between(0.2, 8.0).all() and fitted["v_max"].between(2.0, 40.0).all()
    fixed = replay_with_engine(tracks, osm, ["tirl"], proto, tmp_path / "fixed", desired_speed=(2.0, 12.0))["rows"]
    assert set(fixed["a_lat"]) == {2.0} and set(fixed["v_max"]) == {12.0}
    default = replay_with_engine(tracks, osm, ["tirl"], proto, tmp_path / "default")
    assert set(default["rows"]["a_lat"]) == {default["scene"].a_lat}


def test_scenes_show_where_the_best_learner_beats_ca_most_and_loses_most(mixed_result, tmp_path):
    from matplotlib.colors import to_rgb
    from matplotlib.image import imread

    from pirl_sim.cli import main
    from pirl_sim.experiments.replay_scenes import scene_learner
    from pirl_sim.viz.prediction import HISTORY_COLOR

    scene, result = mixed_result
    ex, errors, seed = result["examples"], result["errors"], result["seeds"][0]
    best = scene_learner(result)
    assert best in ("TIRL", "PIRL-GMM (k=2)")
    diff = errors[(seed, "CA (path)")] - errors[(seed, best)]
    gain, loss = (int(w) for w in ex["scene_windows"])
    assert diff[gain] == diff.max() and diff[loss] == diff.min()
    for k, w in enumerate((gain, loss)):  # the stored positions give the window's MED back
        for name in (best, "CA (path)"):
            err = np.linalg.norm(ex["scenes"][name][k] - ex["scene_future"][k], axis=-1).mean()
            assert err == pytest.approx(errors[(seed, name)][w], rel=1e-9, abs=1e-9)
    write_replay_results(result, scene, tmp_path, "test")
    for kind in ("gain", "loss"):
        img = imread(tmp_path / f"scene_{kind}.png")[..., :3]
        assert np.all(np.abs(img - to_rgb(HISTORY_COLOR)) < 0.05, axis=-1).sum() > 20  # the history is drawn
    assert "![gain](scene_gain.png)" in (tmp_path / "README.md").read_text()
    assert main(["show", str(tmp_path), "--window", "loss", "--out", str(tmp_path / "again.png")]) == 0
