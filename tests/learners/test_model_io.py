"""Fitted learners pickle and round-trip through the versioned model file (pirl_sim.learners.model_io)."""

import json
import pickle
import warnings

import numpy as np
import pytest

from pirl_sim.driving import CompositePath, PathDriverModel, SpeedProfile, roundabout_features
from pirl_sim.dynamics import longitudinal
from pirl_sim.features import Feature, FeatureSet, Residual
from pirl_sim.learners import PIRLDPGMM, PIRLGMM, PIRLKNN, TIRL
from pirl_sim.learners.model_io import (
    FORMAT_VERSION,
    load_learner,
    model_from_config,
    model_to_config,
    read_header,
    save_learner,
)
from pirl_sim.model import DriverModel, synthetic_model
from pirl_sim.mpc import Bounds
from pirl_sim.paths import ReferencePath
from pirl_sim.receding import RecedingResult
from pirl_sim.scenarios.passage import passage_polyline
from pirl_sim.scenarios.replay import load_replay
from pirl_sim.scenarios.synthetic import SyntheticConfig, generate

from style_demos import roundabout_passages


KINDS = [
    (TIRL, {}),
    (PIRLGMM, {"n_components": 2, "random_state": 0}),
    (PIRLGMM, {"n_components": "bic", "max_components": 3, "random_state": 0}),
    (PIRLDPGMM, {"random_state": 0}),
    (PIRLKNN, {"n_neighbors": 3, "prior": "population"}),
    (PIRLGMM, {"n_components": 2, "random_state": 0, "space": "weights"}),
    (PIRLDPGMM, {"random_state": 0, "space": "weights", "max_components": 4}),
    (PIRLKNN, {"n_neighbors": 5, "weighting": "likelihood"}),
]


@pytest.fixture(scope="module")
def synthetic():
    return generate(SyntheticConfig(n_trajectories=160, n_train=120, seed=3))


@pytest.fixture(scope="module")
def passage():
    return roundabout_passages(n_trajectories=60, n_train=50, n_steps=15)


def _fit(cls, params, model, train):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return cls(model, **params).fit(train)


def _same_predictions(a, b, test, horizon=6):
    np.testing.assert_array_equal(a.infer_weights(test), b.infer_weights(test))
    np.testing.assert_array_equal(a.predict_states(test, horizon), b.predict_states(test, horizon))
    if hasattr(a, "predict_style"):
        np.testing.assert_array_equal(a.predict_style(test), b.predict_style(test))
        np.testing.assert_array_equal(a.predict_proba(test), b.predict_proba(test))


@pytest.mark.parametrize("cls,params", KINDS, ids=lambda v: getattr(v, "__name__", str(v)))
def test_synthetic_learners_round_trip_through_pickle_and_the_file(cls, params, synthetic, tmp_path):
    learner = _fit(cls, params, None, synthetic.train)
    _same_predictions(learner, pickle.loads(pickle.dumps(learner)), synthetic.test)
    path = learner.save(tmp_path / "model")
    assert path.suffix == ".npz"
    back = load_learner(path)
    assert type(back) is cls and back.get_params(deep=False).keys() == learner.get_params(deep=False).keys()
    assert {k: v for k, v in back.get_params().items() if k != "model"} == \
        {k: v for k, v in learner.get_params().items() if k != "model"}
    _same_predictions(learner, back, synthetic.test)
    np.testing.assert_array_equal(back.irl_result_.normalized, learner.irl_result_.normalized)


@pytest.mark.parametrize("cls,params", KINDS[:5], ids=lambda v: getattr(v, "__name__", str(v)))
def test_path_model_learners_round_trip(cls, params, passage, tmp_path):
    learner = _fit(cls, {**params, "n_components": 3} if "n_components" in params and params["n_components"] != "bic"
                   else params, passage.model, passage.train)
    test = passage.test[:4]
    _same_predictions(learner, pickle.loads(pickle.dumps(learner)), test, 5)
    back = load_learner(save_learner(learner, tmp_path / "path_model.npz"))
    assert isinstance(back.model_, PathDriverModel)
    _same_predictions(learner, back, test, 5)


def test_file_is_an_npz_with_a_json_header_and_no_pickle(synthetic, tmp_path):
    path = _fit(PIRLGMM, {"random_state": 0}, None, synthetic.train).save(tmp_path / "m.npz")
    with np.load(path, allow_pickle=False) as data:
        header = json.loads(bytes(data["header"]).decode("utf-8"))
        assert header["format"] == "pirl_sim.learner" and header["format_version"] == FORMAT_VERSION
        assert header["learner"] == "PIRLGMM"
        theta = data[header["state"]["theta_"]["__array__"]]
    assert theta.shape == (2, 2)
    feats = header["state"]["model_"]["__model__"]["features"]
    assert [f["name"] for f in feats["features"]] == ["state_sq", "control_sq"]
    assert read_header(path)["learner"] == "PIRLGMM"


