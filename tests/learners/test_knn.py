"""PIRL-kNN (pirl_sim.learners.knn): exact matches and inverse distances, the population prior, online windows,
another k without refitting, next-step costs with states, motion and the road ahead in the look-up, the
likelihood weighting, and a style switch followed online."""

import warnings

import numpy as np
import pytest
from sklearn.exceptions import NotFittedError

from pirl_sim.evaluation.protocols import Protocol, evaluate
from pirl_sim.learners import PIRLKNN, TIRL
from pirl_sim.learners.knn import knn_average
from pirl_sim.metrics import weight_recovery_error
from pirl_sim.model import synthetic_model
from pirl_sim.population import Population, Style, generate_demonstrations
from pirl_sim.scenarios.replay import load_replay
from pirl_sim.scenarios.synthetic import SyntheticConfig, generate
from pirl_sim.simulate import simulate_receding_horizon
from pirl_sim.trajectory import Trajectory

from style_demos import roundabout_passages


@pytest.fixture(scope="module")
def small():
    return generate(SyntheticConfig(n_trajectories=300, n_train=240, seed=3))


def test_knn_exact_match_and_inverse_distance():
    dist = np.array([[0.0, 1.0], [1.0, 3.0]])
    theta = np.array([[[2.0, 1.0], [8.0, 1.0]], [[2.0, 1.0], [8.0, 1.0]]])
    out = knn_average(dist, theta, "linear")
    np.testing.assert_allclose(out[0], [2.0, 1.0])  # exact match wins alone
    np.testing.assert_allclose(out[1], [(2 * 1 + 8 / 3) / (1 + 1 / 3), 1.0])
    out_log = knn_average(dist, theta, "log")
    np.testing.assert_allclose(out_log[1, 0], np.exp((np.log(2) + np.log(8) / 3) / (4 / 3)))


def test_knn_recovers_each_demo_on_noise_free_data(small):
    knn = PIRLKNN(n_neighbors=1).fit(small.train)
    true = np.stack([t.metadata["theta"] for t in small.train])
    np.testing.assert_allclose(knn.demo_theta_, true, rtol=1e-3)
    assert knn.n_weights_at_bound_ == 0
    assert knn.n_scale_at_bound_ == len(small.train)  # noise-free: only the direction is identified
    # a training trajectory queried again is an exact match: its own weights come back
    np.testing.assert_allclose(knn.infer_weights(small.train[:5]), true[:5], rtol=1e-3)


def test_knn_population_prior_runs_and_stays_close(model, rng):
    x0 = np.column_stack([rng.uniform(-3, 3, 80), rng.uniform(-1, 1, 80)])
    pop = Population(model.features, (Style("s", 1.0, {"state_sq": 2.0}, {"state_sq": 0.5}),), rationality=5.0)
    demos = generate_demonstrations(model, pop, x0, 30, rng)
    ml = PIRLKNN().fit(demos)
    mapk = PIRLKNN(prior="population").fit(demos)
    true = np.array([d.metadata["theta"][0] for d in demos])
    err_ml = np.median(np.abs(np.log(ml.demo_theta_[:, 0] / true)))
    err_map = np.median(np.abs(np.log(mapk.demo_theta_[:, 0] / true)))
    assert err_map <= err_ml  # shrinkage towards the population helps weakly identified demos


def test_online_windows_and_short_history(small):
    knn = PIRLKNN(n_neighbors=3, window=10, windows="first").fit(small.train)
    assert len(knn.sample_theta_) == len(small.train)
    sliding = PIRLKNN(n_neighbors=3, window=10, stride=5).fit(small.train)
    assert len(sliding.sample_theta_) == len(small.train) * 9
    with pytest.raises(ValueError, match="shorter than the feature window of 10 steps"):
        knn.infer_weights(small.test[0].window(0, 5))


@pytest.mark.parametrize("options", [{}, {"window": 10, "windows": "first", "weighting": "likelihood"}])
def test_knn_with_neighbors_equals_refitting(small, options):
    base = PIRLKNN(n_neighbors=1, **options).fit(small.train)
    test = small.test[:12]
    histories = [t.window(0, 10) for t in test] if options else test
    for k in (2, 7):
        refit = PIRLKNN(n_neighbors=k, **options).fit(small.train)
        derived = base.with_neighbors(k)
        assert derived.get_params()["n_neighbors"] == k and base.n_neighbors == 1
        assert derived.irl_result_ is base.irl_result_ and derived.scaler_ is base.scaler_  # shared, not refitted
        np.testing.assert_array_equal(derived.infer_weights(histories), refit.infer_weights(histories))
        np.testing.assert_array_equal(derived.predict_states(histories, 5), refit.predict_states(histories, 5))
        for a, b in zip(derived.predict_futures(histories, 5), refit.predict_futures(histories, 5)):
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(base.infer_weights(histories), PIRLKNN(**options).fit(small.train).infer_weights(histories))
    with pytest.raises(ValueError, match="larger than the number of training samples"):
        base.with_neighbors(10_000)
    with pytest.raises(ValueError, match="positive integer"):
        base.with_neighbors(0)
    with pytest.raises(NotFittedError):
        PIRLKNN().with_neighbors(2)


