"""``pirl-sim policy-recovery`` and ``pirl-sim weight-space`` end to end (the agents study: tests/test_agents.py)."""

import pandas as pd
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


def test_weight_space_writes_the_study_it_runs(tmp_path, capsys, monkeypatch):
    import pirl_sim.experiments.weight_space as study

    def tiny_study(seed, say, figures):
        figures["futures.png"] = b"png"
        return pd.DataFrame({"experiment": ["synthetic"], "learner": ["TIRL"], "med": [0.5 + seed]})

    monkeypatch.setattr(study, "run_study", tiny_study)
    out = tmp_path / "ws"
    assert main(["weight-space", "--seed", "2", "--quiet", "--out", str(out)]) == 0
    assert f"wrote {out}/" in capsys.readouterr().out
    assert pd.read_csv(out / "table.csv")["med"].tolist() == [2.5]
    assert (out / "futures.png").read_bytes() == b"png"
    assert "Written by `pirl-sim weight-space --seed 2`" in (out / "README.md").read_text()
    (tmp_path / "a_file").write_text("")
    assert main(["weight-space", "--out", str(tmp_path / "a_file")]) == 2
    assert capsys.readouterr().err.startswith("pirl-sim: error: --out")
