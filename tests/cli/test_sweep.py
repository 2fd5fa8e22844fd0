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


TINY = """
name = "tiny"
seeds = [0, 1]

[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 80, n_train = 60 }
protocols = ["paper", { kind = "online", history_steps = 10 }]
learners = ["tirl", { name = "pirl-gmm", params = { n_components = 2 } },
            { name = "pirl-knn", grid = { n_neighbors = [1, 4] } }]
"""


BAD = {
    "unknown top-level key": ("nme = 'x'\n" + TINY, r"unknown key\(s\) 'nme'; valid keys: name, description, seeds"),
    "unknown scenario": (TINY.replace('scenario = "synthetic"', 'scenario = "sumo-v9"'),
                         r"unknown scenario 'sumo-v9'; registered scenarios: .*passage.*synthetic"),
    "unknown learner": (TINY.replace('"tirl",', '"pirl-svm",'), r"unknown learner 'pirl-svm'; choose one of"),
    "unknown experiment key": (TINY.replace("protocols =", "protocol ="),
                               r"unknown key\(s\) 'protocol'; valid keys: scenario, label, seeds"),
    "unknown scenario parameter": (TINY.replace("n_train = 60", "n_tain = 60"),
                                   r"scenario 'synthetic': unknown parameter\(s\) 'n_tain'; valid parameters: "
                                   r"n_trajectories, n_train"),
    "unknown learner parameter": (TINY.replace("n_components = 2", "k = 2"),
                                  r"learner 'pirl-gmm': unknown parameter 'k'; valid parameters: .*n_components"),
    "unknown protocol kind": (TINY.replace('"paper",', '"offline",'), r"unknown protocol kind 'offline'"),
    "unknown protocol key": (TINY.replace("history_steps = 10", "history = 10"),
                             r"unknown key\(s\) 'history'; valid keys: kind, history_steps, horizon"),
    "empty value list": (TINY.replace("n_neighbors = [1, 4]", "n_neighbors = []"), r"empty grid: .*n_neighbors"),
    "no learners": (TINY.replace(TINY[TINY.index("learners ="):], "learners = []\n"),
                    r"empty grid: experiment 'synthetic' has no learner"),
    "no seeds": (TINY.replace("seeds = [0, 1]", "seeds = []"), r"empty grid: seeds is an empty list"),
    "no experiments": ('name = "x"\nseeds = [0]\n', r"empty grid: the sweep has no \[\[experiments\]\]"),
    "kNN k larger than the training set": (
        TINY.replace("n_neighbors = [1, 4]", "n_neighbors = [1, 61]"),
        r"PIRL-kNN \(k=61\) under the paper protocol: k = n_neighbors = 61 is larger than the training set "
        r"\(60 training trajectories"),
    "GMM k larger than the training set": (
        TINY.replace("n_components = 2", "n_components = 70"),
        r"k = n_components = 70 is larger than the training set"),
    "history longer than the trajectories": (
        TINY.replace("history_steps = 10", "history_steps = 50"),
        r"online \(history 50 steps\) protocol needs trajectories of at least 51 steps; the scenario's have at "
        r"most 50"),
    "window set by hand": (TINY.replace("n_components = 2", "n_components = 2, window = 5"),
                           r"'window' is set by the sweep"),
    "bad scenario value": (TINY.replace("n_train = 60", "n_train = 90"), r"scenario 'synthetic': n_train must be in"),
    "wrong type": (TINY.replace("n_train = 60", "n_train = 60.5"), r"'n_train' must be an integer, got 60.5"),
    "unknown style in a mix": (TINY.replace("n_train = 60 }", "n_train = 60, mix = { fast = 1.0 } }"),
                               r"mix names unknown style\(s\) \['fast'\]"),
    "two experiments with one label": (TINY + TINY[TINY.index("[[experiments]]"):],
                                       r"experiments 1 and 2 are both labelled 'synthetic': give one a label"),
    "rolling without horizon": (TINY.replace('"paper",', '{ kind = "rolling", history_steps = 5 },'),
                                r"the rolling protocol needs horizon >= 1"),
}


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


_TINY_SWEEP = """
name = "tiny-log"
seeds = [0]

[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 80, n_train = 60 }
protocols = ["paper"]
learners = ["tirl"]
"""


def test_failed_cells_are_reported_through_logging(tmp_path, monkeypatch, caplog, capsys):
    import logging

    import pirl_sim.engine.run as engine_run
    from pirl_sim.cli import main

    class FakeRun:
        table = pd.DataFrame({"key": ["abc"]})
        computed, cached, failed, wall_s = ["abc"], [], {"abc": "ValueError: boom"}, 0.1

    monkeypatch.setattr(engine_run, "run_sweep", lambda *a, **k: FakeRun())
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(_TINY_SWEEP)
    with caplog.at_level(logging.WARNING, logger="pirl_sim"):
        code = main(["sweep", str(cfg), "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 1
    messages = [r.getMessage() for r in caplog.records if r.name == "pirl_sim.cli.sweep"]
    assert any("cell abc failed: ValueError: boom" in m for m in messages), messages
    assert all(r.levelno == logging.WARNING for r in caplog.records if r.name == "pirl_sim.cli.sweep")
    err = capsys.readouterr().err
    assert "cell abc failed: ValueError: boom" in err  # and shown on stderr by the command's handler
    assert "1 cells failed" in err
