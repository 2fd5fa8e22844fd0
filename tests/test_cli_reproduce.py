import subprocess
import sys

import pandas as pd
import pytest

from pirl_sim.cli import main


def test_reproduce_quick_config_end_to_end_and_byte_identical(tmp_path, capsys):
    args = ["reproduce", "synthetic", "--n-trajectories", "240", "--n-train", "200", "--quiet"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    assert "MED(TIRL) > MED(PIRL-GMM) > MED(PIRL-kNN)" in out
    names = ["table.csv", "table.md", "knn_k.csv", "knn_k.png", "README.md"]
    for n in names:
        assert (tmp_path / "a" / n).read_bytes() == (tmp_path / "b" / n).read_bytes(), n
    table = pd.read_csv(tmp_path / "a" / "table.csv")
    assert set(table["learner"]) == {"TIRL", "PIRL-GMM (k=2)", "PIRL-kNN (k=1)", "PIRL-DPGMM"}
    assert table["med"].notna().all() and (table["med"] >= 0).all()


def test_cli_rejects_bad_arguments(tmp_path, capsys):
    assert main(["reproduce", "synthetic", "--n-trajectories", "10", "--n-train", "10", "--out", str(tmp_path)]) == 2
    assert "n_train must be in" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["reproduce", "highway"])
    with pytest.raises(SystemExit):
        main(["reproduce", "synthetic", "--n-train", "-3"])


def test_console_script_help_lists_every_subcommand():
    out = subprocess.run([sys.executable, "-m", "pirl_sim.cli", "--help"], capture_output=True, text=True, check=True)
    assert "reproduce" in out.stdout
    out = subprocess.run(
        [sys.executable, "-m", "pirl_sim.cli", "reproduce", "--help"], capture_output=True, text=True, check=True
    )
    assert "--history-steps" in out.stdout


def test_reproduce_passage_quick_config(tmp_path, capsys):
    out = tmp_path / "p"
    assert main(["reproduce", "passage", "--n-trajectories", "150", "--n-train", "120", "--quiet", "--out", str(out)]) == 0
    table = pd.read_csv(out / "table.csv")
    assert len(table) == 12 and table["med"].notna().all()
    for name in ("knn_k.png", "clusters.png", "s_t.png", "switch.png", "README.md"):
        assert (out / name).stat().st_size > 0
    assert "crosses half-way after" in (out / "README.md").read_text()