def _switching_drivers(model, rng, n=40):
    """Point mass regulated to 0, gently for 20 steps then hard for 20 more (`style_demos.switching_drivers`)."""
    from style_demos import switching_drivers

    return switching_drivers(model, rng, n)


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


def _small_scene(passage_scene, n=48):
    import dataclasses

    out, _ = passage_scene
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm")
    return dataclasses.replace(scene, trajectories=scene.trajectories[:n], n_tracks=n, track_table=None)


def test_knn_with_another_k_equals_refitting(passage_scene):
    from pirl_sim.learners import PIRLKNN

    scene = _small_scene(passage_scene)
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


def test_next_step_knn_looks_up_training_histories_as_an_online_query_sees_them(passage_scene):
    """lookup_history=True: the training histories' look-up keys are their own estimates (the same as a query
    of that history gets), not the smoothed track's; without an estimator (simulated states) nothing changes."""
    from pirl_sim.learners import PIRLKNN

    out, _ = passage_scene
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


def test_next_segments_restarted_at_the_history_estimate_follow_the_track(passage_scene):
    """segment_start="history": every training segment whose cost the IRL fits starts exactly at its history's
    own estimate (the state an online prediction starts from) and follows the track's positions and speeds; the
    look-up keys are unchanged, the costs differ; it needs lookup_history."""
    from pirl_sim.learners import PIRLKNN

    out, _ = passage_scene
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


def test_the_road_ahead_enters_the_look_up(passage_scene):
    """lookup_ahead: |curvature| of the model's speed profile at those distances beyond each window's end are
    look-up keys, standardised with the rest."""
    from pirl_sim.learners import PIRLKNN
    from pirl_sim.model import synthetic_model

    out, _ = passage_scene
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


def test_several_road_weights_are_chosen_on_held_out_windows_of_other_tracks(passage_scene):
    """ahead_weights with several candidates: each scored by the look-up's error along the path on held-out
    training windows whose neighbours come from other tracks; the best is used, also after with_neighbors."""
    from pirl_sim.learners import PIRLKNN

    out, _ = passage_scene
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


@pytest.fixture(scope="module")
def passage():
    return roundabout_passages()


def test_knn_beats_tirl_online(passage):
    proto = Protocol("rolling", 10, "sliding", horizon=15, stride=5)
    rows = {}
    for learner in (TIRL(passage.model), PIRLKNN(passage.model, n_neighbors=10, stride=2)):
        learner.set_params(**proto.learner_params())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            learner.fit(passage.train)
        rows[type(learner).__name__] = evaluate(learner, passage.test, proto)["med"]
    assert rows["PIRLKNN"] < 0.7 * rows["TIRL"]


def test_a_style_switch_is_followed_within_five_steps(passage):
    model = passage.model
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        knn = PIRLKNN(model, n_neighbors=10, window=10, stride=2).fit(passage.train)
    calm = model.features.weights({"speed_dev": 0.1, "acc_sq": 3.0, "jerk_sq": 1.0})
    eager = model.features.weights({"speed_dev": 3.0, "acc_sq": 0.3, "jerk_sq": 1.0})
    M, switch = 8, 20
    rng = np.random.default_rng(2)
    x0 = np.column_stack([np.zeros(M), rng.uniform(10, 12, M), np.zeros(M)])
    trajs = simulate_receding_horizon(
        model, x0, lambda k: np.tile(calm if k < switch else eager, (M, 1)), 45, 25, rng=rng, control_noise=0.3
    )
    log_ratio = lambda t: np.median(np.log(knn.infer_weights([tr.window(t - 10, t) for tr in trajs])[:, 0]))
    before = log_ratio(switch)
    after = log_ratio(switch + 5)
    assert before < np.log(0.5)  # calm: small speed_dev weight
    assert after > np.log(1.0)  # five steps after the switch the eager style is inferred
    assert np.array_equal(trajs[0].metadata["theta_schedule"][switch], eager)


@pytest.fixture(scope="module")
def three_styles():
    """Boltzmann-rational LQ drivers of three styles from spread start states (train 300, test 60)."""
    from style_demos import three_style_demonstrations

    return three_style_demonstrations(1, 360, 40, 300)


def test_knn_neighbours_weighted_by_their_likelihood_of_the_history(three_styles):
    """PIRL-kNN's analogue of the style posterior: the neighbours whose cost explains the history best count."""
    model, train, test = three_styles
    true = np.stack([t.metadata["theta"] for t in test])
    for params, histories in (({}, test), ({"window": 10, "windows": "first"}, [t.window(0, 10) for t in test])):
        errors = {}
        for weighting in ("distance", "likelihood"):
            knn = PIRLKNN(model, n_neighbors=20, weighting=weighting, **params).fit(train)
            errors[weighting] = np.median(weight_recovery_error(knn.infer_weights(histories), true, 1))
        assert errors["likelihood"] < 0.5 * errors["distance"], (params, errors)
    one = PIRLKNN(model, n_neighbors=1, weighting="likelihood").fit(train)
    np.testing.assert_allclose(one.infer_weights(test), one.sample_theta_[one.neighbors_.kneighbors(
        one._to_space(model.feature_values(test)))[1][:, 0]])  # one neighbour: its weights
    with pytest.raises(ValueError, match=r"weighting must be one of \('distance', 'likelihood'\), got 'vote'"):
        PIRLKNN(model, weighting="vote").fit(train)
