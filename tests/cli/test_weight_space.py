"""``pirl-sim weight-space``: ``--dry-run`` counts the cells still to run, and bad options are clear errors (killed
mid-run it resumes: tests/cli/test_resume.py)."""

from __future__ import annotations

import pytest

from pirl_sim.cli import main


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
