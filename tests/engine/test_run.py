"""Running a sweep (pirl_sim.engine.run): one file per cell and the tables, reruns that reuse the store, unreadable
cells recomputed, a failing cell kept apart, and resuming after a SIGKILL."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from pirl_sim.engine import (
    SCENARIOS,
    TIMING_COLUMNS,
    ScenarioData,
    ScenarioSpec,
    code_version,
    load_config,
    register_scenario,
    run_sweep,
)
from pirl_sim.experiments.spec import Param, TrainShape

from sweep_configs import TINY, sweep_config, sweep_toml


def _scores(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns=list(TIMING_COLUMNS)).reset_index(drop=True)


# ---------------------------------------------------------------------------------------------- runs
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    return out, run_sweep(sweep_config(), out, workers=0, progress=False)


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
    again = run_sweep(sweep_config(), out, workers=0, progress=False)
    assert not again.computed and len(again.cached) == 16
    assert {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")} == before
    pd.testing.assert_frame_equal(again.table, run.table)  # timings included: read back from the store


def test_fresh_run_gives_identical_scores(tiny_run, tmp_path):
    _, run = tiny_run
    fresh = run_sweep(sweep_config(), tmp_path, workers=0, progress=False)
    pd.testing.assert_frame_equal(_scores(fresh.table), _scores(run.table))


def test_unreadable_cell_file_is_recomputed(tiny_run, tmp_path):
    out, run = tiny_run
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    victim = copy / "cells" / f"{run.table['key'][3]}.json"
    victim.write_text('{"key": "trunc')
    again = run_sweep(sweep_config(), copy, workers=0, progress=False)
    assert again.computed == [run.table["key"][3]]
    pd.testing.assert_frame_equal(_scores(again.table), _scores(run.table))


def test_changed_grid_reuses_the_stored_cells(tiny_run, tmp_path):
    out, run = tiny_run
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    bigger = sweep_config(TINY.replace("n_neighbors = [1, 4]", "n_neighbors = [1, 4, 7]"))
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
    cfg = sweep_config('seeds = [0, 1]\n[[experiments]]\nscenario = "flaky-test"\nprotocols = ["paper"]\n'
                  'learners = ["tirl"]\n')
    run = run_sweep(cfg, tmp_path, workers=0, progress=False)
    assert len(run.computed) == 1 and len(run.failed) == 1
    (key, err), = run.failed.items()
    assert "RuntimeError: simulator crashed" in err
    assert json.loads((tmp_path / "errors" / f"{key}.json").read_text())["error"] == err
    assert list(run.table["seed"]) == [0]
    again = run_sweep(cfg, tmp_path, workers=0, progress=False)
    assert len(again.cached) == 1 and list(again.failed) == [key]  # retried, still failing


CONFIG = sweep_toml("resume", [0, 1], """
scenario = "synthetic"
params = { n_trajectories = 600, n_train = 500 }
protocols = ["paper", { kind = "online", history_steps = 10 }]
learners = ["tirl", "pirl-dpgmm", { name = "pirl-gmm", grid = { n_components = [2, 3] } },
            { name = "pirl-knn", grid = { n_neighbors = [1, 3, 5] } }]
