"""Sweep configs (pirl_sim.engine.config): expansion into cells and grids, cell keys, bad configs named, the
default config, and fuzzed configs and TOML bytes (hypothesis)."""

from __future__ import annotations

import tomllib

import pytest

from pirl_sim.engine import code_version, default_config, parse_config
from pirl_sim.engine.worker import run_cell, single_threaded

pytest.importorskip("hypothesis")

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


TINY = """
name = "tiny"
seeds = [0, 1]

[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 80, n_train = 60 }
protocols = ["paper", { kind = "online", history_steps = 10 }]
learners = ["tirl", { name = "pirl-gmm", params = { n_components = 2 } },
            { name = "pirl-knn", grid = { n_neighbors = [1, 4] } }]
"""


def _config(text: str = TINY, **kw):
    return parse_config(tomllib.loads(text), text=text, **kw)


# ---------------------------------------------------------------------------------------------- config
def test_tiny_config_expands_to_its_grid():
    cfg = _config()
    assert len(cfg.cells) == 2 * 4 * 2  # protocols x learner variants x seeds
    labels = {c.learner_label for c in cfg.cells}
    assert labels == {"TIRL", "PIRL-GMM (k=2)", "PIRL-kNN (k=1)", "PIRL-kNN (k=4)"}
    gmm = [c for c in cfg.cells if c.learner == "pirl-gmm"]
    assert {c.learner_params["random_state"] for c in gmm} == {0, 1}  # the cell's seed
    assert all(c.scenario_params["n_train"] == 60 and c.scenario_params["n_steps"] == 50 for c in cfg.cells)
    online = [c for c in cfg.cells if c.protocol["kind"] == "online"]
    assert all(c.protocol == {"kind": "online", "history_steps": 10, "horizon": None, "stride": 1,
                              "window_mode": "first"} for c in online)


def test_cell_keys_follow_config_and_code_version_not_labels():
    a, b = _config().cells[0], _config(TINY.replace('name = "tiny"', 'name = "other"')).cells[0]
    assert a.key("v1") == b.key("v1")  # names and labels are presentation
    assert a.key("v1") != a.key("v2")
    changed = _config(TINY.replace("n_train = 60", "n_train = 59")).cells[0]
    assert changed.key("v1") != a.key("v1")
    assert len({c.key("v1") for c in _config().cells}) == len(_config().cells)
    assert code_version() == code_version() and code_version().startswith("0.")


