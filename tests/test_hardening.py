"""Issue 15: every bad input a clear error, nothing silently wrong (regression tests, one or more per item)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.io import interaction
from pirl_sim.io.interaction import read_tracks

from shared_sample import SAMPLE_MAP, SAMPLE_TRACKS, needs_sample  # noqa: E402
REPO = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------------- item 2: map nodes

@pytest.mark.parametrize("attr, value", [("lat", "abc"), ("lon", ""), ("lat", "nan"), ("lon", "inf"),
                                         ("lat", "91")])
@needs_sample
def test_map_node_with_bad_coordinate_is_an_error_naming_the_node(tmp_path, attr, value):
    pytest.importorskip("lanelet2")
    from pirl_sim.io.lanelet2_map import load_map

    text = SAMPLE_MAP.read_text()
    bad = tmp_path / "bad.osm"
    bad.write_text(re.sub(rf'(<node id="3"[^>]*?){attr}="[^"]*"', rf'\g<1>{attr}="{value}"', text, count=1))
    assert bad.read_text() != text
    with pytest.raises(ValueError, match=rf"bad.osm: node 3 has {attr}='{re.escape(value)}'; expected a number"):
        load_map(bad)


@needs_sample
def test_map_node_without_lat_and_non_xml_map_are_errors(tmp_path):
    pytest.importorskip("lanelet2")
    from pirl_sim.io.lanelet2_map import load_map

    bad = tmp_path / "nolat.osm"
    bad.write_text(re.sub(r'(<node id="5"[^>]*?)lat="[^"]*"', r"\1", SAMPLE_MAP.read_text(), count=1))
    with pytest.raises(ValueError, match="node 5 has no lat attribute"):
        load_map(bad)
    binary = tmp_path / "binary.osm"
    binary.write_bytes(b"\x00\xff\xfe garbage")
    with pytest.raises(ValueError, match="binary.osm: not a readable Lanelet2 map"):
        load_map(binary)


# ---------------------------------------------------------------------------------------------- item 8: lenient CSV

def _sample_lines() -> list[str]:
    return SAMPLE_TRACKS.read_text().splitlines()


@needs_sample
def test_lenient_reader_keeps_a_clean_file_whole():
    df, n_dropped = interaction.read_tracks_lenient(SAMPLE_TRACKS)
    assert n_dropped == 0 and df.equals(read_tracks(SAMPLE_TRACKS))


@needs_sample
def test_lenient_reader_does_not_truncate_a_fractional_track_id(tmp_path):
    lines = _sample_lines()
    fields = lines[5].split(",")
    fields[0] = "1.5"
    lines[5] = ",".join(fields)
    path = tmp_path / "vehicle_tracks_000.csv"
    path.write_text("\n".join(lines) + "\n")
    df, n_dropped = interaction.read_tracks_lenient(path)
    assert n_dropped == 1  # the row of no track is counted, not read as track 1
    assert len(df) == 169 and set(df["track_id"]) == {1, 2}
    assert 5 not in set(df.loc[df["track_id"] == 1, "frame_id"])  # line 6 held frame 5 of track 1


@needs_sample
def test_lenient_reader_drops_a_track_whose_timestamps_run_backwards(tmp_path):
    lines = _sample_lines()
    rows = [i for i in range(1, len(lines)) if lines[i].split(",")[0] == "2"]
    stamps = [lines[i].split(",")[2] for i in rows]
    for i, stamp in zip(rows, reversed(stamps)):
        fields = lines[i].split(",")
        fields[2] = stamp
        lines[i] = ",".join(fields)
    path = tmp_path / "vehicle_tracks_000.csv"
    path.write_text("\n".join(lines) + "\n")
    df, n_dropped = interaction.read_tracks_lenient(path)
    assert n_dropped == 1 and set(df["track_id"]) == {1}
    with pytest.raises(ValueError, match="timestamp_ms"):
        read_tracks(path)  # the strict reader names the row


@pytest.mark.parametrize("content", [b"", b"\xff\xfe\x00binary", b"a,b,c\n1,2,3\n"])
def test_lenient_reader_on_unreadable_files_returns_none(tmp_path, content):
    path = tmp_path / "vehicle_tracks_000.csv"
    path.write_bytes(content)
    assert interaction.read_tracks_lenient(path) == (None, 0)


# ---------------------------------------------------------------------------------------------- item 5: seeds

@pytest.mark.parametrize("seed", ["-1", "4294967296", "2147483648", "x"])
def test_reproduce_rejects_seeds_outside_the_shared_range(tmp_path, capsys, seed):
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "synthetic", "--seed", seed, "--out", str(tmp_path / "o"), "--quiet"])
    assert exc.value.code == 2
    assert "--seed" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------------------------- item 4: outputs

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


def test_reproduce_api_checks_the_output_directory_first(tmp_path, monkeypatch):
    import pirl_sim.engine.presets as presets

    monkeypatch.setattr(presets, "run_sweep", lambda *a, **k: pytest.fail("ran the cells before the check"))
    for out, message in _bad_outputs(tmp_path):
        with pytest.raises(ValueError, match=f"out_dir .* {message}"):
            presets.run_preset("synthetic", out, progress=False)


def test_report_checks_its_output_directory(tmp_path, capsys):
    results = REPO / "results" / "sweep"
    for out, message in _bad_outputs(tmp_path):
        assert main(["report", str(results), "--out", str(out)]) == 2
        assert message in capsys.readouterr().err


def test_simulate_checks_its_output_directory_before_the_run(tmp_path, capsys):
    pytest.importorskip("highway_env")
    for out, message in _bad_outputs(tmp_path):
        assert main(["simulate", "highway", "--n-vehicles", "2", "--quiet", "--out", str(out)]) == 2
        assert message in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- item 11

def test_report_on_a_truncated_table_names_the_file_and_row(tmp_path, capsys):
    text = (REPO / "results" / "sweep" / "table.csv").read_text()
    cases = {"mid_row": text[:len(text) - 40], "mid_quote": text[:len(text) // 2],
             "one_row": text[:text.index("\n") + 10], "header_only": text[:text.index("\n") + 1]}
    for name, cut in cases.items():
        d = tmp_path / name
        d.mkdir()
        (d / "table.csv").write_text(cut)
        assert main(["report", str(d), "--out", str(d / "o")]) == 2, name
        err = capsys.readouterr().err
        assert str(d / "table.csv") in err or "no finished cell" in err, (name, err)
        assert "Traceback" not in err


def test_n_vehicles_beyond_the_limit_is_an_error_not_a_memory_error(tmp_path, capsys):
    from pirl_sim.scenarios.population_config import MAX_VEHICLES, PopulationConfig

    with pytest.raises(ValueError, match=rf"n_vehicles must be >= 1 and <= {MAX_VEHICLES}, got 100000000000"):
        PopulationConfig(n_vehicles=100_000_000_000)
    assert main(["simulate", "highway", "--n-vehicles", "100000000000", "--quiet",
                 "--out", str(tmp_path / "o")]) == 2
    assert "n_vehicles must be >= 1 and <=" in capsys.readouterr().err


def test_control_noise_beyond_the_jerk_bound_is_rejected_up_front():
    from pirl_sim.scenarios.population_config import population_from_toml

    with pytest.raises(ValueError, match=r"pop.toml: control_noise must be >= 0 and <= 8 m/s\^3.*got 1000000.0"):
        population_from_toml("control_noise = 1e6\n", source="pop.toml")
    assert population_from_toml("control_noise = 8.0\n").control_noise == 8.0


@pytest.mark.parametrize("loader", ["population", "scenario", "sweep"])
def test_a_binary_toml_error_names_the_file(tmp_path, loader):
    path = tmp_path / "binary.toml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff")
    if loader == "population":
        from pirl_sim.scenarios.population_config import load_population as load
    elif loader == "scenario":
        from pirl_sim.scenarios.scenario_config import load_toml as load
    else:
        from pirl_sim.engine.config import load_config as load
    with pytest.raises(ValueError, match=rf"{re.escape(str(path))}: not valid TOML: .*not UTF-8"):
        load(path)


# ---------------------------------------------------------------------------------------------- item 9: sweep

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


# ---------------------------------------------------------------------------------------------- items 3 and 10: envs

BAD_ACTIONS = [
    (None, TypeError, "action must be a finite number"),
    ("0.5", TypeError, "action must be a finite number"),
    (np.array([np.nan], dtype=np.float32), ValueError, "action must be a finite number"),
    (np.array([np.inf]), ValueError, "action must be a finite number"),
    (np.array([0.1, 0.2]), ValueError, r"got shape \(2,\)"),
    (np.zeros((1, 1)), ValueError, r"got shape \(1, 1\)"),
]


def test_check_action_accepts_the_action_space_and_clips():
    from pirl_sim.envs.common import check_action

    assert check_action(np.array([0.25], dtype=np.float32)) == pytest.approx(0.25)
    assert check_action(0.5) == 0.5 and check_action(np.float64(-2.0)) == -1.0 and check_action([3]) == 1.0


@pytest.fixture(scope="module")
def highway_env():
    gym = pytest.importorskip("gymnasium")
    pytest.importorskip("highway_env")
    import pirl_sim.envs  # noqa: F401

    env = gym.make("pirl_sim/Roundabout-v0", config={"initial_vehicles": 2, "duration": 0.4}).unwrapped
    yield env
    env.close()


@pytest.mark.parametrize("action, error, message", BAD_ACTIONS)
def test_highway_backend_rejects_bad_actions_and_keeps_working(highway_env, action, error, message):
    highway_env.reset(seed=0)
    with pytest.raises(error, match=message):
        highway_env.step(action)
    assert highway_env.time == 0.0  # nothing moved
    obs, *_ = highway_env.step(np.array([0.5], dtype=np.float32))  # the env still works
    assert np.isfinite(obs).all()


def test_highway_backend_warns_when_stepping_past_truncation(highway_env):
    highway_env.reset(seed=0)
    for _ in range(2):
        *_, terminated, truncated, _ = highway_env.step(np.zeros(1, dtype=np.float32))
    assert truncated and not terminated
    with pytest.warns(UserWarning, match="already returned truncated = True"):
        highway_env.step(np.zeros(1, dtype=np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        highway_env.step(np.zeros(1, dtype=np.float32))  # once per episode
        highway_env.reset(seed=1)
        highway_env.step(np.zeros(1, dtype=np.float32))


ENV_CONFIG_ERRORS = [
    ({"observation": {"type": "Kinematics", "vehicles_count": "8"}}, r"vehicles_count must be an integer >= 1"),
    ({"observation": {"type": "Kinematics", "vehicles_count": 0}}, r"vehicles_count must be an integer >= 1"),
    ({"observation": {"type": "Kinematics", "features": ["warp"]}}, r"features.*'warp'.*valid: presence"),
    ({"observation": {"type": "Kinematics", "features": "x"}}, r"features must be a non-empty list"),
    ({"observation": {"type": "Kinematics", "features_range": {"x": [5, -5]}}}, r"features_range\['x'\]"),
    ({"observation": {"type": "Kinematics", "order": "random"}}, r"order must be one of"),
    ({"action": {"type": "LongitudinalAcceleration", "acceleration_range": None}},
     r"acceleration_range must be \[a_min < 0, a_max > 0\]"),
    ({"action": {"type": "LongitudinalAcceleration", "acceleration_range": [None, 3]}},
     r"acceleration_range\[0\] must be a finite number"),
    ({"ego_speed": 1e9}, r"ego_speed must be in \[0, 30\] m/s"),
]


@pytest.mark.parametrize("config, message", ENV_CONFIG_ERRORS)
def test_highway_backend_config_errors_name_the_key(config, message):
    pytest.importorskip("highway_env")
    from pirl_sim.envs.roundabout import PirlRoundaboutEnv

    with pytest.raises(ValueError, match=message):
        PirlRoundaboutEnv(config=config)


@pytest.mark.parametrize("config, message", ENV_CONFIG_ERRORS)
def test_sumo_backend_config_errors_name_the_key(config, message):
    pytest.importorskip("libsumo")
    from pirl_sim.envs.sumo_roundabout import PirlRoundaboutSumoEnv

    config = dict(config)
    if "observation" in config and "features" in config["observation"] and config["observation"]["features"] != "x":
        message = r"features.*'warp'.*valid: presence"
    with pytest.raises(ValueError, match=message):
        PirlRoundaboutSumoEnv(config={"backend": "sumo", **config})


def test_sumo_backend_rejects_bad_actions_and_warns_past_truncation():
    gym = pytest.importorskip("gymnasium")
    pytest.importorskip("libsumo")
    import pirl_sim.envs  # noqa: F401

    env = gym.make("pirl_sim/Roundabout-v0", config={"backend": "sumo", "warmup": 4.0, "duration": 0.4}).unwrapped
    try:
        env.reset(seed=0)
        for action, error, message in BAD_ACTIONS:
            with pytest.raises(error, match=message):
                env.step(action)
        assert env.time == 0.0
        for _ in range(2):
            *_, terminated, truncated, _ = env.step(np.zeros(1, dtype=np.float32))
        assert truncated and not terminated
        with pytest.warns(UserWarning, match="already returned truncated = True"):
            env.step(np.zeros(1, dtype=np.float32))
    finally:
        env.close()


# ---------------------------------------------------------------------------------------------- item 14

@pytest.mark.parametrize("ci, outcome", [("true", "failed"), ("", "skipped")])
def test_under_ci_a_missing_extra_fails_instead_of_skipping(tmp_path, ci, outcome):
    (tmp_path / "conftest.py").write_text((Path(__file__).parent / "conftest.py").read_text())
    (tmp_path / "test_extra.py").write_text(
        "import pytest\n"
        "pytest.importorskip('pirl_sim_no_such_extra')\n\n"
        "def test_something():\n    pass\n")
    env = {**os.environ, "CI": ci}
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
                         capture_output=True, text=True, cwd=tmp_path, env=env)
    summary = out.stdout.strip().splitlines()[-1]
    if outcome == "failed":
        assert out.returncode != 0 and "skipped" not in summary, out.stdout
        assert "pirl_sim_no_such_extra" in out.stdout
    else:
        assert out.returncode in (0, 5) and "1 skipped" in summary, out.stdout  # 5: no test ran