""")
N_CELLS = 2 * 2 * 7


@pytest.mark.skipif(not hasattr(os, "killpg"), reason="needs POSIX process groups")
def test_sigkill_halfway_then_resume(tmp_path):
    cfg_path = tmp_path / "resume.toml"
    cfg_path.write_text(CONFIG)
    out = tmp_path / "killed"
    cells = out / "cells"
    proc = subprocess.Popen(
        [sys.executable, "-m", "pirl_sim", "sweep", str(cfg_path), "--out", str(out), "--workers", "1",
         "--quiet"],
        start_new_session=True,  # its own process group: the driver and its worker die together
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )
    _kill_after(proc, cells, n_cells=3, timeout=120)
    assert proc.returncode == -signal.SIGKILL
    before = {p.stem: (p.stat().st_mtime_ns, p.read_bytes()) for p in cells.glob("*.json")}
    assert 3 <= len(before) < N_CELLS, "killed halfway"
    assert not (out / "table.parquet").exists()  # the sweep never got to its table

    config = load_config(cfg_path)
    resumed = run_sweep(config, out, workers=1, progress=False)
    assert not resumed.failed
    assert set(resumed.cached) == set(before)  # no finished cell lost ...
    assert not set(resumed.computed) & set(before)  # ... or recomputed
    assert len(resumed.computed) + len(resumed.cached) == N_CELLS
    for key, (mtime, data) in before.items():
        p = cells / f"{key}.json"
        assert p.stat().st_mtime_ns == mtime and p.read_bytes() == data

    uninterrupted = run_sweep(config, tmp_path / "whole", workers=0, progress=False)
    assert len(uninterrupted.computed) == N_CELLS
    pd.testing.assert_frame_equal(_scores(resumed.table), _scores(uninterrupted.table))
    pd.testing.assert_frame_equal(_scores(pd.read_parquet(out / "table.parquet")), _scores(uninterrupted.table))


SUMO_CONFIG = sweep_toml("resume-sumo", [0, 1, 2], """
scenario = "sumo"
params = { n_vehicles = 8, depart_interval = 3.0 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 20 }]
learners = ["cv", "ca", { name = "tirl", params = { likelihood = "receding", step_stride = 4 } }]
""")


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "killpg"), reason="needs POSIX process groups")
def test_sigkilled_sumo_sweep_resumes_without_simulating_or_computing_again(tmp_path):
    """Killed once a cell is stored: the finished simulations and cells are kept and reused, the rest run."""
    cfg_path = tmp_path / "sumo.toml"
    cfg_path.write_text(SUMO_CONFIG)
    out = tmp_path / "killed"
    cells, sims = out / "cells", out / "simulations"
    proc = subprocess.Popen(
        [sys.executable, "-m", "pirl_sim", "sweep", str(cfg_path), "--out", str(out), "--workers", "1",
         "--quiet"],
        start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )
    _kill_after(proc, cells, n_cells=1, timeout=300)
    finished_sims = {p.name: p.joinpath("simulation.json").stat().st_mtime_ns
                     for p in sims.iterdir() if (p / "simulation.json").is_file()}
    finished_cells = {p.stem: p.read_bytes() for p in cells.glob("*.json")}
    assert finished_sims and 1 <= len(finished_cells) < 9

    resumed = run_sweep(load_config(cfg_path), out, workers=1, progress=False)
    assert not resumed.failed
    assert not set(resumed.simulated) & set(finished_sims)  # no finished simulation runs again ...
    assert len(resumed.simulated) + len(finished_sims) == 3  # ... and every seed's run exists once
    assert not set(resumed.computed) & set(finished_cells) and len(resumed.table) == 9
    for name, mtime in finished_sims.items():
        assert (sims / name / "simulation.json").stat().st_mtime_ns == mtime
    for key, data in finished_cells.items():
        assert (cells / f"{key}.json").read_bytes() == data
    whole = run_sweep(load_config(cfg_path), tmp_path / "whole", workers=0, progress=False)
    pd.testing.assert_frame_equal(_scores(resumed.table), _scores(whole.table))


def _kill_after(proc, cells, n_cells: int, timeout: float) -> None:
    """SIGKILL the sweep's process group once ``n_cells`` cell files are in ``cells`` (fails if it ends first)."""
    try:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and proc.poll() is None:
            if cells.is_dir() and len(list(cells.glob("*.json"))) >= n_cells:
                break
            time.sleep(0.02)
        assert proc.poll() is None, f"the sweep ended before it could be killed: {proc.stderr.read().decode()}"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:  # pragma: no cover - only if an assertion fired first
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
