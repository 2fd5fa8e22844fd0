"""The Dask executor (pirl_sim.engine.executors): the same sweep through a Dask LocalCluster of 2 workers
(loopback) gives the local run's table, a SUMO simulation included; ``pirl-sim sweep --scheduler-file`` on a
scheduler and worker started as commands (as on a cluster) gives the local table too; a worker with other package
versions, and a missing scheduler file, are clear errors before any cell runs."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.engine import TIMING_COLUMNS, executors, run_sweep
from pirl_sim.engine.executors import DaskExecutor, LocalExecutor, check_worker_versions, package_versions

from sweep_configs import TINY_EXPERIMENT, sweep_config, sweep_toml

distributed = pytest.importorskip("dask.distributed")

# TINY's synthetic experiment (16 cells), a passage one (4 cells) and a SUMO one (2 cells, one simulation)
TEXT = sweep_toml("dask", [0, 1], TINY_EXPERIMENT, """
scenario = "passage"
params = { n_trajectories = 40, n_train = 30 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 15, stride = 5 }]
learners = ["tirl", { name = "pirl-knn", params = { n_neighbors = 3 } }]
""", """
scenario = "sumo"
seeds = [0]
params = { n_vehicles = 8, depart_interval = 3.0 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 20 }]
learners = ["ca", { name = "tirl", params = { likelihood = "receding", step_stride = 4 } }]
""")


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
    config = sweep_config(TEXT)
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


TINY = sweep_toml("tiny", [0], """
scenario = "synthetic"
params = { n_trajectories = 60, n_train = 40 }
protocols = ["paper"]
learners = ["cv", "tirl", { name = "pirl-knn", grid = { n_neighbors = [1, 3] } }]
""")


def _dask_command(name: str) -> list[str]:
    """``dask NAME``, or the module behind it where the ``dask`` command is not installed."""
    if shutil.which("dask"):
        return ["dask", name]
    return [sys.executable, "-m", f"distributed.cli.dask_{name}"]


def _stop(proc: subprocess.Popen) -> None:
    """End the process group of ``proc`` (started in its own session): SIGTERM, SIGKILL after 10 s."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    except ProcessLookupError:
        pass


@pytest.fixture(scope="module")
def scheduler_file(tmp_path_factory):
    """A scheduler and one worker (one process, one thread) on 127.0.0.1, started as on a cluster by their
    commands; the scheduler file's path."""
    folder = tmp_path_factory.mktemp("dask")
    path = folder / "scheduler.json"
    procs = []
    with open(folder / "scheduler.log", "w") as scheduler_log, open(folder / "worker.log", "w") as worker_log:
        try:
            procs.append(subprocess.Popen(
                [*_dask_command("scheduler"), "--scheduler-file", str(path), "--host", "127.0.0.1", "--port", "0",
                 "--no-dashboard"], cwd=folder, start_new_session=True, stdout=subprocess.DEVNULL,
                stderr=scheduler_log))
            deadline = time.monotonic() + 30
            while not (path.is_file() and path.stat().st_size > 0):
                assert procs[0].poll() is None, (folder / "scheduler.log").read_text()
                assert time.monotonic() < deadline, "no scheduler file after 30 s"
                time.sleep(0.1)
            procs.append(subprocess.Popen(
                [*_dask_command("worker"), "--scheduler-file", str(path), "--nthreads", "1", "--nworkers", "1",
                 "--host", "127.0.0.1", "--no-dashboard"], cwd=folder, start_new_session=True,
                stdout=subprocess.DEVNULL, stderr=worker_log))
            with distributed.Client(scheduler_file=str(path), timeout="30s") as client:
                client.wait_for_workers(1, timeout=60)
            yield path
        finally:
            for proc in reversed(procs):
                _stop(proc)


@pytest.mark.slow
def test_cli_scheduler_file_gives_the_local_table(scheduler_file, tmp_path, capsys):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    assert main(["sweep", str(cfg), "--workers", "0", "--out", str(tmp_path / "local"), "--quiet"]) == 0
    assert main(["sweep", str(cfg), "--scheduler-file", str(scheduler_file), "--out", str(tmp_path / "dask"),
                 "--quiet"]) == 0
    assert "4 cells" in capsys.readouterr().out
    workers = {r["worker"]["pid"] for r in _records(tmp_path / "dask")}
    assert len(workers) == 1 and os.getpid() not in workers  # the Dask worker ran them
    local_csv = pd.read_csv(tmp_path / "local" / "table.csv").drop(columns=list(TIMING_COLUMNS))
    dask_csv = pd.read_csv(tmp_path / "dask" / "table.csv").drop(columns=list(TIMING_COLUMNS))
    assert len(dask_csv) == 4
    assert local_csv.to_csv(index=False) == dask_csv.to_csv(index=False)


@pytest.mark.slow
def test_worker_with_other_versions_is_refused(scheduler_file, tmp_path, monkeypatch, capsys):
    with distributed.Client(scheduler_file=str(scheduler_file), timeout="30s") as client:
        check_worker_versions(client)  # the same install: passes
        worker = next(iter(client.scheduler_info()["workers"]))
        ours = package_versions()
        with pytest.raises(ValueError) as err:  # the worker reports another numpy
            check_worker_versions(client, versions=lambda: {**package_versions(), "numpy": "1.0.0"})
        assert str(err.value).startswith(f"Dask worker {worker} runs numpy 1.0.0, this client {ours['numpy']}")
    # through the command: the client expects another numpy; nothing runs, nothing is written
    monkeypatch.setattr(executors, "package_versions", lambda: {**ours, "numpy": "1.0.0"})
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    out = tmp_path / "out"
    assert main(["sweep", str(cfg), "--scheduler-file", str(scheduler_file), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"runs numpy {ours['numpy']}, this client 1.0.0" in err and worker in err
    assert not out.exists()


SUMO = sweep_toml("sumo", [0], """
scenario = "sumo"
params = { n_vehicles = 8, depart_interval = 3.0 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 20 }]
learners = ["ca"]
""")


@pytest.mark.slow
def test_cli_relative_out_holds_the_simulation(scheduler_file, tmp_path, monkeypatch):
    """A relative --out is the client's: the worker (started in another directory) records the SUMO run there."""
    pytest.importorskip("libsumo")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sumo.toml").write_text(SUMO)
    assert main(["sweep", "sumo.toml", "--scheduler-file", str(scheduler_file), "--out", "rel", "--quiet"]) == 0
    assert len(list((tmp_path / "rel" / "simulations").glob("*/simulation.json"))) == 1
    assert not (scheduler_file.parent / "rel").exists()  # the worker's directory


def test_missing_or_bad_scheduler_file_is_a_clear_error(tmp_path, capsys):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    missing = tmp_path / "nowhere" / "scheduler.json"
    out = tmp_path / "out"
    assert main(["sweep", str(cfg), "--scheduler-file", str(missing), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"scheduler file {missing} does not exist" in err
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"type": "Scheduler"}))
    assert main(["sweep", str(cfg), "--scheduler-file", str(bad), "--out", str(out)]) == 2
    assert f"scheduler file {bad} holds no scheduler address" in capsys.readouterr().err
    for extra in (["--workers", "2"], ["--scheduler", "tcp://127.0.0.1:1"]):
        assert main(["sweep", str(cfg), "--scheduler-file", str(missing), *extra, "--out", str(out)]) == 2
        assert f"not both {extra[0]} and --scheduler-file" in capsys.readouterr().err
    assert not out.exists()
