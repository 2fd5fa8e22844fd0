"""``pirl-sim sweep``: bad configs and learner settings refused by the dry run, damaged cell files not counted as
stored, failed cells reported through logging, and the report and dry run of the default config."""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.cli import main as sweep_main

from shared_sample import SAMPLE_MAP, needs_sample
from sweep_configs import BAD, TINY, TINY_LOG


SWEEP = """
seeds = [0]
[[experiments]]
scenario = "synthetic"
params = {{ n_trajectories = 60, n_train = 40 }}
protocols = [{{ kind = "paper" }}]
learners = [{learner}]
"""


def _sweep(tmp_path, learner: str, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(SWEEP.format(learner=learner))
    return path


@pytest.mark.parametrize("learner, message", [
    ('{ name = "pirl-gmm", params = { covariance_type = "weird" } }', "covariance_type"),
    ('{ name = "pirl-dpgmm", params = { covariance_type = "weird" } }', "covariance_type"),
    ('{ name = "pirl-gmm", params = { log_bounds = [5.0, -5.0] } }', r"log_bounds must be (\[low, high\]|a pair \(low, high\))"),
    ('{ name = "tirl", params = { log_bounds = [1.0] } }', r"log_bounds must be (\[low, high\]|a pair \(low, high\))"),
    ('{ name = "pirl-gmm", params = { log_bounds = [nan, 5.0] } }',
     r"learners\[0\]\.params\.log_bounds\[0\]: nan is not allowed"),
    ('{ name = "pirl-gmm", params = { random_state = 4294967296 } }', r"random_state must be an integer in \[0, 2\*\*31\)"),
    ('{ name = "pirl-gmm", params = { n_init = 0 } }', "n_init"),
])
def test_dry_run_rejects_learner_settings_that_fail_at_run_time(tmp_path, capsys, learner, message):
    path = _sweep(tmp_path, learner)
    assert main(["sweep", str(path), "--dry-run", "--out", str(tmp_path / "out")]) == 2
    assert re.search(message, capsys.readouterr().err)


def test_sweep_seeds_beyond_two_to_the_31_are_rejected(tmp_path, capsys):
    path = tmp_path / "s.toml"
    path.write_text(SWEEP.format(learner='"pirl-gmm"').replace("seeds = [0]", "seeds = [4294967296]"))
    assert main(["sweep", str(path), "--dry-run"]) == 2
    assert "seeds must hold integers in [0, 2**31), got 4294967296" in capsys.readouterr().err


@needs_sample
def test_dry_run_rejects_an_unreadable_replay_csv(tmp_path, capsys):
    pytest.importorskip("lanelet2")
    tracks = tmp_path / "vehicle_tracks_000.csv"
    tracks.write_text("track_id,foo\n1,2\n1,3\n2,4\n")
    path = tmp_path / "replay.toml"
    path.write_text(f"""
seeds = [0]
[[experiments]]
scenario = "replay"
params = {{ tracks = "{tracks}", map = "{SAMPLE_MAP}" }}
protocols = [{{ kind = "paper" }}]
learners = ["tirl"]
""")
    assert main(["sweep", str(path), "--dry-run"]) == 2
    assert "no valid track" in capsys.readouterr().err


def test_dry_run_does_not_count_corrupted_cell_files_as_stored(tmp_path, capsys):
    from pirl_sim.engine.config import load_config
    from pirl_sim.engine.store import code_version

    path = _sweep(tmp_path, '"tirl"')
    out = tmp_path / "out"
    key = load_config(path).cells[0].key(code_version())
    (out / "cells").mkdir(parents=True)
    (out / "cells" / f"{key}.json").write_text('{"key": "trunc')
    assert main(["sweep", str(path), "--dry-run", "--out", str(out)]) == 0
    assert "0 already in" in capsys.readouterr().out


def test_bad_config_fails_before_any_work(tmp_path, capsys):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(BAD["kNN k larger than the training set"][0])
    out = tmp_path / "results"
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--workers", "0"]) == 2
    assert "is larger than the training set" in capsys.readouterr().err
    assert not out.exists()  # nothing started, nothing written
    assert sweep_main(["sweep", str(tmp_path / "missing.toml"), "--out", str(out)]) == 2
    assert "not found" in capsys.readouterr().err
    cfg.write_text("seeds = [0\n")
    assert sweep_main(["sweep", str(cfg), "--out", str(out)]) == 2
    assert "not valid TOML" in capsys.readouterr().err
    cfg.write_text(TINY)
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--workers", "1", "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert "not both" in capsys.readouterr().err
    assert not out.exists()


def test_cli_sweep_report_and_dry_run(tmp_path, capsys):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY.replace("seeds = [0, 1]", "seeds = [0]"))
    out = tmp_path / "res"
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--workers", "0", "--dry-run"]) == 0
    assert "8 cells (8 distinct), 0 already in" in capsys.readouterr().out
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--workers", "0"]) == 0
    captured = capsys.readouterr()
    assert "8 cells in" in captured.out and "ETA" in captured.err and "8/8 cells" in captured.err
    assert sweep_main(["report", str(out)]) == 0
    assert "README.md" in capsys.readouterr().out and (out / "learners.png").exists()
    assert sweep_main(["sweep", str(cfg), "--out", str(out), "--dry-run"]) == 0
    assert "8 already in" in capsys.readouterr().out
    assert sweep_main(["report", str(tmp_path / "nothing")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_default_config_dry_run(capsys, tmp_path):
    assert sweep_main(["sweep", "--dry-run", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "sweep 'paper' (<default>): 294 cells (282 distinct), 0 already in" in out
    assert "282 to run and 6 simulations (code" in out  # SUMO and highway-env, 3 seeds each


def test_failed_cells_are_reported_through_logging(tmp_path, monkeypatch, caplog, capsys):
    import logging

    import pirl_sim.engine.run as engine_run
    from pirl_sim.cli import main

    class FakeRun:
        table = pd.DataFrame({"key": ["abc"]})
        computed, cached, failed, wall_s = ["abc"], [], {"abc": "ValueError: boom"}, 0.1

    monkeypatch.setattr(engine_run, "run_sweep", lambda *a, **k: FakeRun())
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_LOG)
    with caplog.at_level(logging.WARNING, logger="pirl_sim"):
        code = main(["sweep", str(cfg), "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 1
    messages = [r.getMessage() for r in caplog.records if r.name == "pirl_sim.cli.sweep"]
    assert any("cell abc failed: ValueError: boom" in m for m in messages), messages
    assert all(r.levelno == logging.WARNING for r in caplog.records if r.name == "pirl_sim.cli.sweep")
    err = capsys.readouterr().err
    assert "cell abc failed: ValueError: boom" in err  # and shown on stderr by the command's handler
    assert "1 cells failed" in err
