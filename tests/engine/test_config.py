"""Sweep configs (pirl_sim.engine.config): expansion into cells and grids, cell keys, bad configs named, the
default config, and fuzzed configs and TOML bytes (hypothesis)."""

from __future__ import annotations

import tomllib

import pytest

from pirl_sim.engine import code_version, default_config
from pirl_sim.engine.worker import run_cell, single_threaded

pytest.importorskip("hypothesis")

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from sweep_configs import BAD, TINY, sweep_config, sweep_toml  # noqa: E402
from toml_fuzz import FUZZ, mutated_mapping  # noqa: E402


# ---------------------------------------------------------------------------------------------- config
def test_tiny_config_expands_to_its_grid():
    cfg = sweep_config()
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
    a, b = sweep_config().cells[0], sweep_config(TINY.replace('name = "tiny"', 'name = "other"')).cells[0]
    assert a.key("v1") == b.key("v1")  # names and labels are presentation
    assert a.key("v1") != a.key("v2")
    changed = sweep_config(TINY.replace("n_train = 60", "n_train = 59")).cells[0]
    assert changed.key("v1") != a.key("v1")
    assert len({c.key("v1") for c in sweep_config().cells}) == len(sweep_config().cells)
    assert code_version() == code_version() and code_version().startswith("0.")


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_configs_fail_naming_the_problem(case):
    text, match = BAD[case]
    with pytest.raises(ValueError, match=match):
        sweep_config(text)


def test_grid_over_scenario_parameters_with_named_variants():
    text = sweep_toml(None, [3], """
scenario = "passage"
label = "pop"
params = { n_trajectories = 40, n_train = 30 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 15, stride = 5 }]
learners = ["tirl"]
[experiments.grid]
rationality = [20.0, inf]
[experiments.grid.mix]
two = { "tracks desired speed" = 1.0, "minimises acceleration" = 2.0, "no preference" = 0.0 }
""")
    cfg = sweep_config(text)
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
        mutated_mapping(draw, data, ["seeds", "experiments", "name", "description"])
    elif where == "experiment":
        mutated_mapping(draw, exp, ["scenario", "params", "protocols", "learners", "seeds", "label", "grid"])
    elif where == "params":
        mutated_mapping(draw, exp["params"], ["n_trajectories", "n_train", "seed"])
    elif where == "protocol":
        mutated_mapping(draw, exp["protocols"][1], ["kind", "history_steps", "horizon", "stride"])
    else:
        mutated_mapping(draw, exp["learners"][1]["params"], ["n_components", "covariance_type", "log_bounds",
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
