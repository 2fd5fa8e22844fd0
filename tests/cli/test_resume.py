"""Experiment commands run through the engine: SIGKILLed once a cell is stored, the same command resumes (the
stored cells are not computed again) to the files an uninterrupted run writes, and ``--dry-run`` counts the cells
still to run. (``sweep``: tests/engine/test_run.py; ``reproduce``, ``recover``, ``weight-space`` and
``policy-recovery``: their own command's tests.)"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from pirl_sim.cli import main
from weaving import weaving_scene


def kill_after_first_cell(argv: list[str], out) -> dict[str, int]:
    """Run ``pirl-sim ARGV --out OUT`` in a process group, SIGKILL it once a cell file is in OUT/cells; returns
    the stored cell files' names with their modification times."""
    proc = subprocess.Popen([sys.executable, "-m", "pirl_sim", *argv, "--out", str(out)],
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True)
    cells = out / "cells"
    deadline = time.monotonic() + 600
    while proc.poll() is None and time.monotonic() < deadline and not list(cells.glob("*.json")):
        time.sleep(0.01)
    ended = proc.poll()
    os.killpg(proc.pid, signal.SIGKILL)
    stderr = proc.communicate()[1].decode(errors="replace")
    assert ended is None, f"the command ended before it was killed (status {ended}): {stderr[-2000:]}"
    return {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json")}


def resumes_to_the_same_files(argv, tmp_path, capsys, files, n_cells, timings=()):
    """`kill_after_first_cell`, then the dry run's counts, the resumed run (stored cells kept) and the files
    against an uninterrupted run's: CSV ``files`` equal but for the ``timings`` columns."""
    killed, fresh = tmp_path / "killed", tmp_path / "fresh"
    kept = kill_after_first_cell(argv, killed)
    assert 1 <= len(kept) < n_cells
    capsys.readouterr()
    assert main([*argv, "--dry-run", "--out", str(killed)]) == 0
    assert f"{len(kept)} already in {killed}/, {n_cells - len(kept)} to run" in capsys.readouterr().out
    assert main([*argv, "--out", str(killed)]) == 0
    cells = killed / "cells"
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json") if p.name in kept} == kept  # not redone
    assert main([*argv, "--out", str(fresh)]) == 0
    for name in files:
        a, b = (pd.read_csv(d / name).drop(columns=list(timings), errors="ignore") for d in (killed, fresh))
        pd.testing.assert_frame_equal(a, b, check_exact=True)
    capsys.readouterr()
    assert main([*argv, "--dry-run", "--out", str(fresh)]) == 0
    assert f"{n_cells} already in {fresh}/, 0 to run" in capsys.readouterr().out


@pytest.fixture(scope="module")
def weaving(tmp_path_factory):
    return weaving_scene(tmp_path_factory.mktemp("weaving"))


@pytest.mark.slow
def test_a_killed_replay_resumes(weaving, tmp_path, capsys):
    tracks, osm = weaving
    argv = ["replay", "--tracks", str(tracks), "--map", str(osm), "--seeds", "3", "--learners", "tirl",
            "--quiet"]
    # per seed: CV, CA, TIRL and CV (x, y), one task per seed
    resumes_to_the_same_files(argv, tmp_path, capsys, ["rows.csv", "paired_ca.csv"], 12,
                              timings=("fit_s", "predict_s"))


@pytest.mark.slow
def test_a_killed_horizon_scan_resumes(weaving, tmp_path, capsys):
    tracks, osm = weaving
    argv = ["replay", "--tracks", str(tracks), "--map", str(osm), "--seeds", "3", "--scan-horizon", "5,8",
            "--features", "speed-level", "--quiet"]
    resumes_to_the_same_files(argv, tmp_path, capsys, ["horizon_scan_rows.csv"], 6, timings=("fit_s",))


@pytest.mark.slow
def test_a_killed_agents_run_resumes(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    argv = ["agents", "--steps", "64", "--n-steps", "32", "--seeds", "0,1", "--episodes", "1", "--modes", "none",
            "--direct-modes", "", "--baselines", "hold-speed", "--workers", "1", "--quiet"]
    resumes_to_the_same_files(argv, tmp_path, capsys, ["episodes.csv"], 3)
