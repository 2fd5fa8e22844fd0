"""``pirl-sim weight-space`` end to end: it writes the study it runs."""

import pandas as pd

from pirl_sim.cli import main


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
