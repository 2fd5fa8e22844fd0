"""``pirl-sim recover``: bad input is a clear error (killed mid-run it resumes: tests/cli/test_resume.py)."""

from __future__ import annotations

import pytest

from pirl_sim.cli import main

pytest.importorskip("highway_env")

def test_bad_recover_input_is_a_clear_error(tmp_path, capsys):
    pop = tmp_path / "pop.toml"
    pop.write_text("n_vehicles = 'many'\n")
    assert main(["recover", "--population", str(pop), "--dry-run", "--out", str(tmp_path / "o")]) == 2
    assert "n_vehicles" in capsys.readouterr().err
    assert main(["recover", "--population", str(tmp_path / "absent.toml"), "--dry-run", "--out", str(tmp_path)]) == 2
    assert "population config not found" in capsys.readouterr().err
