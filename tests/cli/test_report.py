"""``pirl-sim report``: its output directory checked, a truncated table named, and the report of a replay's cells."""

from pathlib import Path

import pandas as pd
import pytest

from pirl_sim.cli import main


REPO = Path(__file__).resolve().parents[2]


def _bad_outputs(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a directory")
    return [(a_file, "is an existing file"), (a_file / "sub", "is not a writable directory"),
            (Path("/proc/pirl_sim_not_writable"), "is not a writable directory")]


def test_report_checks_its_output_directory(tmp_path, capsys):
    results = REPO / "results" / "sweep"
    for out, message in _bad_outputs(tmp_path):
        assert main(["report", str(results), "--out", str(out)]) == 2
        assert message in capsys.readouterr().err


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


def test_report_reads_the_cells_of_a_replay_and_keeps_its_readme(replay_out, capsys):
    from pirl_sim.engine import read_table

    readme = (replay_out / "README.md").read_bytes()
    table = read_table(replay_out)  # no table files: the cells listed in sweep.json
    rows = pd.read_csv(replay_out / "rows.csv").set_index("method")
    assert list(table["learner_label"]) == ["CV (path)", "CA (path)", "TIRL", "CV (x, y)"]
    for _, r in table.iterrows():
        assert r["med"] == pytest.approx(rows.loc[r["learner_label"], "med"], rel=1e-5)
    capsys.readouterr()
    assert main(["report", str(replay_out)]) == 0
    assert f"to {replay_out}/report/" in capsys.readouterr().out
    md = (replay_out / "report" / "README.md").read_text()
    assert "| TIRL |" in md and "| CV (x, y) |" in md and f"the cells stored in {replay_out}/cells/" in md
    assert "numbers are in its cell's file" in md and "`table.csv`" not in md  # a replay writes no table files
    assert (replay_out / "README.md").read_bytes() == readme  # the replay's own README is not overwritten
