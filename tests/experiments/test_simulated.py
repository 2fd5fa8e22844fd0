"""SUMO and highway-env scenarios in the sweep (pirl_sim.experiments.simulated): one simulation per (parameters,
seed) shared by its cells and kept in the store, per-feature weight scores, parameters checked up front, and a
missing simulator extra named.

The simulators are the real ones (a run of 8-12 vehicles takes a second or two)."""

from __future__ import annotations

import json
import tomllib
import types

import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.cli import main as sweep_main
from pirl_sim.engine import load_config, parse_config, run_sweep


SUMO = """
seeds = [0]
[[experiments]]
scenario = "sumo"
params = { n_vehicles = 12, depart_interval = 3.0 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 20, stride = 20 }]
learners = ["cv", "ca", { name = "tirl", grid = { likelihood = ["trajectory", "receding"] }, params = { step_stride = 2 } }]
"""


def _config(text: str):
    return parse_config(tomllib.loads(text), text=text)


@pytest.fixture(scope="module")
def sumo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("sumo_sweep")
    return out, run_sweep(_config(SUMO), out, workers=0, progress=False)


@pytest.mark.slow
def test_one_simulation_serves_every_cell_of_its_parameters_and_seed(sumo_run):
    out, run = sumo_run
    assert not run.failed and len(run.table) == 4
    assert len(run.simulated) == 1
    sim_dir = out / "simulations" / run.simulated[0]
    assert (sim_dir / "simulation.json").is_file() and (sim_dir / "ground_truth.csv").is_file()
    record = json.loads((sim_dir / "simulation.json").read_text())
    assert record["scenario"] == "sumo" and record["seed"] == 0 and "selection" not in record["simulation"]
    t = run.table.set_index("learner_label")
    assert set(t.index) == {"CV", "CA", "TIRL (likelihood=trajectory)", "TIRL (likelihood=receding)"}
    assert (t["med"] > 0).all() and (t["fde"] > 0).all()
    assert t.loc[["CV", "CA"], "weight_error"].isna().all()  # baselines infer no weights
    assert t.loc["TIRL (likelihood=receding)", "weight_error"] >= 0
    # the drivers' horizon is the receding likelihood's default
    cell = [c for c in _config(SUMO).cells if c.learner_params.get("likelihood") == "receding"][0]
    assert cell.learner_params["horizon"] == 30


@pytest.mark.slow
def test_weights_table_per_feature_and_style(sumo_run):
    out, run = sumo_run
    w = pd.read_csv(out / "weights.csv")
    assert set(w["feature"]) == {"speed_dev", "acc_sq"}
    assert set(w["learner_label"]) == {"TIRL (likelihood=trajectory)", "TIRL (likelihood=receding)"}
    styles = set(w["style"]) - {"all"}
    assert styles and styles <= {"tracks desired speed", "minimises acceleration", "no preference"}
    overall = w[w["style"] == "all"]
    assert (overall["p90_abs_log_err"] >= overall["median_abs_log_err"]).all()
    n_all = overall.groupby(["key", "feature"])["n"].first()
    n_styles = w[w["style"] != "all"].groupby(["key", "feature"])["n"].sum()
    assert (n_all == n_styles).all()  # every test history has a style


@pytest.mark.slow
def test_rerun_and_other_selection_reuse_the_simulation(sumo_run, tmp_path):
    out, run = sumo_run
    again = run_sweep(_config(SUMO), out, workers=0, progress=False)
    assert again.computed == [] and again.simulated == []
    other = _config(SUMO.replace("depart_interval = 3.0 }", "depart_interval = 3.0, min_steps = 20 }"))
    more = run_sweep(other, out, workers=0, progress=False)
    assert len(more.computed) == 4 and more.simulated == []  # new cells, the same run
    sims = [p for p in (out / "simulations").iterdir() if not p.name.startswith(".")]
    assert len(sims) == 1


def _with_learners(text: str, learners: str) -> str:
    """The SUMO test config ``text`` with its learners list replaced by ``learners`` (TOML)."""
    old = 'learners = ["cv", "ca", { name = "tirl", grid = { likelihood = ["trajectory", "receding"] }, params = { step_stride = 2 } }]'
    assert old in text
    return text.replace(old, f"learners = {learners}")


