"""PIRL-kNN with costs of what drivers did next (target="next"), situation look-ups and averaged futures
(issue 12)."""

import numpy as np
import pytest

from pirl_sim.learners import PIRLKNN
from pirl_sim.model import synthetic_model
from pirl_sim.trajectory import Trajectory


def _phase(model, x0, theta, n):
    states = model.predict_states(np.atleast_2d(x0), np.atleast_2d(theta), n)[0]
    return states


def _switching_drivers(model, rng, n=40):
    """Point mass regulated to 0: gently (q/r = 0.05) for 20 steps, then hard (q/r = 20) for 20 more, each
    phase the optimum of its own cost from where the last one ended."""
    out = []
    for _ in range(n):
        x0 = np.array([rng.uniform(1.0, 3.0), 0.0])
        a = _phase(model, x0, [0.05, 1.0], 20)
        b = _phase(model, a[-1], [20.0, 1.0], 20)
        states = np.vstack([a, b[1:]])
        controls = np.diff(states[:, 1])[:, None] / model.dynamics.dt
        out.append(Trajectory(states, controls, model.dynamics.dt))
    return out


def test_next_costs_predict_a_switch_that_whole_track_costs_average_away():
    model = synthetic_model()
    rng = np.random.default_rng(0)
    train, test = _switching_drivers(model, rng), _switching_drivers(model, rng, 10)
    hist = [t.window(10, 20) for t in test]  # histories that end at the switch
    truth = np.stack([t.states[20:31, 0] for t in test])
    common = dict(model=model, window=10, stride=2, n_neighbors=3)
    demo = PIRLKNN(**common).fit(train)
    nxt = PIRLKNN(**common, target="next", target_steps=10, state_features=(0, 1), aggregate="futures").fit(train)
    assert len(nxt.demo_theta_) == len(nxt.sample_theta_) == 40 * len(range(0, 40 - 10 - 10 + 1, 2))
    err = {name: np.abs(learner.predict_states(hist, 10)[:, :, 0] - truth).mean()
           for name, learner in (("demo", demo), ("next", nxt))}
    assert err["next"] < 0.7 * err["demo"], err  # measured 0.21 vs 0.34 m
    # the averaged future is the vote-weighted mean of predict_futures
    states, proba = nxt.predict_futures(hist, 10)
    np.testing.assert_allclose(nxt.predict_states(hist, 10), np.einsum("mk,mk...->m...", proba, states))
    one = nxt.predict_states(hist[0], 10)
    np.testing.assert_allclose(one, nxt.predict_states(hist, 10)[0])
    # aggregate="weights": one future under the averaged weights, as the base learner predicts
    w = PIRLKNN(**common, target="next", target_steps=10, state_features=(0, 1)).fit(train)
    np.testing.assert_allclose(w.predict_states(hist, 10),
                               model.predict_states(np.stack([h.states[-1] for h in hist]), w.infer_weights(hist), 10))


def test_state_features_enter_the_look_up():
    model = synthetic_model()
    train = _switching_drivers(model, np.random.default_rng(1), 12)
    plain = PIRLKNN(model=model, window=10, stride=5).fit(train)
    with_state = PIRLKNN(model=model, window=10, stride=5, state_features=(1,)).fit(train)
    assert with_state.neighbors_._fit_X.shape[1] == plain.neighbors_._fit_X.shape[1] + 1


def test_motion_look_up_takes_states_at_lags_and_can_leave_the_features_out():
    model = synthetic_model()
    rng = np.random.default_rng(3)
    train, test = _switching_drivers(model, rng, 12), _switching_drivers(model, rng, 4)
    motion = PIRLKNN(model=model, window=10, stride=5, state_features=(0, 1), state_lags=(0, 4),
                     lookup_features=False).fit(train)
    assert motion.neighbors_._fit_X.shape[1] == 4  # (p, v) now and 4 steps earlier, no features
    hist = [t.window(10, 20) for t in test]
    raw = np.stack([np.r_[h.states[-1], h.states[-5]] for h in hist])
    np.testing.assert_allclose(motion._lookup(hist), motion.scaler_.transform(raw))
    # on the switching drivers it finds what follows as well as the feature look-up does
    truth = np.stack([t.states[20:31, 0] for t in test])
    common = dict(model=model, window=10, stride=2, n_neighbors=3, target="next", target_steps=10,
                  aggregate="futures")
    err = {}
    for name, extra in (("features", {"state_features": (0, 1)}),
                        ("motion", {"state_features": (0, 1), "state_lags": (0, 5), "lookup_features": False})):
        learner = PIRLKNN(**common, **extra).fit(train)
        err[name] = np.abs(learner.predict_states(hist, 10)[:, :, 0] - truth).mean()
    assert err["motion"] < 1.5 * err["features"] + 0.01, err
    with pytest.raises(ValueError, match="state_lags reach 12"):
        PIRLKNN(model=model, window=10, stride=5, state_features=(1,), state_lags=(0, 12)).fit(train)


