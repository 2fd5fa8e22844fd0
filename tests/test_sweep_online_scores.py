"""The sweep's online scores (issue 14): style posterior and K futures per test history in the cells, the
table and the report; the other scores of a cell unchanged by them."""

import tomllib

import numpy as np
import pandas as pd
import pytest

from pirl_sim.evaluation.protocols import Protocol, evaluate
from pirl_sim.learners import PIRLGMM
from pirl_sim.metrics import adjusted_rand_index, match_styles
from pirl_sim.engine import parse_config, run_sweep, write_report
from pirl_sim.engine.worker import ONLINE_FUTURES, ONLINE_SCORES, _data, run_cell, single_threaded
from pirl_sim.engine.run import TABLE_COLUMNS, read_table

TINY_PASSAGE = """
name = "tiny online"
seeds = [1]

[[experiments]]
scenario = "passage"
params = { n_trajectories = 60, n_train = 45 }
protocols = ["paper", { kind = "online", history_steps = 10 }]
learners = [
    "tirl",
    { name = "pirl-gmm", label = "PIRL-GMM in weight space", params = { n_components = 3, space = "weights" } },
]
"""


def _cells():
    cfg = parse_config(tomllib.loads(TINY_PASSAGE), text=TINY_PASSAGE)
    return {(c.protocol["kind"], c.learner_label): c for c in cfg.cells}, cfg


@pytest.fixture(scope="module")
def results():
    cells, _ = _cells()
    with single_threaded():
        return {key: run_cell(c.spec()) for key, c in cells.items()}


def test_online_cells_score_futures_and_other_protocols_do_not(results):
    for (kind, label), res in results.items():
        s = res["scores"]
        assert set(ONLINE_SCORES) <= set(s)
        if kind == "paper":
            assert all(s[c] is None for c in ONLINE_SCORES), label
    tirl = results[("online", "TIRL")]["scores"]
    # one cost, one future: the multi-modal scores are the point prediction's
    assert tirl["k_futures"] == 1
    assert tirl["min_ade"] == pytest.approx(tirl["med"], rel=1e-12)
    assert tirl["min_fde"] == pytest.approx(tirl["fde"], rel=1e-12)
    assert tirl["style_accuracy"] is None and tirl["style_ari"] is None
    gmm = results[("online", "PIRL-GMM in weight space (k=3)")]["scores"]
    assert gmm["k_futures"] == ONLINE_FUTURES
    assert 0.0 <= gmm["miss_rate"] <= 1.0 and np.isfinite(gmm["nll"])
    assert 0.0 <= gmm["style_accuracy"] <= 1.0 and -1.0 <= gmm["style_ari"] <= 1.0


def test_online_scores_match_the_learner_and_leave_the_other_scores_alone(results):
    cells, _ = _cells()
    cell = cells[("online", "PIRL-GMM in weight space (k=3)")]
    spec = cell.spec()
    data = _data(spec)
    protocol = Protocol(**spec["protocol"])
    test = [t for t in data.test if t.n_steps >= protocol.steps_needed()]
    with single_threaded():
        learner = PIRLGMM(model=data.model, **spec["learner_params"], **protocol.learner_params()).fit(data.train)
        plain = evaluate(learner, test, protocol)  # without futures: the scores before issue 14
        futures = evaluate(learner, test, protocol, n_futures=ONLINE_FUTURES, random_state=spec["seed"])
        proba = learner.predict_proba([t.window(0, protocol.history_steps) for t in test])
    s = results[("online", cell.learner_label)]["scores"]
    for name in ("med", "med_std", "fde", "weight_error"):
        assert s[name] == plain[name], name
    for name in ("min_ade", "min_fde", "miss_rate", "nll"):
        assert s[name] == futures[name], name
    truth = np.array([t.metadata["style"] for t in test])
    guess = proba.argmax(axis=1)
    to_true = match_styles(np.array([t.metadata["style"] for t in data.train]), learner.labels_)
    assert s["style_accuracy"] == pytest.approx(np.mean([to_true.get(int(j), -1) == k for j, k in zip(guess, truth)]))
    assert s["style_ari"] == pytest.approx(adjusted_rand_index(truth, guess))


def test_table_and_report_show_the_online_scores(tmp_path):
    _, cfg = _cells()
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
