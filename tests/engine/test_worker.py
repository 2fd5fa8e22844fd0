"""The cell worker (pirl_sim.engine.worker): online scores (style posterior and K futures) in the cells, cells of
other code refused, BLAS threads limited only while cells run, and a kNN k grid run as one fit."""

import numpy as np
import pytest

from pirl_sim.engine import run_sweep
from pirl_sim.engine.worker import ONLINE_FUTURES, ONLINE_SCORES, _data, run_cell, single_threaded
from pirl_sim.evaluation.protocols import Protocol, evaluate
from pirl_sim.learners import PIRLGMM
from pirl_sim.metrics import adjusted_rand_index, match_styles

from sweep_configs import TINY, passage_cells, sweep_config


@pytest.fixture(scope="module")
def results():
    cells, _ = passage_cells()
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
    cells, _ = passage_cells()
    cell = cells[("online", "PIRL-GMM in weight space (k=3)")]
    spec = cell.spec()
    data = _data(spec)
    protocol = Protocol(**spec["protocol"])
    test = [t for t in data.test if t.n_steps >= protocol.steps_needed()]
    with single_threaded():
        learner = PIRLGMM(model=data.model, **spec["learner_params"], **protocol.learner_params()).fit(data.train)
        plain = evaluate(learner, test, protocol)  # without futures
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


def _threads():
    import os

    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_info

    return {i["filepath"]: i["num_threads"] for i in threadpool_info()}, os.environ.get("OPENBLAS_NUM_THREADS")


_THREADS_AT_START, _OPENBLAS_ENV_AT_START = _threads()


def test_worker_with_other_code_refuses_the_cell():
    from pirl_sim.engine import worker as cell_module

    cell_module._VERSION = None
    cell = sweep_config().cells[0]
    with single_threaded(), pytest.raises(RuntimeError, match="install the same code on every worker"):
        run_cell(cell.spec(), "0.0.0+0000000000000000")


def test_sweep_tests_leave_the_process_multi_threaded():
    """Cells run in this process (inline) limit BLAS threads only while they run."""
    import os

    from threadpoolctl import threadpool_info

    from pirl_sim.engine import worker as cell_module

    now = {i["filepath"]: i["num_threads"] for i in threadpool_info()}
    assert {f: n for f, n in now.items() if f in _THREADS_AT_START} == _THREADS_AT_START
    assert os.environ.get("OPENBLAS_NUM_THREADS") == _OPENBLAS_ENV_AT_START
    assert not cell_module._THREADS_LIMITED


# ---------------------------------------------------------------------------------------------- k-grid
def test_knn_k_grid_runs_as_one_fit_with_each_cells_own_numbers(tmp_path, monkeypatch):
    """PIRL-kNN cells that differ only in k run as one task (one IRL fit, `PIRLKNN.with_neighbors`); every
    cell's stored result equals the cell run on its own, warnings included; a k larger than the training set
    (which the config check rejects) fails alone."""
    from pirl_sim.learners import PIRLKNN
    from pirl_sim.engine.worker import knn_group, run_cells
    from pirl_sim.engine.run import _tasks

    text = TINY.replace("seeds = [0, 1]", "seeds = [0]").replace("n_neighbors = [1, 4]", "n_neighbors = [4, 1]")
    cfg = sweep_config(text)
    knn = [c for c in cfg.cells if c.learner == "pirl-knn" and c.protocol["kind"] == "online"]
    assert [c.k for c in knn] == [4, 1] and len({knn_group(c.spec()) for c in knn}) == 1
    assert knn_group(cfg.cells[0].spec()) is None  # TIRL
    unique = {c.key("v"): c for c in cfg.cells}
    tasks = _tasks(unique, list(unique))
    assert sorted(len(t) for t in tasks) == [1, 1, 1, 1, 2, 2]
    assert [unique[k].k for k in next(t for t in tasks if len(t) == 2)] == [1, 4]

    fits = []
    real_fit = PIRLKNN.fit
    monkeypatch.setattr(PIRLKNN, "fit", lambda self, *a, **kw: fits.append(self.n_neighbors) or real_fit(self, *a, **kw))
    specs = [c.spec() for c in sorted(knn, key=lambda c: c.k)]
    specs.append({**specs[0], "learner_params": {**specs[0]["learner_params"], "n_neighbors": 61}})
    with single_threaded():
        together = run_cells(specs)
        assert fits == [1]
        alone = [run_cell(s) for s in specs[:2]]
    assert together[2] == {"error": "ValueError: n_neighbors=61 is larger than the number of training samples (60)"}
    for a, b in zip(alone, together):
        assert a["scores"] == b["scores"] and a["recovery"] == b["recovery"] and a["weights"] == b["weights"]
        assert a["warnings"] == b["warnings"]
    with pytest.raises(ValueError, match="differ only in n_neighbors"):
        run_cells([cfg.cells[0].spec(), specs[0]])

    run = run_sweep(cfg, tmp_path, workers=0, progress=False)
    assert len(run.computed) == 8 and not run.failed
    table = run.table.set_index("learner_label")
    assert set(table.index) == {"TIRL", "PIRL-GMM (k=2)", "PIRL-kNN (k=1)", "PIRL-kNN (k=4)"}