BAD = {
    "unknown top-level key": ("nme = 'x'\n" + TINY, r"unknown key\(s\) 'nme'; valid keys: name, description, seeds"),
    "unknown scenario": (TINY.replace('scenario = "synthetic"', 'scenario = "sumo-v9"'),
                         r"unknown scenario 'sumo-v9'; registered scenarios: .*passage.*synthetic"),
    "unknown learner": (TINY.replace('"tirl",', '"pirl-svm",'), r"unknown learner 'pirl-svm'; choose one of"),
    "unknown experiment key": (TINY.replace("protocols =", "protocol ="),
                               r"unknown key\(s\) 'protocol'; valid keys: scenario, label, seeds"),
    "unknown scenario parameter": (TINY.replace("n_train = 60", "n_tain = 60"),
                                   r"scenario 'synthetic': unknown parameter\(s\) 'n_tain'; valid parameters: "
                                   r"n_trajectories, n_train"),
    "unknown learner parameter": (TINY.replace("n_components = 2", "k = 2"),
                                  r"learner 'pirl-gmm': unknown parameter 'k'; valid parameters: .*n_components"),
    "unknown protocol kind": (TINY.replace('"paper",', '"offline",'), r"unknown protocol kind 'offline'"),
    "unknown protocol key": (TINY.replace("history_steps = 10", "history = 10"),
                             r"unknown key\(s\) 'history'; valid keys: kind, history_steps, horizon"),
    "empty value list": (TINY.replace("n_neighbors = [1, 4]", "n_neighbors = []"), r"empty grid: .*n_neighbors"),
    "no learners": (TINY.replace(TINY[TINY.index("learners ="):], "learners = []\n"),
                    r"empty grid: experiment 'synthetic' has no learner"),
    "no seeds": (TINY.replace("seeds = [0, 1]", "seeds = []"), r"empty grid: seeds is an empty list"),
    "no experiments": ('name = "x"\nseeds = [0]\n', r"empty grid: the sweep has no \[\[experiments\]\]"),
    "kNN k larger than the training set": (
        TINY.replace("n_neighbors = [1, 4]", "n_neighbors = [1, 61]"),
        r"PIRL-kNN \(k=61\) under the paper protocol: k = n_neighbors = 61 is larger than the training set "
        r"\(60 training trajectories"),
    "GMM k larger than the training set": (
        TINY.replace("n_components = 2", "n_components = 70"),
        r"k = n_components = 70 is larger than the training set"),
    "history longer than the trajectories": (
        TINY.replace("history_steps = 10", "history_steps = 50"),
        r"online \(history 50 steps\) protocol needs trajectories of at least 51 steps; the scenario's have at "
        r"most 50"),
    "window set by hand": (TINY.replace("n_components = 2", "n_components = 2, window = 5"),
                           r"'window' is set by the sweep"),
    "bad scenario value": (TINY.replace("n_train = 60", "n_train = 90"), r"scenario 'synthetic': n_train must be in"),
    "wrong type": (TINY.replace("n_train = 60", "n_train = 60.5"), r"'n_train' must be an integer, got 60.5"),
    "unknown style in a mix": (TINY.replace("n_train = 60 }", "n_train = 60, mix = { fast = 1.0 } }"),
                               r"mix names unknown style\(s\) \['fast'\]"),
    "two experiments with one label": (TINY + TINY[TINY.index("[[experiments]]"):],
                                       r"experiments 1 and 2 are both labelled 'synthetic': give one a label"),
    "rolling without horizon": (TINY.replace('"paper",', '{ kind = "rolling", history_steps = 5 },'),
                                r"the rolling protocol needs horizon >= 1"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_configs_fail_naming_the_problem(case):
    text, match = BAD[case]
    with pytest.raises(ValueError, match=match):
        _config(text)


def test_grid_over_scenario_parameters_with_named_variants():
    text = """
seeds = [3]
[[experiments]]
scenario = "passage"
label = "pop"
params = { n_trajectories = 40, n_train = 30 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 15, stride = 5 }]
learners = ["tirl"]
[experiments.grid]
rationality = [20.0, inf]
[experiments.grid.mix]
two = { "tracks desired speed" = 1.0, "minimises acceleration" = 2.0, "no preference" = 0.0 }
"""
    cfg = _config(text)
    assert [c.scenario_label for c in cfg.cells] == ["pop (rationality=20, mix=two)", "pop (rationality=inf, mix=two)"]
    styles = cfg.cells[0].scenario_params["styles"]
    assert [(s["name"], s["weight"]) for s in styles] == [
        ("tracks desired speed", 1.0), ("minimises acceleration", 2.0)]
    assert cfg.cells[1].scenario_params["rationality"] is None  # inf: exact optima
    assert cfg.cells[0].protocol["window_mode"] == "sliding"


def test_default_config_reproduces_the_papers_experiments():
    cfg = default_config()
    scen = {c.scenario for c in cfg.cells}
    assert scen == {"synthetic", "passage", "sumo", "highway"}
    assert {c.seed for c in cfg.cells} == {0, 1, 2}
    paper = [c for c in cfg.cells if c.scenario in ("synthetic", "passage")]
    assert len(paper) == 3 * 86 and len({c.key("v") for c in paper}) == 3 * 82  # 4 cells shared by two blocks
    sims = [c for c in cfg.cells if c.scenario in ("sumo", "highway")]
    assert len(sims) == 2 * 6 * 3
    receding = [c for c in sims if c.learner_params.get("likelihood") == "receding"]
    assert receding and all(c.learner_params["horizon"] == c.scenario_params["horizon"] for c in receding)
    assert {c.learner for c in sims} == {"cv", "ca", "tirl", "pirl-gmm", "pirl-knn"}
    syn = {(c.protocol_label, c.learner_label): c for c in cfg.cells if c.scenario == "synthetic" and c.seed == 0}
    assert syn[("paper", "PIRL-GMM (k=2)")].learner_params["random_state"] == 0
    assert {c.k for c in cfg.cells if c.experiment == "synthetic" and c.learner == "pirl-knn"} == {
        1, 2, 3, 5, 8, 13, 21, 34, 55, 89}
    # the synthetic cells give the README's table (`pirl-sim reproduce synthetic`, seed 0)
    readme = {"TIRL": 0.0651, "PIRL-GMM (k=2)": 0.012, "PIRL-kNN (k=1)": 6.14e-05}
    for name, med in readme.items():
        with single_threaded():  # as in a worker, without leaving this process single-threaded
            res = run_cell(syn[("paper", name)].spec())
        assert res["scores"]["med"] == pytest.approx(med, rel=5e-3)
    assert res["scores"]["n_train"] == 1800 and res["scores"]["n_test"] == 200


FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                       HealthCheck.too_slow])


