"""Sweeps (issue 7): config validation, cells and keys, the result store, the in-process run, report, CLI."""

import json
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pirl_sim.engine import (
    SCENARIOS,
    TIMING_COLUMNS,
    ResultStore,
    ScenarioData,
    ScenarioSpec,
    code_version,
    default_config,
    load_config,
    parse_config,
    register_scenario,
    run_sweep,
    write_report,
)
from pirl_sim.engine.worker import run_cell, single_threaded
from pirl_sim.cli import main as sweep_main
from pirl_sim.experiments.spec import Param, TrainShape

def _threads():
    import os

    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_info

    return {i["filepath"]: i["num_threads"] for i in threadpool_info()}, os.environ.get("OPENBLAS_NUM_THREADS")


_THREADS_AT_START, _OPENBLAS_ENV_AT_START = _threads()

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


def _scores(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns=list(TIMING_COLUMNS)).reset_index(drop=True)


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


def test_bad_config_fails_before_any_work(tmp_path, capsys):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(BAD["kNN k larger than the training set"][0])
    out = tmp_path / "results"
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--workers", "0"]) == 2
    assert "is larger than the training set" in capsys.readouterr().err
    assert not out.exists()  # nothing started, nothing written
    assert sweep_main(["sweep", str(tmp_path / "missing.toml"), "--out", str(out)]) == 2
    assert "not found" in capsys.readouterr().err
    cfg.write_text("seeds = [0\n")
    assert sweep_main(["sweep", str(cfg), "--out", str(out)]) == 2
    assert "not valid TOML" in capsys.readouterr().err
    cfg.write_text(TINY)
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--workers", "1", "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert "not both" in capsys.readouterr().err
    assert not out.exists()


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


# ---------------------------------------------------------------------------------------------- runs
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    return out, run_sweep(_config(), out, workers=0, progress=False)


def test_inline_run_writes_one_file_per_cell_and_the_tables(tiny_run):
    out, run = tiny_run
    assert len(run.computed) == 16 and not run.cached and not run.failed
    assert len(list((out / "cells").glob("*.json"))) == 16
    table = pd.read_parquet(out / "table.parquet")
    assert len(table) == 16 and table["key"].is_unique
    pd.testing.assert_frame_equal(_scores(table), _scores(run.table))
    csv = pd.read_csv(out / "table.csv")
    np.testing.assert_array_equal(csv["med"].to_numpy(), table["med"].to_numpy())  # full precision in the CSV
    assert (table["med"] > 0).all() and table["weight_error"].notna().all()
    assert table.loc[table["learner"] == "pirl-gmm", "ari"].notna().all()
    assert table.loc[table["learner"] == "tirl", "ari"].isna().all()
    assert (table[list(TIMING_COLUMNS)] >= 0).all().all()
    rec = json.loads((out / "cells" / f"{table['key'][0]}.json").read_text())
    assert rec["cell"]["scenario"] == "synthetic" and rec["code_version"] == code_version()
    manifest = json.loads((out / "sweep.json").read_text())
    assert manifest["n_cells"] == 16 and manifest["config"].strip().startswith('name = "tiny"')
    recovery = pd.read_parquet(out / "recovery.parquet")
    assert set(recovery["feature"]) == {"state_sq / control_sq"} and recovery["key"].nunique() == 16


