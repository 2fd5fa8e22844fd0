"""``pirl-sim policy-recovery`` runs through the engine: killed mid-run it resumes to the same files, ``--dry-run``
counts the cells still to run, and bad options are clear errors (the study: tests/experiments/)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from pirl_sim.cli import main

ARGS = ["policy-recovery", "--steps", "64", "--n-steps", "64", "--seeds", "0,1", "--eval-seeds", "1000",
        "--n-vehicles", "1", "--initial-vehicles", "0", "--duration", "4", "--quiet"]
FILES = ("episodes.csv", "summary.csv", "summary.md", "tracks.csv")  # README.md holds wall times


@pytest.mark.slow
def test_a_killed_policy_recovery_resumes_to_the_same_files(tmp_path, capsys):
    pytest.importorskip("highway_env")
    pytest.importorskip("stable_baselines3")
    killed = tmp_path / "killed"
    assert main([*ARGS, "--dry-run", "--out", str(killed)]) == 0
    assert capsys.readouterr().out.rstrip().endswith(f"3 cells, 0 already in {killed}/, 3 to run")
    proc = subprocess.Popen([sys.executable, "-m", "pirl_sim", *ARGS, "--workers", "0", "--out", str(killed)],
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    cells = killed / "cells"
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline and not list(cells.glob("*.json")):
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL
    kept = {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json")}
    assert len(kept) == 1 and not (killed / "summary.csv").exists()  # one of three cells finished, no report yet

    assert main([*ARGS, "--dry-run", "--out", str(killed)]) == 0
    assert capsys.readouterr().out.rstrip().endswith(f"1 already in {killed}/, 2 to run")
    assert main([*ARGS, "--workers", "0", "--out", str(killed)]) == 0
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json") if p.name in kept} == kept  # not redone
    fresh = tmp_path / "fresh"
    assert main([*ARGS, "--workers", "0", "--out", str(fresh)]) == 0
    assert f"wrote {fresh}/" in capsys.readouterr().out
    for name in FILES:
        assert (killed / name).read_bytes() == (fresh / name).read_bytes(), name
    assert "Made by `pirl-sim policy-recovery" in (fresh / "README.md").read_text()
    assert main([*ARGS, "--dry-run", "--out", str(fresh)]) == 0
    assert capsys.readouterr().out.rstrip().endswith("0 to run")


@pytest.mark.parametrize("option, value, message", [
    ("--steps", "0", "argument --steps: expected a positive integer, got 0"),
    ("--n-steps", "many", "argument --n-steps: expected a positive integer, got 'many'"),
    ("--n-vehicles", "-2", "argument --n-vehicles: expected a positive integer, got -2"),
    ("--seeds", "0,-1", "argument --seeds: expected comma-separated integers >= 0, got '0,-1'"),
    ("--eval-seeds", "", "argument --eval-seeds: expected comma-separated integers >= 0, got ''"),
    ("--duration", "0", "argument --duration: expected a finite number > 0, got '0'"),
    ("--speed-dev", "nan", "argument --speed-dev: expected a finite number > 0, got 'nan'"),
    ("--workers", "-1", "argument --workers: expected a number of workers >= 0, got -1"),
])
def test_bad_options_exit_2_naming_the_value(tmp_path, capsys, option, value, message):
    with pytest.raises(SystemExit) as exit_info:
        main(["policy-recovery", option, value, "--dry-run", "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_bad_settings_are_refused_before_any_work(tmp_path, capsys):
    import argparse

    from pirl_sim.cli import policy_recovery
    from pirl_sim.experiments.policy_recovery import PpoRecoveryConfig

    parser = argparse.ArgumentParser()
    policy_recovery.add_parser(parser.add_subparsers())
    assert parser.parse_args(["policy-recovery"]).duration == PpoRecoveryConfig.duration  # named in the parser
    assert main(["policy-recovery", "--initial-vehicles", "9", "--dry-run", "--out", str(tmp_path / "o")]) == 2
    assert "pirl-sim: error: initial_vehicles = 9 exceeds n_vehicles = 8" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    (tmp_path / "file").write_text("")
    assert main(["policy-recovery", "--out", str(tmp_path / "file")]) == 2
    assert f"--out {tmp_path / 'file'} is an existing file" in capsys.readouterr().err
