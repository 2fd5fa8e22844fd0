"""The evaluation protocols (pirl_sim.evaluation.protocols): the multi-modal scores in `evaluate` only when asked,
and every prediction of the rolling protocol scored."""

import warnings

import numpy as np
import pytest

from pirl_sim.evaluation.protocols import PAPER_PROTOCOL, Protocol, evaluate
from pirl_sim.learners import PIRLKNN


# ---------------------------------------------------------------------------------------------- evaluate
# (the fixtures styles_data and styles_learners: tests/conftest.py)
def test_evaluate_adds_the_scores_only_when_asked(styles_learners, styles_data):
    _, _, test = styles_data
    online = Protocol("online", 10)
    plain = evaluate(styles_learners["gmm-weights"], test, online)
    multi = evaluate(styles_learners["gmm-weights"], test, online, n_futures=6, random_state=0)
    assert "min_ade" not in plain
    for key in ("med", "fde", "weight_error", "n_test"):
        assert multi[key] == plain[key]
    assert multi["k_futures"] == 6
    assert multi["min_ade"] <= multi["med"] and multi["min_fde"] <= multi["fde"] + 1e-12
    assert 0.0 <= multi["miss_rate"] <= 1.0 and np.isfinite(multi["nll"])
    again = evaluate(styles_learners["gmm-weights"], test, online, n_futures=6, random_state=0)
    assert again["min_ade"] == multi["min_ade"] and again["nll"] == multi["nll"]
    # one future: minADE_1 is the MED of the point prediction
    tirl = evaluate(styles_learners["tirl"], test, online, n_futures=6)
    assert tirl["k_futures"] == 1 and tirl["min_ade"] == pytest.approx(tirl["med"], rel=1e-12)
    assert tirl["min_fde"] == pytest.approx(tirl["fde"], rel=1e-12)


def test_evaluate_rolling_scores_every_prediction(styles_data):
    model, train, test = styles_data
    rolling = Protocol("rolling", 10, "sliding", horizon=10, stride=5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        knn = PIRLKNN(model, n_neighbors=10, **rolling.learner_params()).fit(train)
    row = evaluate(knn, test[:10], rolling, n_futures=6, random_state=0)
    assert row["k_futures"] == 6 and row["min_ade"] <= row["med"] + 1e-12
    with pytest.raises(ValueError, match="online or rolling protocol"):
        evaluate(knn, test[:10], PAPER_PROTOCOL, n_futures=6)
    with pytest.raises(ValueError, match="n_futures .* got 0"):
        evaluate(knn, test[:10], rolling, n_futures=0)
    with pytest.raises(ValueError, match="nll_sigma must be .* got -1.0"):
        evaluate(knn, test[:10], rolling, n_futures=6, nll_sigma=-1.0)
