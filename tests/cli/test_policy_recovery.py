"""``pirl-sim policy-recovery`` end to end: a tiny run writes its files (the agents study: tests/experiments/)."""

import pytest

from pirl_sim.cli import main


@pytest.mark.slow
def test_policy_recovery_tiny_run_writes_its_files(tmp_path, capsys):
    pytest.importorskip("highway_env")
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "pr"
    assert main(["policy-recovery", "--steps", "64", "--n-steps", "64", "--seeds", "0", "--eval-seeds", "1000",
                 "--n-vehicles", "1", "--initial-vehicles", "0", "--quiet", "--out", str(out)]) == 0
    assert f"wrote {out}/" in capsys.readouterr().out
    for name in ("summary.csv", "summary.md", "tracks.csv", "episodes.csv", "README.md"):
        assert (out / name).stat().st_size > 0, name
    assert "Made by `pirl-sim policy-recovery" in (out / "README.md").read_text()
