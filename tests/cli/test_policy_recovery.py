"""``pirl-sim policy-recovery``: bad options are clear errors (killed mid-run it resumes: tests/cli/test_resume.py;
the study: tests/experiments/)."""

from __future__ import annotations

import pytest

from pirl_sim.cli import main


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