@pytest.mark.slow
def test_highway_scenario_runs(tmp_path):
    text = _with_learners(SUMO.replace('scenario = "sumo"', 'scenario = "highway"'),
                          '["cv", { name = "pirl-knn", params = { n_neighbors = 1, likelihood = "receding", step_stride = 2 } }]')
    run = run_sweep(_config(text), tmp_path, workers=0, progress=False)
    assert not run.failed and len(run.table) == 2 and len(run.simulated) == 1
    info = json.loads(next((tmp_path / "simulations").glob("*/run.json")).read_text())
    assert info["simulator"] == "highway-env"
    knn = run.table[run.table["learner"] == "pirl-knn"].iloc[0]
    assert knn["med"] > 0 and knn["weight_error"] >= 0


BAD = {
    "selection": ("selection = \"all\"", r"scenario 'sumo' parameter 'selection' must be one of 'tracks', 'steps'"),
    "horizon": ("horizon = 0", r"scenario 'sumo' parameter 'horizon' must be >= 1, got 0"),
    "control_noise": ("control_noise = -0.5", r"scenario 'sumo': control_noise must be >= 0"),
    "control_noise type": ("control_noise = \"high\"", r"'control_noise' must be a number"),
    "background_share": ("background_share = 1.5", r"background_share must be in \[0, 1\]"),
    "test_fraction": ("test_fraction = 1.0", r"'test_fraction' must be in \(0, 1\)"),
    "depart_interval": ("depart_interval = 0.0", r"depart_interval must be > 0 s"),
    "preset style": ("styles = [\"fast\"]", r"unknown style name 'fast' for preset"),
    "mix": ("mix = { fast = 1.0 }", r"mix names unknown style\(s\) \['fast'\]"),
    "unknown key": ("lanes = 2", r"unknown parameter\(s\) 'lanes'; valid parameters: n_vehicles"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_simulator_parameters_fail_at_dry_run_naming_the_key(case, tmp_path, capsys):
    setting, match = BAD[case]
    cfg = tmp_path / "bad.toml"
    cfg.write_text(SUMO.replace("depart_interval = 3.0 }", f"{setting} }}" if case == "depart_interval"
                                else f"depart_interval = 3.0, {setting} }}"))
    with pytest.raises(ValueError, match=match):
        load_config(cfg)
    assert sweep_main(["sweep", str(cfg), "--out", str(tmp_path / "out"), "--dry-run"]) == 2
    assert "error" in capsys.readouterr().err and not (tmp_path / "out").exists()


@pytest.mark.slow
def test_report_of_a_simulator_sweep_has_intervals_and_weight_tables(tmp_path):
    from pirl_sim.engine import write_report

    text = _with_learners(SUMO.replace("seeds = [0]", "seeds = [0, 1]"),
                          '["cv", { name = "tirl", params = { likelihood = "receding", step_stride = 2 } }]')
    run = run_sweep(_config(text), tmp_path, workers=0, progress=False)
    assert not run.failed and len(run.simulated) == 2  # one run per seed
    write_report(tmp_path)
    md = (tmp_path / "README.md").read_text()
    assert "## sumo" in md and " ± " in md
    assert "| TIRL | speed_dev |" in md.replace("rolling (history 10, horizon 20 steps) | ", "")
    assert "Median abs log error per true style" in md


def test_a_missing_simulator_extra_fails_the_config_check_naming_the_extra(tmp_path, capsys, monkeypatch):
    from pirl_sim.experiments import simulated as scenarios

    def import_module(name):
        raise ModuleNotFoundError(f"No module named {'highway_env'!r}", name="highway_env")

    monkeypatch.setattr(scenarios, "importlib", types.SimpleNamespace(import_module=import_module))
    cfg = tmp_path / "highway.toml"
    cfg.write_text("""
seeds = [0]
[[experiments]]
scenario = "highway"
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 20 }]
learners = ["cv"]
""")
    assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "scenario 'highway' needs highway_env, which is not installed: install the 'highway' extra" in err
    assert "Traceback" not in err