def test_rerun_computes_nothing_and_gives_the_same_table(tiny_run):
    out, run = tiny_run
    before = {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")}
    again = run_sweep(_config(), out, workers=0, progress=False)
    assert not again.computed and len(again.cached) == 16
    assert {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")} == before
    pd.testing.assert_frame_equal(again.table, run.table)  # timings included: read back from the store


def test_fresh_run_gives_identical_scores(tiny_run, tmp_path):
    _, run = tiny_run
    fresh = run_sweep(_config(), tmp_path, workers=0, progress=False)
    pd.testing.assert_frame_equal(_scores(fresh.table), _scores(run.table))


def test_unreadable_cell_file_is_recomputed(tiny_run, tmp_path):
    out, run = tiny_run
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    victim = copy / "cells" / f"{run.table['key'][3]}.json"
    victim.write_text('{"key": "trunc')
    again = run_sweep(_config(), copy, workers=0, progress=False)
    assert again.computed == [run.table["key"][3]]
    pd.testing.assert_frame_equal(_scores(again.table), _scores(run.table))


def test_changed_grid_reuses_the_stored_cells(tiny_run, tmp_path):
    out, run = tiny_run
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    bigger = _config(TINY.replace("n_neighbors = [1, 4]", "n_neighbors = [1, 4, 7]"))
    again = run_sweep(bigger, copy, workers=0, progress=False)
    assert len(again.cached) == 16 and len(again.computed) == 4  # k = 7 x 2 protocols x 2 seeds
    assert set(again.table["k"].dropna()) == {1, 2, 4, 7}


@pytest.fixture
def failing_scenario():
    def build(params, seed):
        if seed == 1:
            raise RuntimeError("simulator crashed")
        from pirl_sim.scenarios.synthetic import SyntheticConfig, generate

        d = generate(SyntheticConfig(n_trajectories=40, n_train=30, seed=seed))
        return ScenarioData(d.model, d.train, d.test)

    register_scenario(ScenarioSpec("flaky-test", "fails for seed 1", {"n": Param("int", 1, "unused")},
                                   dict, build, lambda p: TrainShape(30, (50,) * 30)))
    yield
    del SCENARIOS["flaky-test"]


def test_a_failing_cell_is_reported_and_the_others_are_kept(failing_scenario, tmp_path):
    cfg = _config('seeds = [0, 1]\n[[experiments]]\nscenario = "flaky-test"\nprotocols = ["paper"]\n'
                  'learners = ["tirl"]\n')
    run = run_sweep(cfg, tmp_path, workers=0, progress=False)
    assert len(run.computed) == 1 and len(run.failed) == 1
    (key, err), = run.failed.items()
    assert "RuntimeError: simulator crashed" in err
    assert json.loads((tmp_path / "errors" / f"{key}.json").read_text())["error"] == err
    assert list(run.table["seed"]) == [0]
    again = run_sweep(cfg, tmp_path, workers=0, progress=False)
    assert len(again.cached) == 1 and list(again.failed) == [key]  # retried, still failing


def test_worker_with_other_code_refuses_the_cell():
    from pirl_sim.engine import worker as cell_module

    cell_module._VERSION = None
    cell = _config().cells[0]
    with single_threaded(), pytest.raises(RuntimeError, match="install the same code on every worker"):
        run_cell(cell.spec(), "0.0.0+0000000000000000")


# ---------------------------------------------------------------------------------------------- replay
@pytest.fixture(scope="module")
def replay_dir(tmp_path_factory):
    from pirl_sim.scenarios.passage import PassageConfig, generate, write_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate(PassageConfig(n_trajectories=60, n_train=45, seed=2))
    out = tmp_path_factory.mktemp("scene")
    write_scene(data, out)
    return out


def test_replay_scenario_runs_and_its_key_follows_the_data(replay_dir, tmp_path):
    import shutil

    scene = tmp_path / "scene"
    shutil.copytree(replay_dir, scene)
    cfg_path = tmp_path / "replay.toml"
    cfg_path.write_text("""
seeds = [0]
[[experiments]]
scenario = "replay"
params = { tracks = "scene", map = "scene/map.osm" }    # relative to this file
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 5 }]
learners = ["tirl", { name = "pirl-knn", params = { n_neighbors = 5, stride = 2 } }]
""")
    cfg = load_config(cfg_path)
    assert cfg.cells[0].scenario_params["tracks"] == str(scene.resolve())
    run = run_sweep(cfg, tmp_path / "out", workers=0, progress=False)
    assert not run.failed and len(run.table) == 2
    assert run.table["n_train"].iloc[0] + run.table["n_test"].iloc[0] == 60
    assert run.table["weight_error"].notna().all()  # the ground-truth sidecar is read
    key = cfg.cells[0].key("v")
    with open(scene / "ground_truth.csv", "a") as fh:
        fh.write("\n")
    assert load_config(cfg_path).cells[0].key("v") != key  # changed data, new key
    bad = cfg_path.read_text().replace("n_neighbors = 5", "n_neighbors = 5000")
    cfg_path.write_text(bad)
    with pytest.raises(ValueError, match="larger than the training set .*at most"):
        load_config(cfg_path)


# ---------------------------------------------------------------------------------------------- report, CLI
def test_report_draws_figures_and_summary_deterministically(tiny_run, tmp_path):
    out, run = tiny_run
    first = write_report(out, tmp_path / "a")
    assert set(first) == {"med_vs_k.png", "learners.png", "recovery.png", "README.md"}
    second = write_report(out, tmp_path / "b")
    for name in first:
        assert Path(first[name]).read_bytes() == Path(second[name]).read_bytes(), name
    md = (tmp_path / "a" / "README.md").read_text()
    assert "| paper | TIRL |" in md and "PIRL-kNN (k=4)" in md
    assert "MED(TIRL) > MED(PIRL-GMM (k=2)) > MED(PIRL-kNN" in md
    assert "![MED vs k](med_vs_k.png)" in md and 'name = "tiny"' in md


def test_cli_sweep_report_and_dry_run(tmp_path, capsys):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY.replace("seeds = [0, 1]", "seeds = [0]"))
    out = tmp_path / "res"
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--workers", "0", "--dry-run"]) == 0
    assert "8 cells (8 distinct), 0 already in" in capsys.readouterr().out
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--workers", "0"]) == 0
    captured = capsys.readouterr()
    assert "8 cells in" in captured.out and "ETA" in captured.err and "8/8 cells" in captured.err
    assert sweep_main(["report", str(out)]) == 0
    assert "README.md" in capsys.readouterr().out and (out / "learners.png").exists()
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--dry-run"]) == 0
    assert "8 already in" in capsys.readouterr().out
    assert sweep_main(["report", str(tmp_path / "nothing")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_default_config_dry_run(capsys, tmp_path):
    assert sweep_main(["sweep", "--dry-run", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "sweep 'paper' (<default>): 294 cells (282 distinct), 0 already in" in out
    assert "282 to run and 6 simulations (code" in out  # SUMO and highway-env, 3 seeds each


def test_store_ignores_foreign_files(tmp_path):
    store = ResultStore(tmp_path)
    (tmp_path / "cells").mkdir()
    (tmp_path / "cells" / ".abc.json.123.tmp").write_text("half")
    (tmp_path / "cells" / "abc.json").write_text("[1, 2]")
    assert store.finished() == {"abc"}
    assert store.load("abc") is None and store.load("nothing") is None


def test_sweep_tests_leave_the_process_multi_threaded():
    """Cells run in this process (inline) limit BLAS threads only while they run."""
    import os

    from threadpoolctl import threadpool_info

    from pirl_sim.engine import worker as cell_module

    now = {i["filepath"]: i["num_threads"] for i in threadpool_info()}
    assert {f: n for f, n in now.items() if f in _THREADS_AT_START} == _THREADS_AT_START
    assert os.environ.get("OPENBLAS_NUM_THREADS") == _OPENBLAS_ENV_AT_START
    assert not cell_module._THREADS_LIMITED


# ---------------------------------------------------------------------------------------------- k-grid
def test_knn_k_grid_runs_as_one_fit_with_each_cells_own_numbers(tmp_path, monkeypatch):
    """PIRL-kNN cells that differ only in k run as one task (one IRL fit, `PIRLKNN.with_neighbors`); every
    cell's stored result equals the cell run on its own, warnings included; a k larger than the training set
    (which the config check rejects) fails alone."""
    from pirl_sim.learners import PIRLKNN
    from pirl_sim.engine.worker import knn_group, run_cells
    from pirl_sim.engine.run import _tasks

    text = TINY.replace("seeds = [0, 1]", "seeds = [0]").replace("n_neighbors = [1, 4]", "n_neighbors = [4, 1]")
    cfg = _config(text)
    knn = [c for c in cfg.cells if c.learner == "pirl-knn" and c.protocol["kind"] == "online"]
    assert [c.k for c in knn] == [4, 1] and len({knn_group(c.spec()) for c in knn}) == 1
    assert knn_group(cfg.cells[0].spec()) is None  # TIRL
    unique = {c.key("v"): c for c in cfg.cells}
    tasks = _tasks(unique, list(unique))
    assert sorted(len(t) for t in tasks) == [1, 1, 1, 1, 2, 2]
    assert [unique[k].k for k in next(t for t in tasks if len(t) == 2)] == [1, 4]

    fits = []
    real_fit = PIRLKNN.fit
    monkeypatch.setattr(PIRLKNN, "fit", lambda self, *a, **kw: fits.append(self.n_neighbors) or real_fit(self, *a, **kw))
    specs = [c.spec() for c in sorted(knn, key=lambda c: c.k)]
    specs.append({**specs[0], "learner_params": {**specs[0]["learner_params"], "n_neighbors": 61}})
    with single_threaded():
        together = run_cells(specs)
        assert fits == [1]
        alone = [run_cell(s) for s in specs[:2]]
    assert together[2] == {"error": "ValueError: n_neighbors=61 is larger than the number of training samples (60)"}
    for a, b in zip(alone, together):
        assert a["scores"] == b["scores"] and a["recovery"] == b["recovery"] and a["weights"] == b["weights"]
        assert a["warnings"] == b["warnings"]
    with pytest.raises(ValueError, match="differ only in n_neighbors"):
        run_cells([cfg.cells[0].spec(), specs[0]])

    run = run_sweep(cfg, tmp_path, workers=0, progress=False)
    assert len(run.computed) == 8 and not run.failed
    table = run.table.set_index("learner_label")
    assert set(table.index) == {"TIRL", "PIRL-GMM (k=2)", "PIRL-kNN (k=1)", "PIRL-kNN (k=4)"}


def test_local_executor_start_method_is_spawn_or_fork():
    from pirl_sim.engine.executors import LocalExecutor

    with pytest.raises(ValueError, match="start_method must be 'spawn' or 'fork', got 'forkserver'"):
        LocalExecutor(1, start_method="forkserver")
    with LocalExecutor(1, start_method="fork") as ex:  # a forked worker runs a task like a spawned one
        assert ex.submit(sum, [1, 2]).result() == 3
