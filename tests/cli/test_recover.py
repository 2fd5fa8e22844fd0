"""``pirl-sim recover`` runs through the engine: killed mid-run it resumes to the same files, and
``--dry-run`` counts the runs still to do."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from pirl_sim.cli import main

pytest.importorskip("highway_env")

ARGS = ["recover", "--simulator", "highway", "--seeds", "0", "1", "--n-vehicles", "8", "--control-noise", "0",
        "--noise-seeds", "0", "--quiet"]
FILES = ("table.csv", "styles.csv", "tracks.csv", "selection.csv", "noise.csv", "table.md", "noise.md")


@pytest.mark.slow
def test_a_killed_recover_resumes_to_the_same_files(tmp_path, capsys):
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "pirl_sim", *ARGS, "--workers", "1", "--out", str(killed)],
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    cells = killed / "cells"
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline and not list(cells.glob("*.json")):
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL
    kept = {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json")}
    assert len(kept) == 1 and not (killed / "table.csv").exists()  # one of two runs finished, no table yet

    assert main([*ARGS, "--dry-run", "--out", str(killed)]) == 0
    assert capsys.readouterr().out.rstrip().endswith("1 already in " + f"{killed}/, 1 to run")
    assert main([*ARGS, "--workers", "0", "--out", str(killed)]) == 0
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json") if p.name in kept} == kept  # not redone
    fresh = tmp_path / "fresh"
    assert main([*ARGS, "--workers", "0", "--out", str(fresh)]) == 0
    for name in FILES:
        assert (killed / name).read_bytes() == (fresh / name).read_bytes(), name
    assert main([*ARGS, "--dry-run", "--out", str(fresh)]) == 0
    assert capsys.readouterr().out.rstrip().endswith("0 to run")


def test_bad_recover_input_is_a_clear_error(tmp_path, capsys):
    pop = tmp_path / "pop.toml"
    pop.write_text("n_vehicles = 'many'\n")
    assert main(["recover", "--population", str(pop), "--dry-run", "--out", str(tmp_path / "o")]) == 2
    assert "n_vehicles" in capsys.readouterr().err
    assert main(["recover", "--population", str(tmp_path / "absent.toml"), "--dry-run", "--out", str(tmp_path)]) == 2
    assert "population config not found" in capsys.readouterr().err
