"""Model files: earlier revisions' files read (converted) or refused clearly, versions recorded, damaged headers
and arrays refused naming the file, writes that leave nothing behind on failure."""

import json
import os
import warnings
from pathlib import Path

import numpy as np
import pytest

from pirl_sim.learners import LEARNERS, PIRLDPGMM, PIRLGMM, PIRLKNN, TIRL
from pirl_sim.learners.model_io import (
    FORMAT_VERSION,
    LEARNER_PARAMS,
    LEARNER_STATE,
    load_learner,
    read_header,
    save_learner,
)
from pirl_sim.scenarios.synthetic import SyntheticConfig, generate
from pirl_sim.trajectory import Trajectory

DATA = Path(__file__).parent / "data"
COMMITS = ("c3f80b3", "a24179e", "d2becb5")
NAMES = ("tirl", "pirl-gmm", "pirl-dpgmm", "pirl-knn", "pirl-knn-window")


@pytest.fixture(scope="module")
def synthetic():
    return generate(SyntheticConfig(n_trajectories=60, n_train=48, seed=5))


def _fit(cls, params, train):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return cls(**params).fit(train)


def _arrays(path):
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    return arrays, json.loads(bytes(arrays["header"]).decode("utf-8"))


def _write(path, arrays, header):
    arrays = dict(arrays, header=np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8))
    np.savez(path, **arrays)


@pytest.mark.parametrize("commit", COMMITS)
@pytest.mark.parametrize("name", NAMES)
def test_golden_files_of_earlier_revisions_predict_what_those_revisions_did(commit, name):
    expected = np.load(DATA / f"{commit}_expected.npz")
    hist = [Trajectory(s, c, float(expected["dt"])) for s, c in zip(expected["hist_states"], expected["hist_controls"])]
    assert read_header(DATA / f"{commit}_{name}.npz")["format_version"] == 1
    learner = load_learner(DATA / f"{commit}_{name}.npz")
    assert type(learner) is LEARNERS[name.removesuffix("-window")]
    np.testing.assert_allclose(learner.infer_weights(hist), expected[f"{name}.theta"], rtol=1e-12, atol=0)
    np.testing.assert_allclose(learner.predict_states(hist, 8), expected[f"{name}.states"], rtol=1e-10, atol=1e-12)
    if hasattr(learner, "predict_style"):
        np.testing.assert_array_equal(learner.predict_style(hist), expected[f"{name}.style"])
        np.testing.assert_allclose(learner.predict_proba(hist).sum(axis=1), 1.0)
    assert set(learner.get_params()) == set(LEARNER_PARAMS[type(learner).__name__])


def test_converted_file_saves_again_as_the_current_version(tmp_path):
    learner = load_learner(DATA / "c3f80b3_pirl-knn.npz")
    back = load_learner(save_learner(learner, tmp_path / "again.npz"))
    assert read_header(tmp_path / "again.npz")["format_version"] == FORMAT_VERSION
    assert back.state_idx_ == () and back.irl_max_iter == 100


def test_a_converted_mixture_refuses_what_its_file_cannot_tell_clearly(tmp_path):
    arrays, header = _arrays(DATA / "c3f80b3_pirl-gmm.npz")
    params = dict((k, v) for k, v in header["params"]["__dict__"])
    params.update(window=10, windows="first")  # histories at the start of episodes: their length is not in the file
    header["params"]["__dict__"] = [[k, v] for k, v in params.items()]
    _write(tmp_path / "first.npz", arrays, header)
    learner = load_learner(tmp_path / "first.npz")
    expected = np.load(DATA / "c3f80b3_expected.npz")
    hist = [Trajectory(s, c, float(expected["dt"])) for s, c in zip(expected["hist_states"], expected["hist_controls"])]
    learner.predict_style(hist)  # the feature-space look-up needs nothing more
    with pytest.raises(ValueError, match="episode_steps_.*written before predict_proba existed; refit"):
        learner.predict_proba(hist)


def test_a_version_1_parameter_that_no_longer_exists_is_refused_naming_both_versions(tmp_path):
    arrays, header = _arrays(DATA / "c3f80b3_tirl.npz")
    header["params"]["__dict__"].append(["old_option", 3])
    _write(tmp_path / "old.npz", arrays, header)
    with pytest.raises(ValueError, match=rf"old\.npz: this format version 1 file holds a TIRL with parameter\(s\) "
                                         rf"\['old_option'\].*format version {FORMAT_VERSION}.*refit"):
        load_learner(tmp_path / "old.npz")


def test_files_record_the_package_numpy_and_scikit_learn_versions(synthetic, tmp_path):
    import sklearn

    header = read_header(_fit(TIRL, {}, synthetic.train).save(tmp_path / "m"))
    assert header["format_version"] == FORMAT_VERSION == 2
    assert header["numpy_version"] == np.__version__ and header["scikit_learn_version"] == sklearn.__version__
    assert header["pirl_sim_version"]


