"""A sweep killed with SIGKILL halfway resumes without losing or recomputing a finished cell (issue 7)."""

import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from pirl_sim.engine import TIMING_COLUMNS, load_config, run_sweep

CONFIG = """
name = "resume"
seeds = [0, 1]

[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 600, n_train = 500 }
protocols = ["paper", { kind = "online", history_steps = 10 }]
learners = ["tirl", "pirl-dpgmm", { name = "pirl-gmm", grid = { n_components = [2, 3] } },
            { name = "pirl-knn", grid = { n_neighbors = [1, 3, 5] } }]
"""
N_CELLS = 2 * 2 * 7


def _scores(table):
    return table.drop(columns=list(TIMING_COLUMNS)).reset_index(drop=True)


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


SUMO_CONFIG = """
name = "resume-sumo"
seeds = [0, 1, 2]

[[experiments]]
scenario = "sumo"
params = { n_vehicles = 8, depart_interval = 3.0 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 20 }]
learners = ["cv", "ca", { name = "tirl", params = { likelihood = "receding", step_stride = 4 } }]
"""


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
