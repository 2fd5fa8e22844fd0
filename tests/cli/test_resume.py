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


def resumes_after_a_kill(argv, tmp_path, capsys, n_cells: int, files=(), timings=()):
    """`kill_after_first_cell`, then the dry run's counts and the resumed run (the stored cells kept, not
    computed again); ``files`` of the resumed run against an uninterrupted run's: equal bytes, or for
    ``timings`` columns given, equal CSV tables without them. Returns the resumed run's directory."""
    killed, fresh = tmp_path / "killed", tmp_path / "fresh"
    kept = kill_after_first_cell(argv, killed)
    assert 1 <= len(kept) < n_cells
    capsys.readouterr()
    assert main([*argv, "--dry-run", "--out", str(killed)]) == 0
    assert f"{len(kept)} already in {killed}/, {n_cells - len(kept)} to run" in capsys.readouterr().out
    assert main([*argv, "--out", str(killed)]) == 0
    cells = killed / "cells"
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json") if p.name in kept} == kept  # not redone
    if files:
        assert main([*argv, "--out", str(fresh)]) == 0
    for name in files:
        if timings:
            a, b = (pd.read_csv(d / name).drop(columns=list(timings), errors="ignore") for d in (killed, fresh))
            pd.testing.assert_frame_equal(a, b, check_exact=True)
        else:
            assert (killed / name).read_bytes() == (fresh / name).read_bytes(), name
    capsys.readouterr()
    assert main([*argv, "--dry-run", "--out", str(killed)]) == 0
    assert f"{n_cells} already in {killed}/, 0 to run" in capsys.readouterr().out
    return killed


@pytest.fixture(scope="module")
def weaving(tmp_path_factory):
    return weaving_scene(tmp_path_factory.mktemp("weaving"))


@pytest.mark.slow
def test_a_killed_replay_resumes(weaving, tmp_path, capsys):
    tracks, osm = weaving
    argv = ["replay", "--preset", "paper",
            "--tracks", str(tracks), "--map", str(osm), "--seeds", "3", "--learners", "tirl",
            "--quiet"]
    # per seed: CV, CA, TIRL and CV (x, y), one task per seed
    resumes_after_a_kill(argv, tmp_path, capsys, 12, ["rows.csv", "paired_ca.csv"], timings=("fit_s", "predict_s"))


@pytest.mark.slow
def test_a_killed_horizon_scan_resumes(weaving, tmp_path, capsys):
    tracks, osm = weaving
    argv = ["replay", "--preset", "paper",
            "--tracks", str(tracks), "--map", str(osm), "--seeds", "3", "--scan-horizon", "5,8",
            "--features", "speed-level", "--quiet"]
    resumes_after_a_kill(argv, tmp_path, capsys, 6, ["horizon_scan_rows.csv"], timings=("fit_s",))


@pytest.mark.slow
def test_a_killed_agents_run_resumes(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    argv = ["agents", "--steps", "64", "--n-steps", "32", "--seeds", "0,1", "--episodes", "1", "--modes", "none",
            "--direct-modes", "", "--baselines", "hold-speed", "--workers", "1", "--quiet"]
    resumes_after_a_kill(argv, tmp_path, capsys, 3, ["episodes.csv"])


@pytest.mark.slow
def test_a_killed_recover_resumes(tmp_path, capsys):
    pytest.importorskip("highway_env")
    argv = ["recover", "--simulator", "highway", "--seeds", "0", "1", "--n-vehicles", "8", "--control-noise", "0",
            "--noise-seeds", "0", "--workers", "1", "--quiet"]
    resumes_after_a_kill(argv, tmp_path, capsys, 2, ["table.csv", "styles.csv", "tracks.csv", "selection.csv",
                                                     "noise.csv", "table.md", "noise.md"])


@pytest.mark.slow
def test_a_killed_policy_recovery_resumes(tmp_path, capsys):
    pytest.importorskip("highway_env")
    pytest.importorskip("stable_baselines3")
    argv = ["policy-recovery", "--steps", "64", "--n-steps", "64", "--seeds", "0,1", "--eval-seeds", "1000",
            "--n-vehicles", "1", "--initial-vehicles", "0", "--duration", "4", "--workers", "0", "--quiet"]
    killed = resumes_after_a_kill(argv, tmp_path, capsys, 3, ["episodes.csv", "summary.csv", "summary.md",
                                                               "tracks.csv"])  # README.md holds wall times
    assert "Made by `pirl-sim policy-recovery" in (killed / "README.md").read_text()


@pytest.mark.slow
def test_a_killed_weight_space_resumes_to_the_rows_of_the_committed_table(tmp_path, capsys):
    from pathlib import Path

    argv = ["weight-space", "--experiments", "lq-receding", "--workers", "1", "--quiet"]  # 6 cells of seconds
    killed = resumes_after_a_kill(argv, tmp_path, capsys, 6)
    committed = Path(__file__).resolve().parents[2] / "results" / "weight_space" / "table.csv"
    lines = committed.read_text().splitlines(keepends=True)  # the uninterrupted run of the whole study
    assert (killed / "table.csv").read_text() == "".join([lines[0], *(x for x in lines if x.startswith("lq-receding,"))])
    assert "Written by `pirl-sim weight-space --experiments lq-receding`" in (killed / "README.md").read_text()