def test_a_future_version_is_refused_naming_both_versions_and_what_to_do(synthetic, tmp_path):
    path = _fit(TIRL, {}, synthetic.train).save(tmp_path / "m")
    arrays, header = _arrays(path)
    header.update(format_version=FORMAT_VERSION + 1, pirl_sim_version="9.0")
    _write(path, arrays, header)
    with pytest.raises(ValueError, match=rf"m\.npz: pirl_sim\.learner format version {FORMAT_VERSION + 1} is not "
                                         rf"supported \(written by pirl_sim 9\.0\); this pirl_sim \(.*\) writes "
                                         rf"version {FORMAT_VERSION} and reads version\(s\) 1, 2: upgrade pirl_sim"):
        load_learner(path)


FITS = [(TIRL, {}), (PIRLGMM, {"random_state": 0}), (PIRLGMM, {"n_components": "bic", "max_components": 2}),
        (PIRLGMM, {"random_state": 0, "space": "weights"}), (PIRLDPGMM, {"random_state": 0, "max_components": 3}),
        (PIRLKNN, {"n_neighbors": 2, "prior": "population"}), (PIRLKNN, {"n_neighbors": 2, "weighting": "likelihood"})]


def test_the_format_version_lists_every_parameter_and_fitted_attribute_of_the_learners(synthetic):
    """A learner whose parameters or fitted state change needs a new FORMAT_VERSION (and a converter): the lists of
    the current version must be the learners' own."""
    for cls in LEARNERS.values():
        assert set(cls().get_params()) == set(LEARNER_PARAMS[cls.__name__]), cls.__name__
    for cls, params in FITS:
        learner = _fit(cls, params, synthetic.train[:24])
        state = {k for k in vars(learner) if k.endswith("_") and not k.startswith("_")}
        required, optional = LEARNER_STATE[cls.__name__]
        assert set(required) <= state <= set(required) | set(optional), (cls.__name__, params)


def test_saving_a_learner_whose_state_is_not_the_format_versions_is_refused(synthetic, tmp_path):
    learner = _fit(TIRL, {}, synthetic.train[:24])
    learner.new_thing_ = np.zeros(2)
    with pytest.raises(RuntimeError, match=r"fitted attributes \['new_thing_'\] differ.*needs a new FORMAT_VERSION"):
        learner.save(tmp_path / "m")
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def knn_file(synthetic, tmp_path_factory):
    return _fit(PIRLKNN, {"n_neighbors": 3}, synthetic.train).save(tmp_path_factory.mktemp("knn") / "knn.npz")


def test_an_empty_file_is_a_value_error_naming_it(tmp_path):
    (tmp_path / "empty.npz").write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.npz: not a pirl_sim\.learner file \(the file is empty\)"):
        load_learner(tmp_path / "empty.npz")
    np.save(tmp_path / "one.npy", np.zeros(3))
    with pytest.raises(ValueError, match=r"one\.npy: not a pirl_sim\.learner file \(a single NumPy array"):
        load_learner(tmp_path / "one.npy")


@pytest.mark.parametrize("drop", ["params", "state", "model", "learner"])
def test_a_header_without_its_parts_is_a_value_error_naming_the_file(knn_file, tmp_path, drop):
    arrays, header = _arrays(knn_file)
    del header[drop]
    _write(tmp_path / "h.npz", arrays, header)
    with pytest.raises(ValueError, match=rf"h\.npz: the header of this pirl_sim\.learner file lacks '{drop}'"):
        load_learner(tmp_path / "h.npz")
    with pytest.raises(ValueError, match=rf"h\.npz: .*lacks '{drop}'"):
        read_header(tmp_path / "h.npz")


def test_a_header_of_the_wrong_kind_is_a_value_error_naming_the_file(knn_file, tmp_path):
    arrays, header = _arrays(knn_file)
    header["params"] = [1, 2]
    _write(tmp_path / "k.npz", arrays, header)
    with pytest.raises(ValueError, match=r"k\.npz: the header's 'params' is not of the right kind"):
        load_learner(tmp_path / "k.npz")
    arrays, header = _arrays(knn_file)
    header["state"]["demo_theta_"] = {"__dataclass__": "IRLResult", "fields": {"theta": 1}}
    _write(tmp_path / "d.npz", arrays, header)
    with pytest.raises(ValueError, match=r"d\.npz: the header cannot be decoded \(TypeError"):
        load_learner(tmp_path / "d.npz")
    arrays, header = _arrays(knn_file)
    del header["state"]["neighbors_"]
    _write(tmp_path / "s.npz", arrays, header)
    with pytest.raises(ValueError, match=r"s\.npz: the fitted state of the PIRLKNN lacks \['neighbors_'\]"):
        load_learner(tmp_path / "s.npz")


def _tamper(path, out, key, change):
    arrays, header = _arrays(path)
    arrays[key] = change(arrays[key])
    _write(out, arrays, header)
    return out


