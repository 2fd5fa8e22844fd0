"""The replay's reference without a cost (`pirl_sim.evaluation.direct`): the arc lengths ahead regressed on the history
and the place, on generated roundabout-passage data."""

import numpy as np
import pandas as pd
import pytest

from pirl_sim.scenarios.replay import load_replay
from pirl_sim.evaluation.baselines import KinematicModel
from pirl_sim.evaluation.direct import DIRECT, DirectRegression

from replay_scenes import passage_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out, _ = passage_scene(tmp_path_factory.mktemp("passage"), n_trajectories=60, n_train=50, seed=3)
    return load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm", estimate="speeds"), out


def _windows(tracks, T=10, F=15, stride=5):
    hist, truth = [], []
    for t in tracks:
        for start in range(0, t.n_steps - T - F + 1, stride):
            hist.append(t.history_window(start, start + T))
            truth.append(t.states[start + T + 1 : start + T + F + 1, 0])
    return hist, np.stack(truth)


def test_keys_are_the_history_kinematics_the_road_ahead_and_the_place(scene):
    sc, _ = scene
    reg = DirectRegression(sc.model, 10, 15, lags=(0, 4), ahead=(0.0, 20.0))
    hist, _ = _windows(sc.trajectories[:3])
    z = reg.keys(hist)
    assert z.shape == (len(hist), 2 * 2 + 2 + 4)
    np.testing.assert_allclose(z[:, :4], [np.r_[h.states[-1, 1:3], h.states[-5, 1:3]] for h in hist])
    s_end = np.array([h.states[-1, 0] for h in hist])
    np.testing.assert_allclose(z[:, 4:6], sc.model.curvature(s_end[:, None] + [0.0, 20.0]))
    np.testing.assert_allclose(z[:, 6:8], sc.model.path.to_cartesian(s_end, np.zeros_like(s_end)))
    np.testing.assert_allclose(np.linalg.norm(z[:, 8:], axis=1), 1.0)  # the path's heading, a unit vector


def test_it_predicts_held_out_tracks_better_than_constant_acceleration_and_repeats_itself(scene):
    sc, _ = scene
    train, test = sc.trajectories[:45], sc.trajectories[45:]
    reg = DirectRegression(sc.model, 10, 15).fit(train)
    assert reg.n_samples_ > 100 and len(reg.regression_.models_) == 15
    hist, truth = _windows(test)
    s = reg.predict_s(hist)
    assert s.shape == truth.shape and np.all(np.isfinite(s))
    x0 = np.stack([h.states[-1] for h in hist])
    ca = KinematicModel(sc.model, "ca").predict_states(x0, None, 15)[:, 1:, 0]
    err, err_ca = np.abs(s - truth).mean(), np.abs(ca - truth).mean()
    assert err < 0.8 * err_ca, (err, err_ca)
    again = DirectRegression(sc.model, 10, 15).fit(train).predict_s(hist)
    assert again.tobytes() == s.tobytes()  # fixed seed, no early stopping: same data, same bytes


@pytest.mark.parametrize("kwargs, match", [
    ({"window": 0}, "window must be a positive integer"),
    ({"horizon": 2.5}, "horizon must be a positive integer"),
    ({"lags": (0, 11)}, "lags must be whole numbers"),
    ({"lags": ()}, "lags must be whole numbers"),
    ({"ahead": (-1.0,)}, "ahead must be finite distances"),
    ({"learning_rate": 0.0}, "learning_rate must be in"),
    ({"stride": -1}, "stride must be a positive integer"),
])
def test_bad_settings_name_the_value(scene, kwargs, match):
    sc, _ = scene
    args = {"window": 10, "horizon": 15, **kwargs}
    with pytest.raises(ValueError, match=match):
        DirectRegression(sc.model, args.pop("window"), args.pop("horizon"), **args)


def test_unfitted_or_starved_regressions_say_so(scene):
    sc, _ = scene
    reg = DirectRegression(sc.model, 10, 15)
    with pytest.raises(ValueError, match="not fitted"):
        reg.predict_s(_windows(sc.trajectories[:1])[0])
    with pytest.raises(ValueError, match="at least 2 training windows"):
        DirectRegression(sc.model, 10, 500).fit(sc.trajectories[:3])
    with pytest.raises(TypeError, match="model along a path"):
        DirectRegression(object(), 10, 15)


def test_replay_cli_scores_the_direct_regression_beside_the_learners(scene, tmp_path):
    from pirl_sim.cli import main

    _, out = scene
    args = ["replay", "--preset", "paper",
            "--tracks", str(out), "--map", str(out / "map.osm"), "--learners", "tirl", "--seeds", "1",
            "--direct", "--out", str(tmp_path / "out")]
    assert main(args) == 0
    rows = pd.read_csv(tmp_path / "out" / "rows.csv").set_index("method")
    assert DIRECT in rows.index and np.isfinite(rows.loc[DIRECT, "med"])
    assert rows.loc[DIRECT, "med"] < rows.loc["CA (path)", "med"]
    plain_args = [a for a in args[:-2] if a != "--direct"]
    assert main([*plain_args, "--out", str(tmp_path / "plain")]) == 0
    plain = pd.read_csv(tmp_path / "plain" / "rows.csv")
    assert DIRECT not in set(plain["method"])  # only with --direct
