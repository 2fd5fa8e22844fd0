"""``pirl-sim reproduce``: the quick configs end to end and byte-identical, resumed after an interruption, and bad
seeds, arguments and output directories refused before any work starts."""

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from pirl_sim.cli import main


def test_reproduce_quick_config_end_to_end_and_byte_identical(tmp_path, capsys):
    args = ["reproduce", "synthetic", "--n-trajectories", "240", "--n-train", "200", "--quiet"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    assert "MED(TIRL) > MED(PIRL-GMM) > MED(PIRL-kNN)" in out
    names = ["table.csv", "table.md", "knn_k.csv", "knn_k.png", "README.md"]
    for n in names:
        assert (tmp_path / "a" / n).read_bytes() == (tmp_path / "b" / n).read_bytes(), n
    table = pd.read_csv(tmp_path / "a" / "table.csv")
    assert set(table["learner"]) == {"TIRL", "PIRL-GMM (k=2)", "PIRL-kNN (k=1)", "PIRL-DPGMM"}
    assert table["med"].notna().all() and (table["med"] >= 0).all()


def test_cli_rejects_bad_arguments(tmp_path, capsys):
    assert main(["reproduce", "synthetic", "--n-trajectories", "10", "--n-train", "10", "--out", str(tmp_path)]) == 2
    assert "n_train must be in" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["reproduce", "highway"])
    with pytest.raises(SystemExit):
        main(["reproduce", "synthetic", "--n-train", "-3"])


def test_reproduce_help_in_a_fresh_process():
    out = subprocess.run(
        [sys.executable, "-m", "pirl_sim", "reproduce", "--help"], capture_output=True, text=True, check=True
    )
    assert "--history-steps" in out.stdout


def test_reproduce_passage_quick_config(tmp_path, capsys):
    out = tmp_path / "p"
    assert main(["reproduce", "passage", "--n-trajectories", "150", "--n-train", "120", "--quiet", "--out", str(out)]) == 0
    table = pd.read_csv(out / "table.csv")
    assert len(table) == 12 and table["med"].notna().all()
    for name in ("knn_k.png", "clusters.png", "s_t.png", "switch.png", "README.md"):
        assert (out / name).stat().st_size > 0
    assert "crosses half-way after" in (out / "README.md").read_text()


def test_an_interrupted_reproduce_resumes_without_recomputing_finished_cells(tmp_path, monkeypatch):
    """`reproduce synthetic` killed (SIGKILL) after its first cells: the same command computes only the missing
    cells, leaves the finished ones untouched and writes the same files as an uninterrupted run."""
    import json
    import os
    import signal
    import time

    import pirl_sim.engine.run as sweep_run
    from pirl_sim.engine.presets import preset_config
    from pirl_sim.engine.store import code_version

    args = ["reproduce", "synthetic", "--quiet"]
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "pirl_sim", *args, "--out", str(killed)],
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    cells = killed / "cells"
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline and len(list(cells.glob("*.json"))) < 3:
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL
    kept = {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json")}
    if kept and json.loads(next(cells.glob("*.json")).read_text())["code_version"] != code_version():
        pytest.skip("the cell code changed while the test ran (a shared working tree): every cell would rerun")
    n_cells = len({c.key(code_version()) for c in preset_config("synthetic").cells})
    assert 3 <= len(kept) < n_cells and not (killed / "table.csv").exists()

    computed = []
    run_cells = sweep_run.run_cells
    monkeypatch.setattr(sweep_run, "run_cells", lambda specs, *a: computed.extend(specs) or run_cells(specs, *a))
    assert main(args + ["--out", str(killed)]) == 0
    assert len(computed) == n_cells - len(kept)
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json") if p.name in kept} == kept
    fresh = tmp_path / "fresh"
    assert main(args + ["--out", str(fresh)]) == 0
    for name in ("table.csv", "table.md", "knn_k.csv", "knn_k.png", "README.md"):
        assert (killed / name).read_bytes() == (fresh / name).read_bytes(), name


@pytest.mark.parametrize("seed", ["-1", "4294967296", "2147483648", "x"])
def test_reproduce_rejects_seeds_outside_the_shared_range(tmp_path, capsys, seed):
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "synthetic", "--seed", seed, "--out", str(tmp_path / "o"), "--quiet"])
    assert exc.value.code == 2
    assert "--seed" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()

def _bad_outputs(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a directory")
    return [(a_file, "is an existing file"), (a_file / "sub", "is not a writable directory"),
            (Path("/proc/pirl_sim_not_writable"), "is not a writable directory")]


@pytest.mark.parametrize("experiment", ["synthetic", "passage"])
def test_reproduce_checks_the_output_directory_before_the_work(tmp_path, capsys, monkeypatch, experiment):
    import pirl_sim.engine.presets as presets

    def no_work(*args, **kwargs):  # the check must come first: the work is never started
        raise AssertionError("the work started although the output directory is unusable")

    monkeypatch.setattr(presets, "run_sweep", no_work)
    for out, message in _bad_outputs(tmp_path):
        code = main(["reproduce", experiment, "--n-trajectories", "150", "--n-train", "120", "--quiet",
                     "--out", str(out)])
        assert code == 2
        assert message in capsys.readouterr().err
