"""``pirl-sim fit-model`` and ``pirl-sim predict``: a learner fitted into a model file, predictions from it."""

import warnings

from pirl_sim.cli import main
from pirl_sim.scenarios.passage import PassageConfig, write_scene
from pirl_sim.scenarios.passage import generate as generate_passage


def test_fit_model_and_predict_commands(tmp_path, capsys):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate_passage(PassageConfig(n_trajectories=40, n_train=30, n_steps=25, seed=4))
    write_scene(data, tmp_path / "scene")
    scene = tmp_path / "scene"
    assert main(["fit-model", "--tracks", str(scene), "--map", str(scene / "map.osm"), "--learner", "pirl-gmm",
                 "--k", "3", "--out", str(tmp_path / "gmm"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "PIRLGMM: 3 weight vector(s) over ['speed_dev', 'acc_sq', 'jerk_sq']" in out
    assert (tmp_path / "gmm.npz").is_file()
    assert main(["fit-model", "--tracks", str(scene), "--map", str(scene / "map.osm"), "--learner", "pirl-gmm",
                 "--k", "3", "--space", "weights", "--out", str(tmp_path / "gmm_w"), "--quiet"]) == 0
    assert "ARI of the styles against the recording's ground truth: 1.000" in capsys.readouterr().out
    assert main(["fit-model", "--tracks", str(scene), "--map", str(scene / "map.osm"), "--learner", "pirl-knn",
                 "--space", "weights", "--out", str(tmp_path / "knn_w"), "--quiet"]) == 2
    assert "--space weights is an option of pirl-gmm and pirl-dpgmm, not pirl-knn" in capsys.readouterr().err
    assert main(["predict", "--model", str(tmp_path / "gmm.npz"), "--tracks", str(scene), "--map",
                 str(scene / "map.osm"), "--horizon", "2", "--out", str(tmp_path / "pred.csv"), "--quiet"]) == 0
    import pandas as pd

    pred = pd.read_csv(tmp_path / "pred.csv")
    assert set(pred["step"]) == set(range(1, 11)) and pred["track_id"].nunique() == 40
    assert {"x_m", "y_m", "error_m", "style", "theta_speed_dev"} <= set(pred.columns)
    assert pred["error_m"].median() < 1.0  # metres, 2 s ahead
    # a model of another step is refused with the reason
    assert main(["fit-model", "--tracks", str(scene), "--map", str(scene / "map.osm"), "--learner", "tirl",
                 "--dt", "0.1", "--window", "1", "--out", str(tmp_path / "tirl01"), "--quiet"]) == 0
    assert main(["predict", "--model", str(tmp_path / "tirl01.npz"), "--tracks", str(scene), "--map",
                 str(scene / "map.osm"), "--history", "0.01", "--out", str(tmp_path / "p.csv"), "--quiet"]) == 2
    assert "less than one model step" in capsys.readouterr().err
    assert main(["predict", "--model", str(tmp_path / "missing.npz"), "--tracks", str(scene), "--map",
                 str(scene / "map.osm"), "--out", str(tmp_path / "p.csv"), "--quiet"]) == 2
    assert "no learner file" in capsys.readouterr().err
    # predictions never overwrite an input: the model file, the map or a track file
    before = {p: p.read_bytes() for p in (tmp_path / "gmm.npz", scene / "map.osm", scene / "vehicle_tracks_000.csv")}
    for target in before:
        assert main(["predict", "--model", str(tmp_path / "gmm.npz"), "--tracks", str(scene), "--map",
                     str(scene / "map.osm"), "--out", str(target), "--quiet"]) == 2
        assert "is one of the inputs" in capsys.readouterr().err
    assert all(p.read_bytes() == b for p, b in before.items())


def test_on_real_data_the_model_takes_the_replays_best_settings_and_predict_reads_them_back(real_like, tmp_path,
                                                                                           capsys):
    """fit-model's defaults are the replay's (--preset best: speed-level features, a fitted desired speed);
    predict rebuilds that model on its tracks; --preset paper gives the paper's."""
    from pirl_sim.learners import load_learner

    where = ["--tracks", str(real_like), "--map", str(real_like / "map.osm"), "--quiet"]
    assert main(["fit-model", *where, "--learner", "tirl", "--window", "1", "--out", str(tmp_path / "best")]) == 0
    assert "over ['speed_dev', 'acc_sq', 'jerk_sq', 'speed_sq', 'speed_hi']" in capsys.readouterr().out
    profile = load_learner(tmp_path / "best.npz").model_.features.features[0].residual.profile
    assert (profile.a_lat, profile.v_max) != (1.8, 13.9)  # fitted on the tracks
    assert main(["predict", "--model", str(tmp_path / "best.npz"), *where, "--horizon", "1",
                 "--out", str(tmp_path / "pred.csv")]) == 0
    assert "mean displacement error" in capsys.readouterr().out
    assert main(["fit-model", *where, "--preset", "paper", "--learner", "tirl", "--window", "1",
                 "--out", str(tmp_path / "paper")]) == 0
    assert "over ['speed_dev', 'acc_sq', 'jerk_sq']" in capsys.readouterr().out
    profile = load_learner(tmp_path / "paper.npz").model_.features.features[0].residual.profile
    assert (profile.a_lat, profile.v_max) == (1.8, 13.9)
