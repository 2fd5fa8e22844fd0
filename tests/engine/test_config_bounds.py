"""Sweep configs (pirl_sim.engine.config): the kNN learner's choices and the bounds of scenario parameters and style
weights, checked before anything is allocated (apart from tests/engine/test_config.py, whose config helper
takes TOML text)."""

import pytest

from pirl_sim.engine.config import parse_config


def _config(params=None, learner="tirl"):
    return {"seeds": [0], "experiments": [{
        "scenario": "synthetic", "params": {"n_trajectories": 20, "n_train": 10, **(params or {})},
        "protocols": [{"kind": "paper"}], "learners": [learner]}]}


@pytest.mark.parametrize("params, match", [
    ({"weighting": "distanse"}, r"weighting must be one of \('distance', 'likelihood'\), got 'distanse'"),
    ({"target": "nxt"}, r"target must be one of \('demo', 'next'\), got 'nxt'"),
    ({"aggregate": "mean"}, r"aggregate must be one of .*'weights'.*got 'mean'"),
])
def test_sweep_config_rejects_unknown_knn_choices(params, match):
    with pytest.raises(ValueError, match=match):
        parse_config(_config(learner={"name": "pirl-knn", "params": params}))


def test_sweep_config_accepts_the_knn_choices():
    cfg = parse_config(_config(learner={"name": "pirl-knn", "params": {"weighting": "likelihood"}}))
    assert cfg.cells[0].learner_params["weighting"] == "likelihood"


def test_sweep_config_bounds_n_trajectories_without_allocating():
    with pytest.raises(ValueError, match=r"n_trajectories must be in \[2, 1000000\], got 1000000000000"):
        parse_config(_config({"n_trajectories": 10**12, "n_train": 10}))


@pytest.mark.parametrize("name", ["position_range", "velocity_range"])
def test_sweep_config_bounds_the_start_ranges(name):
    with pytest.raises(ValueError, match=rf"{name} must lie within \[-1e\+06, 1e\+06\], got \(1e\+300, 1e\+300\)"):
        parse_config(_config({name: [1e300, 1e300]}))


@pytest.mark.parametrize("field, value, match", [
    ("weight", 1e300, r"style 'a': weight must be in \(0, 1e\+06\], got 1e\+300"),
    ("mean", {"state_sq": 1e300}, r"style 'a': mean of 'state_sq' must be in \(0, 1e\+06\], got 1e\+300"),
    ("std", {"state_sq": 1e300}, r"style 'a': std of 'state_sq' must be in \[0, 1e\+06\], got 1e\+300"),
])
def test_sweep_config_bounds_style_weights(field, value, match):
    style = {"name": "a", "weight": 1.0, "mean": {"state_sq": 4.0}, "std": {"state_sq": 1.0}, field: value}
    with pytest.raises(ValueError, match=match):
        parse_config(_config({"styles": [style]}))


@pytest.mark.parametrize("value, match", [
    (0, r"max_iter must be a positive number of iterations of the mixture's fit, got 0"),  # scikit-learn allows 0
    (-3, r"max_iter.*-3"), (2.5, r"max_iter.*2\.5"),
])
def test_sweep_config_refuses_a_mixture_fit_of_no_iterations(value, match):
    with pytest.raises(ValueError, match=match):
        parse_config(_config(learner={"name": "pirl-dpgmm", "params": {"max_iter": value}}))
