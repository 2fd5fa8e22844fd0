"""``pirl-sim simulate``: the SUMO backends it offers, its output directory checked before the run, its progress bar."""

import io
from pathlib import Path

import pytest

from pirl_sim.cli import main


def test_sumo_backends_agree_with_the_runner():
    pytest.importorskip("sumolib")
    from pirl_sim.cli.simulate import SUMO_BACKENDS
    from pirl_sim.scenarios.sumo.runner import BACKENDS

    assert SUMO_BACKENDS == BACKENDS


def _bad_outputs(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a directory")
    return [(a_file, "is an existing file"), (a_file / "sub", "is not a writable directory"),
            (Path("/proc/pirl_sim_not_writable"), "is not a writable directory")]


def test_simulate_checks_its_output_directory_before_the_run(tmp_path, capsys):
    pytest.importorskip("highway_env")
    for out, message in _bad_outputs(tmp_path):
        assert main(["simulate", "highway", "--n-vehicles", "2", "--quiet", "--out", str(out)]) == 2
        assert message in capsys.readouterr().err


def test_simulate_progress_bar_counts_vehicles_through_tqdm_in_whole_lines():
    from pirl_sim.cli.simulate import ProgressBar

    out = io.StringIO()
    bar_ = ProgressBar(out, every=0.0)
    for t, n in ((1.0, 0), (2.0, 3), (3.0, 8)):
        bar_(t, n, 8)
    bar_.close()
    lines = out.getvalue().splitlines()
    assert lines and all("\r" not in s and s.startswith("vehicles done:") for s in lines)
    assert "8/8" in lines[-1] and "3.0 s simulated" in lines[-1]
    ProgressBar(out).close()  # never called: nothing to close