TOML_SCALAR = st.one_of(st.booleans(), st.integers(-2**40, 2**40), st.floats(allow_nan=True, allow_infinity=True),
                        st.text(max_size=8), st.sampled_from(["full", "weird", "poisson", "regular", "tirl",
                                                              "pirl-gmm", "paper", "online", "synthetic"]))
TOML_VALUE = st.recursive(TOML_SCALAR, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                               st.dictionaries(st.text(max_size=6), inner,
                                                                               max_size=3)), max_leaves=6)


def _mutated_mapping(draw, base, keys: list[str]):
    """``base`` (a dict, changed in place) with some values replaced, some keys deleted, an unknown key added."""
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        key = draw(st.sampled_from(keys))
        if kind == "replace":
            base[key] = draw(TOML_VALUE)
        elif kind == "delete":
            base.pop(key, None)
        else:
            base[draw(st.text(min_size=1, max_size=6))] = draw(TOML_VALUE)
    return base


SWEEP_BASE = """
seeds = [0]
[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 40, n_train = 30 }
protocols = [{ kind = "paper" }, { kind = "online", history_steps = 5 }]
learners = ["tirl", { name = "pirl-gmm", params = { n_components = 2, covariance_type = "diag" } }]
"""


@st.composite
def sweep_dicts(draw):
    data = tomllib.loads(SWEEP_BASE)
    where = draw(st.sampled_from(["top", "experiment", "params", "protocol", "learner"]))
    exp = data["experiments"][0]
    if where == "top":
        _mutated_mapping(draw, data, ["seeds", "experiments", "name", "description"])
    elif where == "experiment":
        _mutated_mapping(draw, exp, ["scenario", "params", "protocols", "learners", "seeds", "label", "grid"])
    elif where == "params":
        _mutated_mapping(draw, exp["params"], ["n_trajectories", "n_train", "seed"])
    elif where == "protocol":
        _mutated_mapping(draw, exp["protocols"][1], ["kind", "history_steps", "horizon", "stride"])
    else:
        _mutated_mapping(draw, exp["learners"][1]["params"], ["n_components", "covariance_type", "log_bounds",
                                                              "random_state", "n_init"])
    return data


@FUZZ
@given(data=sweep_dicts())
def test_fuzz_sweep_config(data):
    from pirl_sim.engine.config import parse_config

    try:
        cfg = parse_config(data)
    except (ValueError, TypeError) as exc:
        assert str(exc)
        return
    for cell in cfg.cells:  # whatever was accepted hashes to a key (no NaN, nothing unserialisable)
        assert len(cell.key("v")) == 32
        assert 0 <= cell.seed < 2**31


@FUZZ
@given(data=st.binary(max_size=200))
def test_fuzz_sweep_toml_bytes(tmp_path_factory, data):
    from pirl_sim.engine.config import load_config

    path = tmp_path_factory.mktemp("toml") / "sweep.toml"
    path.write_bytes(data)
    with pytest.raises(ValueError):  # random bytes never make a sweep with experiments
        load_config(path)