@pytest.mark.parametrize("params, error, match", [
    ({"window": 10, "state_features": (1,), "state_lags": ()}, ValueError, "state_lags"),
    ({"window": 10, "state_features": (1,), "state_lags": (-1,)}, ValueError, "state_lags"),
    ({"window": 10, "state_features": (1,), "state_lags": 3}, TypeError, "state_lags"),
    ({"window": 10, "lookup_features": False}, ValueError, "state_features alone"),
    ({"window": 10, "state_features": (1,), "lookup_features": "no"}, TypeError, "lookup_features"),
    ({"target": "future", "window": 10}, ValueError, "target must be one of"),
    ({"target": "next"}, ValueError, "needs window"),
    ({"target": "next", "window": 10}, ValueError, "target_steps"),
    ({"target": "next", "window": 10, "target_steps": 0}, ValueError, "target_steps"),
    ({"target": "next", "window": 10, "target_steps": 5, "weighting": "likelihood"}, ValueError, "weighting"),
    ({"window": 10, "aggregate": "median"}, ValueError, "aggregate must be one of"),
    ({"window": 10, "state_features": (2,)}, ValueError, "state_features"),
    ({"window": 10, "state_features": 1}, TypeError, "state_features"),
    ({"target": "next", "window": 30, "target_steps": 30}, ValueError, "no training trajectory"),
    ({"window": 10, "irl_max_iter": 0}, ValueError, "irl_max_iter"),
])
def test_bad_next_parameters_name_the_value(params, error, match):
    model = synthetic_model()
    train = _switching_drivers(model, np.random.default_rng(2), 4)
    with pytest.raises(error, match=match):
        PIRLKNN(model=model, **params).fit(train)


def _replay_args(tmp_path, seed: int, learners: str, knn_k: str) -> list:
    """`pirl-sim replay` arguments (one split seed) on a small simulated three-style passage scene."""
    import warnings

    from pirl_sim.scenarios.passage import PassageConfig, generate, write_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate(PassageConfig(n_trajectories=40, n_train=30, seed=seed))
    write_scene(data, tmp_path / "scene")
    return ["replay", "--tracks", str(tmp_path / "scene"), "--map", str(tmp_path / "scene" / "map.osm"),
            "--learners", learners, "--knn-k", knn_k, "--seeds", "1"]


def test_replay_cli_runs_the_next_learner_and_keeps_it_out_of_the_papers_ordering(tmp_path):
    import pandas as pd

    from pirl_sim.cli import main

    args = _replay_args(tmp_path, 5, "tirl,pirl-knn,pirl-knn-next", "3,5")
    assert main([*args, "--hindsight", "--out", str(tmp_path / "out")]) == 0
    rows = pd.read_csv(tmp_path / "out" / "rows.csv")
    med = rows.set_index("method")["med"]
    # the oracle row: each test window under the cost fitted on its own future beats every predictor
    assert med["hindsight cost (oracle)"] < 0.5 * med["CA (path)"]
    assert med["hindsight cost (oracle)"] < med.drop("hindsight cost (oracle)").min()
    nxt = rows[rows["method"].str.startswith("PIRL-kNN next")]
    assert sorted(nxt["method"]) == ["PIRL-kNN next (k=3)", "PIRL-kNN next (k=5)"]
    assert (nxt["irl_converged"] == nxt["irl_groups"]).all() and (nxt["irl_groups"] > 30).all()
    assert nxt["med"].notna().all() and (nxt["med"] > 0).all()
    assert nxt.set_index("method").loc["PIRL-kNN next (k=5)", "irl_from"] == "PIRL-kNN next (k=3)"
    assert nxt["ahead_weight"].isin([0.0, 0.5, 1.0]).all()  # the road's weight each split chose
    assert main([*args, "--rollout", "closed", "--mpc-horizon", "15", "--out", str(tmp_path / "bad")]) == 2


