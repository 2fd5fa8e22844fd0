"""The sweep report (pirl_sim.engine.report): figures and summary drawn deterministically, the online scores in the
table and the report."""

from pathlib import Path

import pandas as pd
import pytest

from pirl_sim.engine import run_sweep, write_report
from pirl_sim.engine.run import TABLE_COLUMNS, read_table
from pirl_sim.engine.worker import ONLINE_SCORES

from sweep_configs import passage_cells, sweep_config


# ---------------------------------------------------------------------------------------------- runs
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    return out, run_sweep(sweep_config(), out, workers=0, progress=False)


# ---------------------------------------------------------------------------------------------- report, CLI
def test_report_draws_figures_and_summary_deterministically(tiny_run, tmp_path):
    out, run = tiny_run
    first = write_report(out, tmp_path / "a")
    assert set(first) == {"med_vs_k.png", "learners.png", "recovery.png", "README.md"}
    second = write_report(out, tmp_path / "b")
    for name in first:
        assert Path(first[name]).read_bytes() == Path(second[name]).read_bytes(), name
    md = (tmp_path / "a" / "README.md").read_text()
    assert "| paper | TIRL |" in md and "PIRL-kNN (k=4)" in md
    assert "MED(TIRL) > MED(PIRL-GMM (k=2)) > MED(PIRL-kNN" in md
    assert "![MED vs k](med_vs_k.png)" in md and 'name = "tiny"' in md


def test_table_and_report_show_the_online_scores(tmp_path):
    _, cfg = passage_cells()
    run = run_sweep(cfg, tmp_path / "run", workers=0, progress=False)
    table = run.table
    assert list(table.columns) == list(TABLE_COLUMNS)
    online = table[table["protocol_kind"] == "online"]
    assert online["min_ade"].notna().all() and online["k_futures"].notna().all()
    assert table.loc[table["protocol_kind"] == "paper", list(ONLINE_SCORES)].isna().all().all()
    write_report(tmp_path / "run", tmp_path / "report")
    md = (tmp_path / "report" / "README.md").read_text()
    assert "| protocol | learner | style accuracy | style ARI | minADE_6 [m] |" in md
    gmm = online[online["learner_label"] == "PIRL-GMM in weight space (k=3)"].iloc[0]
    assert f"| online (history 10 steps) | PIRL-GMM in weight space (k=3) | {gmm['style_accuracy']:.3g} |" in md
    # a table written before these scores existed still reads, with empty columns, and reports without them
    old = pd.read_csv(tmp_path / "run" / "table.csv").drop(columns=list(ONLINE_SCORES))
    (tmp_path / "old").mkdir()
    old.to_csv(tmp_path / "old" / "table.csv", index=False)
    back = read_table(tmp_path / "old")
    assert list(back.columns) == list(TABLE_COLUMNS) and back[list(ONLINE_SCORES)].isna().all().all()
    write_report(tmp_path / "old")
    assert "minADE_6" not in (tmp_path / "old" / "README.md").read_text()