def _rewrite_header(path, change):
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    header = json.loads(bytes(arrays["header"]).decode("utf-8"))
    change(header)
    arrays["header"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(path, **arrays)


def test_other_format_versions_and_other_files_are_refused(synthetic, tmp_path):
    path = _fit(TIRL, {}, None, synthetic.train).save(tmp_path / "m.npz")
    _rewrite_header(path, lambda h: h.update(format_version=FORMAT_VERSION + 1))
    with pytest.raises(ValueError, match=rf"format version {FORMAT_VERSION + 1} is not supported.*reads "
                                         r"version\(s\) 1"):
        load_learner(path)
    _rewrite_header(path, lambda h: h.update(format="something.else", format_version=1))
    with pytest.raises(ValueError, match="not a pirl_sim.learner file"):
        load_learner(path)
    other = tmp_path / "other.npz"
    np.savez(other, x=np.zeros(3))
    with pytest.raises(ValueError, match="no 'header' entry"):
        load_learner(other)
    (tmp_path / "text.npz").write_text("hello")
    with pytest.raises(ValueError, match="not a NumPy .npz archive"):
        load_learner(tmp_path / "text.npz")
    with pytest.raises(FileNotFoundError):
        load_learner(tmp_path / "missing.npz")


def test_what_the_format_cannot_describe_is_a_type_error_naming_it(synthetic, tmp_path):
    def odd(x, u):
        return Residual(u, np.zeros((1, 1, 1, x.shape[-1])), np.ones((1, 1, 1, 1)))

    base = synthetic_model()
    model = DriverModel(base.dynamics, FeatureSet((base.features.features[0], Feature("odd", odd)), reference="odd"))
    learner = _fit(TIRL, {}, model, synthetic.train)
    with pytest.raises(TypeError, match="feature 'odd' has a residual of type function"):
        learner.save(tmp_path / "m")
    gen = _fit(PIRLGMM, {"random_state": np.random.RandomState(0)}, None, synthetic.train)
    with pytest.raises(TypeError, match="params.random_state: cannot store a RandomState"):
        gen.save(tmp_path / "g")


def test_receding_results_and_composite_paths_round_trip(synthetic, tmp_path):
    learner = _fit(TIRL, {}, None, synthetic.train)
    learner.irl_result_ = RecedingResult(
        theta=np.ones((1, 2)), normalized=np.ones((1, 2)), beta=np.array([4.0]), sigma=np.array([0.5]),
        neg_log_likelihood=np.array([np.inf]), n_steps=np.array([10]), at_bound=np.zeros((1, 2), bool),
        converged=np.array([True]), n_iter=3, n_regularized=0, n_bounded=1, log_se=np.array([[0.0, np.inf]]))
    back = load_learner(learner.save(tmp_path / "r"))
    assert back.irl_result_.neg_log_likelihood[0] == np.inf and back.irl_result_.n_bounded == 1
    np.testing.assert_array_equal(back.irl_result_.log_se, [[0.0, np.inf]])
    assert back.irl_result_.at_bound.dtype == bool

    # a replay-like model: two routes on one arc-length axis, the desired speed from a smoothed curvature table
    a = ReferencePath.from_polyline(passage_polyline(20.0, 30.0, 90.0, 20.0))
    b = ReferencePath.from_polyline(passage_polyline(15.0, 20.0, 180.0, 20.0))
    comp = CompositePath((a, b), gap=200.0)
    profile_path = CompositePath((a, b), gap=200.0)
    object.__setattr__(profile_path, "kappa", profile_path.kappa * 0.9)
    bounds = Bounds(state={"v [m/s]": (0.0, 30.0)}, control={})
    names = longitudinal(0.2).state_names
    assert "v [m/s]" in names
    model = PathDriverModel(longitudinal(0.2), roundabout_features(SpeedProfile(profile_path, 1.5, 12.0)), bounds,
                            path=comp, n_iter=7)
    cfg, arrays = model_to_config(model)
    back = model_from_config(json.loads(json.dumps(cfg)), arrays)
    assert back.n_iter == 7 and back.bounds == bounds
    x0 = np.array([[5.0, 8.0, 0.0], [comp.offsets[1] + 3.0, 6.0, 0.5]])
    theta = np.array([1.0, 0.1, 1.0])
    np.testing.assert_array_equal(back.predict_states(x0, theta, 8), model.predict_states(x0, theta, 8))
    states = model.predict_states(x0, theta, 8)
    controls = model.dynamics.controls_from_states(states)
    np.testing.assert_array_equal(back.features.values(states, controls), model.features.values(states, controls))
    np.testing.assert_array_equal(back.positions(states), model.positions(states))


def test_a_learner_on_the_following_features_round_trips_through_the_model_file(tmp_path):
    from pirl_sim.dynamics import following
    from pirl_sim.learners import TIRL
    from pirl_sim.learners.model_io import load_learner
    from pirl_sim.trajectory import Trajectory

    path = ReferencePath.from_polyline(np.column_stack([np.linspace(0, 400, 81), np.zeros(81)]))
    model = PathDriverModel(following(0.2), roundabout_features(SpeedProfile(path, 1.8, 10.0), "following"),
                            None, path=path)
    rng = np.random.default_rng(0)
    x0 = np.column_stack([np.zeros(6), rng.uniform(4, 9, 6), np.zeros(6), rng.uniform(5, 40, 6), rng.uniform(0, 8, 6)])
    theta = np.array([1.0, 1.0, 1.0, 0.05, 0.05, 3.0])
    states = model.predict_states(x0, np.tile(theta, (6, 1)), 20)
    demos = [Trajectory(s, model.dynamics.controls_from_states(s), 0.2) for s in states]
    learner = TIRL(model=model, window=10).fit(demos)
    back = load_learner(learner.save(tmp_path / "tirl.npz"))
    np.testing.assert_array_equal(back.infer_weights(demos), learner.infer_weights(demos))


def test_a_next_learner_with_restarted_segments_and_the_road_ahead_saves_and_loads(passage_scene, tmp_path):
    from pirl_sim.learners import PIRLKNN
    from pirl_sim.learners.model_io import load_learner, save_learner

    out, _ = passage_scene
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