def test_replay_cli_sets_the_next_learners_segments_and_road_ahead(tmp_path, capsys):
    """pirl-knn-next: segments re-started at the history estimates and the curvature 0-45 m ahead in the
    look-up by default; --next-segments history needs history starts; bad distances are named."""
    from pirl_sim.cli import build_parser, main
    from pirl_sim.cli.replay import replay_config, replay_settings

    args = _replay_args(tmp_path, 5, "pirl-knn-next", "3")
    ns = build_parser().parse_args(args)
    config = replay_config(ns, replay_settings(ns), ns.tracks, ns.map)
    (nxt,) = [e for e in config.experiments[0].learners if e.params.get("target") == "next"]
    assert nxt.params["segment_start"] == "history" and nxt.params["lookup_history"] is True
    assert list(nxt.params["lookup_ahead"]) == [0.0, 10.0, 20.0, 30.0, 45.0]
    assert list(nxt.params["ahead_weights"]) == [0.0, 0.5, 1.0]
    ns = build_parser().parse_args([*args, "--next-segments", "track", "--lookup-ahead", ""])
    config = replay_config(ns, replay_settings(ns), ns.tracks, ns.map)
    (nxt,) = [e for e in config.experiments[0].learners if e.params.get("target") == "next"]
    assert nxt.params["segment_start"] == "track" and list(nxt.params["lookup_ahead"]) == []
    assert main([*args, "--start", "track", "--next-segments", "history", "--out", str(tmp_path / "bad")]) == 2
    assert "--next-segments history" in capsys.readouterr().err
    for bad in ("-1", "5,far", "inf"):
        for option in ("--lookup-ahead", "--ahead-weights"):
            with pytest.raises(SystemExit):
                build_parser().parse_args([*args, f"{option}={bad}"])
    # an empty weight list is refused by the learner's check, named
    assert main([*args, "--ahead-weights=", "--out", str(tmp_path / "bad2")]) == 2
    assert "ahead_weights" in capsys.readouterr().err


def test_replay_cli_runs_the_selected_bank_once_whatever_the_k_grid(tmp_path):
    """pirl-select: the next-segment costs of pirl-knn-next, mixed to follow a forecast (learners/selector.py);
    one row per split (no k), the same segment and road-ahead settings as pirl-knn-next."""
    import pandas as pd

    from pirl_sim.cli import build_parser, main
    from pirl_sim.cli.replay import replay_config, replay_settings

    args = _replay_args(tmp_path, 5, "tirl,pirl-knn-next,pirl-select", "3,5")
    ns = build_parser().parse_args(args)
    config = replay_config(ns, replay_settings(ns), ns.tracks, ns.map)
    (sel,) = [e for e in config.experiments[0].learners if e.params.get("aggregate") == "selected"]
    assert sel.params["target"] == "next" and sel.params["segment_start"] == "history"
    assert sel.params["target_steps"] == 15 and list(sel.params["lookup_ahead"]) == [0.0, 10.0, 20.0, 30.0, 45.0]
    assert main([*args, "--out", str(tmp_path / "out")]) == 0
    rows = pd.read_csv(tmp_path / "out" / "rows.csv").set_index("method")
    assert "PIRL-select" in rows.index and not any(m.startswith("PIRL-select (") for m in rows.index)
    assert rows.loc["PIRL-select", "irl_converged"] == rows.loc["PIRL-select", "irl_groups"] > 30
    assert 0 < rows.loc["PIRL-select", "med"] < rows.loc["CV (path)", "med"]


def test_replay_scores_k_futures_of_each_learner(tmp_path):
    import pandas as pd

    from pirl_sim.cli import main

    args = [*_replay_args(tmp_path, 6, "tirl,pirl-gmm,pirl-knn-next", "6"), "--futures", "6"]
    assert main([*args, "--out", str(tmp_path / "out")]) == 0
    rows = pd.read_csv(tmp_path / "out" / "rows.csv").set_index("method")
    learners = ["TIRL", "PIRL-GMM (k=3)", "PIRL-kNN next (k=6)"]
    for col in ("min_ade@6", "min_fde@6", "miss_rate@6", "nll_per_step@6"):
        assert rows.loc[learners, col].notna().all(), col
        assert rows.loc[["CA (path)", "CV (path)"], col].isna().all()
    # TIRL has one future: its minADE is its MED; more futures can only lower the best one's error
    assert rows.loc["TIRL", "min_ade@6"] == pytest.approx(rows.loc["TIRL", "med"])
    assert rows.loc["PIRL-kNN next (k=6)", "min_ade@6"] <= rows.loc["PIRL-kNN next (k=6)", "med"] + 1e-9
    assert ((rows.loc[learners, "miss_rate@6"] >= 0) & (rows.loc[learners, "miss_rate@6"] <= 1)).all()
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "min_ade@6_mean" in summary
    # futures are open-loop plans: a closed-loop rollout is refused before any fit
    assert main([*args, "--rollout", "closed", "--mpc-horizon", "15", "--out", str(tmp_path / "bad")]) == 2


@pytest.mark.parametrize("key", ["tirl", "pirl-gmm", "pirl-dpgmm", "pirl-knn"])
def test_every_learner_takes_the_irl_iteration_budget(key):
    from pirl_sim.learners import make_learner

    model = synthetic_model()
    train = _switching_drivers(model, np.random.default_rng(4), 6)
    assert make_learner(key, model=model).get_params()["irl_max_iter"] == 100
    with pytest.raises(ValueError, match="irl_max_iter"):
        make_learner(key, model=model, irl_max_iter=0).fit(train)
