"""The Dask executor (pirl_sim.engine.executors): the same sweep through a Dask LocalCluster of 2 workers
(loopback) gives the local run's table, a SUMO simulation included."""

import os

import pandas as pd
import pytest

from pirl_sim.engine import TIMING_COLUMNS, parse_config, run_sweep
from pirl_sim.engine.executors import DaskExecutor, LocalExecutor

distributed = pytest.importorskip("dask.distributed")

TEXT = """
name = "dask"
seeds = [0, 1]

[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 100, n_train = 80 }
protocols = ["paper", { kind = "online", history_steps = 10 }]
learners = ["tirl", { name = "pirl-gmm", params = { n_components = 2 } },
            { name = "pirl-knn", grid = { n_neighbors = [1, 5] } }]

[[experiments]]
scenario = "passage"
params = { n_trajectories = 40, n_train = 30 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 15, stride = 5 }]
learners = ["tirl", { name = "pirl-knn", params = { n_neighbors = 3 } }]

[[experiments]]
scenario = "sumo"
seeds = [0]
params = { n_vehicles = 8, depart_interval = 3.0 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 20 }]
learners = ["ca", { name = "tirl", params = { likelihood = "receding", step_stride = 4 } }]
"""


@pytest.fixture(autouse=True)
def _thread_variables_restored():
    """distributed's nanny writes its pre-spawn environment (OMP/MKL/OPENBLAS_NUM_THREADS=1, PYTHONHASHSEED, ...)
    into the process that starts a LocalCluster and leaves it there: put back what the test process had, for the
    tests after these."""
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)


def _scores(table):
    return table.drop(columns=list(TIMING_COLUMNS)).reset_index(drop=True)


def test_dask_local_cluster_gives_the_local_table(tmp_path):
    import tomllib

    config = parse_config(tomllib.loads(TEXT), text=TEXT)
    with LocalExecutor(2) as local:
        ran_local = run_sweep(config, tmp_path / "local", executor=local, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        ex = DaskExecutor(client)
        assert ex.workers == 2
        ran_dask = run_sweep(config, tmp_path / "dask", executor=ex, progress=False)
        hosts = {(r["worker"]["host"], r["worker"]["pid"]) for r in _records(tmp_path / "dask")}
    assert not ran_local.failed and not ran_dask.failed
    assert len(ran_dask.computed) == len(config.cells) == 22
    assert len(ran_dask.simulated) == len(ran_local.simulated) == 1  # the SUMO run, on a Dask worker
    assert len(hosts) == 2  # both Dask workers ran cells
    pd.testing.assert_frame_equal(_scores(ran_dask.table), _scores(ran_local.table))
    local_csv = pd.read_csv(tmp_path / "local" / "table.csv").drop(columns=list(TIMING_COLUMNS))
    dask_csv = pd.read_csv(tmp_path / "dask" / "table.csv").drop(columns=list(TIMING_COLUMNS))
    assert local_csv.to_csv(index=False) == dask_csv.to_csv(index=False)  # bit for bit


def _records(out):
    import json

    return [json.loads(p.read_text()) for p in (out / "cells").glob("*.json")]