@pytest.mark.parametrize("key,change,message", [
    ("state.sample_owner_", lambda a: a + 1000, r"sample_owner_ holds values >= \d+ \(indices into"),
    ("state.sample_theta_", lambda a: -a, "sample_theta_ holds values <= 0"),
    ("state.demo_theta_", lambda a: a[:, :1], r"demo_theta_ has shape \(48, 1\), expected \(any, 2\)"),
    ("state.lookup_z_", lambda a: np.full_like(a, np.nan), "lookup_z_ holds values that are not finite"),
    ("state.neighbors_._fit_X", lambda a: a[:5], r"sample_owner_ has shape|lookup_z_ has shape|neighbors_"),
    ("state.scaler_.scale_", lambda a: a[:1], r"scaler_.scale_ has shape"),
])
def test_tampered_arrays_are_value_errors_naming_the_file(knn_file, tmp_path, key, change, message):
    bad = _tamper(knn_file, tmp_path / "t.npz", key, change)
    with pytest.raises(ValueError, match=rf"t\.npz: .*{message}.*damaged or was edited"):
        load_learner(bad)


def test_tampered_mixture_arrays_are_value_errors_naming_the_file(synthetic, tmp_path):
    path = _fit(PIRLGMM, {"random_state": 0}, synthetic.train).save(tmp_path / "g.npz")
    with pytest.raises(ValueError, match=r"t\.npz: theta_ holds values that are not finite"):
        load_learner(_tamper(path, tmp_path / "t.npz", "state.theta_", lambda a: a * np.nan))
    with pytest.raises(ValueError, match=r"u\.npz: components_ holds values >= 2"):
        load_learner(_tamper(path, tmp_path / "u.npz", "state.components_", lambda a: a + 5))
    with pytest.raises(ValueError, match=r"v\.npz: mixture_.precisions_cholesky_ has shape"):
        load_learner(_tamper(path, tmp_path / "v.npz", "state.mixture_.precisions_cholesky_", lambda a: a[:, :1]))
    with pytest.raises(ValueError, match=r"w\.npz: mixture_.precisions_cholesky_ has a diagonal entry <= 0"):
        load_learner(_tamper(path, tmp_path / "w.npz", "state.mixture_.precisions_cholesky_", np.zeros_like))
    with pytest.raises(ValueError, match=r"x\.npz: mixture_.weights_ are all zero"):
        load_learner(_tamper(path, tmp_path / "x.npz", "state.mixture_.weights_", np.zeros_like))


@pytest.mark.parametrize("param,value,message", [
    ("average", "foo", r"average must be one of \('log', 'linear'\), got 'foo'"),
    ("n_neighbors", 0, "n_neighbors must be a positive integer"),
    ("log_bounds", 5, "log_bounds must be a pair"),
    ("state_features", [7], "state_features must be indices into the state"),
])
def test_a_file_with_invalid_parameters_is_refused(knn_file, tmp_path, param, value, message):
    arrays, header = _arrays(knn_file)
    header["params"]["__dict__"] = [[k, value if k == param else v] for k, v in header["params"]["__dict__"]]
    _write(tmp_path / "p.npz", arrays, header)
    with pytest.raises(ValueError, match=rf"p\.npz: invalid parameters of the PIRLKNN: {message}"):
        load_learner(tmp_path / "p.npz")



@pytest.mark.parametrize("param,value,message", [
    ("covariance_type", "foo", r"covariance_type must be one of \('full', 'tied', 'diag', 'spherical'\), got 'foo'"),
    ("weight_concentration_prior", -1.0, "weight_concentration_prior must be None"),
    ("random_state", "seed", r"random_state must be None, an integer seed in \[0, 2\*\*32\)"),
    ("max_iter", 0, "max_iter must be a positive number of iterations"),
])
def test_a_mixture_file_with_invalid_parameters_is_refused(synthetic, tmp_path, param, value, message):
    path = _fit(PIRLDPGMM, {"random_state": 0}, synthetic.train).save(tmp_path / "dp.npz")
    arrays, header = _arrays(path)
    header["params"]["__dict__"] = [[k, value if k == param else v] for k, v in header["params"]["__dict__"]]
    _write(tmp_path / "p.npz", arrays, header)
    with pytest.raises(ValueError, match=rf"p\.npz: invalid parameters of the PIRLDPGMM: {message}"):
        load_learner(tmp_path / "p.npz")

def test_a_failed_save_leaves_no_temporary_file(synthetic, tmp_path, monkeypatch):
    learner = _fit(TIRL, {}, synthetic.train[:24])
    (tmp_path / "taken.npz").mkdir()  # the target is a directory: the final rename fails
    with pytest.raises(OSError):
        learner.save(tmp_path / "taken")
    assert [p.name for p in tmp_path.iterdir()] == ["taken.npz"] and not any((tmp_path / "taken.npz").iterdir())

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        learner.save(tmp_path / "m")
    assert [p.name for p in tmp_path.iterdir()] == ["taken.npz"]
