"""The evaluation protocols (pirl_sim.evaluation.protocols): the multi-modal scores in `evaluate` only when asked,
and every prediction of the rolling protocol scored."""

import warnings

import numpy as np
import pytest

from pirl_sim.evaluation.protocols import PAPER_PROTOCOL, Protocol, evaluate
from pirl_sim.learners import PIRLDPGMM, PIRLGMM, PIRLKNN, TIRL
from pirl_sim.model import synthetic_model
from pirl_sim.population import Population, Style, generate_demonstrations


# ---------------------------------------------------------------------------------------------- learners
@pytest.fixture(scope="module")
def styles_data():
    """Boltzmann-rational LQ drivers of three styles (q = 0.1, 1, 10; 10 % spread) from spread starts."""
    model = synthetic_model()
    styles = tuple(Style(name, 1.0, {"state_sq": q}, {"state_sq": 0.1 * q})
                   for name, q in zip(("calm", "normal", "eager"), (0.1, 1.0, 10.0)))
    rng = np.random.default_rng(3)
    n = 200
    x0 = np.column_stack([rng.uniform(2.0, 8.0, n), rng.uniform(-1.0, 1.0, n)])
    demos = generate_demonstrations(model, Population(model.features, styles, 100.0), x0, 30, rng)
    return model, demos[:160], demos[160:]


@pytest.fixture(scope="module")
def fitted(styles_data):
    model, train, _ = styles_data
    common = {"window": 10, "windows": "first"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return {
            "tirl": TIRL(model, **common).fit(train),
            "gmm-weights": PIRLGMM(model, n_components=3, random_state=0, space="weights", **common).fit(train),
            "gmm-features": PIRLGMM(model, n_components=3, random_state=0, **common).fit(train),
            "dpgmm-weights": PIRLDPGMM(model, random_state=0, space="weights", **common).fit(train),
            "knn-likelihood": PIRLKNN(model, n_neighbors=10, weighting="likelihood", **common).fit(train),
            "knn-distance": PIRLKNN(model, n_neighbors=10, **common).fit(train),
        }


# ---------------------------------------------------------------------------------------------- evaluate
def test_evaluate_adds_the_scores_only_when_asked(fitted, styles_data):
    _, _, test = styles_data
    online = Protocol("online", 10)
    plain = evaluate(fitted["gmm-weights"], test, online)
    multi = evaluate(fitted["gmm-weights"], test, online, n_futures=6, random_state=0)
    assert "min_ade" not in plain
    for key in ("med", "fde", "weight_error", "n_test"):
        assert multi[key] == plain[key]
    assert multi["k_futures"] == 6
    assert multi["min_ade"] <= multi["med"] and multi["min_fde"] <= multi["fde"] + 1e-12
    assert 0.0 <= multi["miss_rate"] <= 1.0 and np.isfinite(multi["nll"])
    again = evaluate(fitted["gmm-weights"], test, online, n_futures=6, random_state=0)
    assert again["min_ade"] == multi["min_ade"] and again["nll"] == multi["nll"]
    # one future: minADE_1 is the MED of the point prediction
    tirl = evaluate(fitted["tirl"], test, online, n_futures=6)
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
