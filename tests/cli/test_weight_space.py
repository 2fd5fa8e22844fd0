"""``pirl-sim weight-space`` runs through the engine: killed mid-run it resumes to the rows of the committed
(uninterrupted) table, ``--dry-run`` counts the cells still to run, and bad options are clear errors."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pirl_sim.cli import main

ARGS = ["weight-space", "--experiments", "lq-receding", "--quiet"]  # 6 cells of a few seconds each
COMMITTED = Path(__file__).resolve().parents[2] / "results" / "weight_space" / "table.csv"


@pytest.mark.slow
def test_a_killed_weight_space_resumes_to_the_rows_of_an_uninterrupted_run(tmp_path, capsys):
    killed = tmp_path / "killed"
    assert main([*ARGS, "--dry-run", "--out", str(killed)]) == 0
    assert capsys.readouterr().out.rstrip().endswith("6 cells, 0 already in " + f"{killed}/, 6 to run")
    proc = subprocess.Popen([sys.executable, "-m", "pirl_sim", *ARGS, "--workers", "1", "--out", str(killed)],
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    cells = killed / "cells"
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline and not list(cells.glob("*.json")):
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)  # the command and its worker process
    assert proc.wait() == -signal.SIGKILL
    kept = {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json")}
    assert 1 <= len(kept) < 6 and not (killed / "table.csv").exists()

    assert main([*ARGS, "--dry-run", "--out", str(killed)]) == 0
    assert capsys.readouterr().out.rstrip().endswith(f"{len(kept)} already in {killed}/, {6 - len(kept)} to run")
    assert main([*ARGS, "--workers", "0", "--out", str(killed)]) == 0
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json") if p.name in kept} == kept  # not redone
    lines = COMMITTED.read_text().splitlines(keepends=True)  # the uninterrupted run of the whole study
    rows = [lines[0], *(x for x in lines if x.startswith("lq-receding,"))]
    assert (killed / "table.csv").read_text() == "".join(rows)
    assert "Written by `pirl-sim weight-space --experiments lq-receding`" in (killed / "README.md").read_text()
    assert main([*ARGS, "--dry-run", "--out", str(killed)]) == 0
    assert capsys.readouterr().out.rstrip().endswith("6 already in " + f"{killed}/, 0 to run")


def test_dry_run_counts_every_cell_of_every_seed(tmp_path, capsys):
    from pirl_sim.cli.weight_space import EXPERIMENTS
    from pirl_sim.experiments import weight_space

    assert EXPERIMENTS == tuple(weight_space.EXPERIMENTS)
    assert main(["weight-space", "--dry-run", "--seeds", "0", "1", "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().out.rstrip() == f"weight-space: 148 cells, 0 already in {tmp_path}/, 148 to run"


@pytest.mark.parametrize("argv, message", [
    (["--experiments", "nope"], "argument --experiments: invalid choice: 'nope'"),
    (["--seeds", "-1"], "the seed must be in [0, 2**31)"),
    (["--workers", "-1"], "expected a number of workers >= 0, got -1"),
])
def test_bad_options_are_argparse_errors(tmp_path, capsys, argv, message):
    with pytest.raises(SystemExit) as exit_info:
        main(["weight-space", *argv, "--dry-run", "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_bad_values_are_clear_errors(tmp_path, capsys):
    assert main(["weight-space", "--seeds", "3", "3", "--dry-run", "--out", str(tmp_path)]) == 2
    assert "repeats a seed: [3, 3]" in capsys.readouterr().err
    (tmp_path / "a_file").write_text("")
    assert main(["weight-space", "--dry-run", "--out", str(tmp_path / "a_file")]) == 2
    assert capsys.readouterr().err.startswith("pirl-sim: error: --out")
