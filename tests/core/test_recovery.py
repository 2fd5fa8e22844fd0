"""pirl_sim.recovery.RecoveryReport on hand-made weights and on synthetic LQ demonstrations of known weights (fast);
recovery from the simulators is tested in tests/experiments/ and tests/scenarios/sumo/."""

import numpy as np
import pytest

from pirl_sim.recovery import RecoveryReport, interval, spearman, statistic, weight_scores
from pirl_sim.testing import assert_recovered, recovery_misses

from recovery_reports import FEATURES, error_report


def test_summary_figures_by_hand():
    err = np.column_stack([np.linspace(0.0, 0.1, 11), -np.linspace(0.0, 0.2, 11)])
    rep = error_report(err, styles=["a"] * 6 + ["b"] * 5, source="hand")
    s = rep.summary().set_index(["feature", "style"])
    assert list(s.index) == [("speed_dev", "all"), ("speed_dev", "a"), ("speed_dev", "b"),
                             ("acc_sq", "all"), ("acc_sq", "a"), ("acc_sq", "b")]
    assert s.loc[("speed_dev", "all"), "median"] == pytest.approx(0.05)
    assert s.loc[("speed_dev", "all"), "p90"] == pytest.approx(0.09)
    assert s.loc[("acc_sq", "all"), "mean"] == pytest.approx(0.1)  # |log error|: the sign is gone
    assert s.loc[("speed_dev", "b"), "median"] == pytest.approx(0.08)  # tracks 7..11: errors 0.06..0.1
    assert s.loc[("speed_dev", "a"), "n"] == 6
    # every interval holds its statistic
    for name in ("median", "p90", "mean"):
        assert (s[f"{name}_low"] <= s[name] + 1e-12).all() and (s[name] <= s[f"{name}_high"] + 1e-12).all()
    # true weights 1..11 all fitted in the same order: Spearman 1; acc_sq's true weights are constant: NaN
    assert s.loc[("speed_dev", "all"), "spearman"] == pytest.approx(1.0)
    assert np.isnan(s.loc[("acc_sq", "all"), "spearman"])
    tracks = rep.per_track()
    assert tracks["log_err_acc_sq"].iloc[-1] == pytest.approx(-0.2) and tracks["style"].iloc[0] == "a"
    assert rep.value("speed_dev", "p90", style="a") == pytest.approx(np.quantile(np.linspace(0, 0.05, 6), 0.9))
    assert "| speed_dev | all | 11 | 0.05 [" in rep.to_markdown()


def test_bootstrap_intervals_are_seeded_and_analytic_ones_cover():
    rng = np.random.default_rng(1)
    err = np.abs(rng.normal(scale=0.1, size=(40, 2)))
    a, b = error_report(err, seed=3).summary(), error_report(err, seed=3).summary()
    assert a.equals(b)
    assert not a.equals(error_report(err, seed=4).summary())  # another seed, other resamples
    # the analytic median interval of 41 draws from N(0, 1) holds the true median 0 in about 95 % of samples
    draws = np.random.default_rng(2).normal(size=(400, 41))
    hits = [lo <= 0.0 <= hi for lo, hi in (interval(d, "median", method="analytic") for d in draws)]
    assert 0.90 <= np.mean(hits) <= 0.99
    hits = [lo <= 0.0 <= hi for lo, hi in (interval(d, "mean", method="analytic") for d in draws)]
    assert 0.90 <= np.mean(hits) <= 0.99
    gen = np.random.default_rng(5)
    hits = [lo <= 0.0 <= hi for lo, hi in (interval(d, "median", rng=gen) for d in draws[:200])]
    assert 0.88 <= np.mean(hits) <= 0.99
    assert np.isnan(interval([0.1], "median", rng=gen)).all()  # one value: no interval
    assert statistic([1.0, 2.0, 3.0, 4.0], "p90") == pytest.approx(3.7)
    assert spearman([1, 2, 3], [3, 2, 1]) == pytest.approx(-1.0) and np.isnan(spearman([1, 2], [1, 2]))


@pytest.mark.parametrize("change, match", [
    ({"true": np.ones((3, 3))}, r"true must have shape \(n, 2\)"),
    ({"estimated": -np.ones((3, 2))}, r"estimated weights must be finite and > 0; 6 are not"),
    ({"true": np.full((3, 2), np.nan)}, r"true weights must be finite"),
    ({"track_ids": np.array([1, 1, 2])}, r"track_ids must be unique"),
    ({"styles": ("a", "b")}, r"styles must be 3 style names"),
    ({"styles": ("a", "all", "b")}, r"style name 'all' is reserved"),
    ({"features": ("speed_dev", "speed_dev")}, r"features must be distinct"),
    ({"features": ("speed_dev", "jerk_sq")}, r"reference feature 'jerk_sq'"),
    ({"method": "jackknife"}, r"method must be one of .*'jackknife'"),
    ({"confidence": 95}, r"confidence must be a number in \(0, 1\)"),
    ({"n_boot": 10}, r"n_boot must be an integer >= 100"),
    ({"converged": np.array([1, 0, 1])}, r"converged must be 3 booleans"),
])
def test_report_checks_itself(change, match):
    fields = dict(features=FEATURES, true=np.ones((3, 2)), estimated=np.ones((3, 2)), track_ids=np.arange(3),
                  styles=("a", "a", "b"))
    fields.update(change)
    with pytest.raises(ValueError, match=match):
        RecoveryReport(**fields)


def test_report_is_frozen_and_read_only():
    rep = error_report(np.full((3, 2), 0.01))
    assert rep.style_names == ("(none)",) and list(rep.summary()["style"]) == ["all", "(none)"] * 2
    with pytest.raises(AttributeError):
        rep.seed = 2
    with pytest.raises(ValueError, match="read-only"):
        rep.estimated[0, 0] = 5.0


def test_from_trajectories_recovers_lq_drivers_of_known_weights():
    from pirl_sim.scenarios.synthetic import SyntheticConfig, generate

    data = generate(SyntheticConfig(n_trajectories=40, n_train=30, rationality=1e4, seed=0))
    rep = RecoveryReport.from_trajectories(data.model, data.train, likelihood="trajectory", source="synthetic")
    assert rep.n_tracks == 30 and rep.features == ("state_sq",) and rep.reference == "control_sq"
    assert rep.converged.all()
    assert_recovered(rep, {"median": {"state_sq": 0.05}, "p90": {"state_sq": 0.15}}, styles="each")
    # recovery cannot be claimed from weights that are not the drivers': other truth, errors far out
    wrong = RecoveryReport.from_trajectories(data.model, data.train, likelihood="trajectory", theta=[2.0, 1.0])
    assert recovery_misses(wrong, {"state_sq": 0.3})
    with pytest.raises(ValueError, match="needs horizon"):
        RecoveryReport.from_trajectories(data.model, data.train, likelihood="receding")
    with pytest.raises(ValueError, match="likelihood must be one of"):
        RecoveryReport.from_trajectories(data.model, data.train, likelihood="open-loop")
    plain = [type(t)(t.states, t.controls, t.dt) for t in data.train[:3]]
    with pytest.raises(ValueError, match=r"metadata\['theta'\]"):
        RecoveryReport.from_trajectories(data.model, plain, likelihood="trajectory")


def test_weight_scores_of_the_sweep():
    from pirl_sim.model import synthetic_model

    model = synthetic_model(0.1)  # state_sq, control_sq (reference)
    true = np.column_stack([np.array([1.0, 2.0, 3.0, 4.0]), np.ones(4)])
    est = true * np.exp(np.array([[0.1, 0], [-0.2, 0], [0.3, 0], [0.0, 0]]))
    rows = weight_scores(est, true, np.array([0, 0, 1, 1]), model, ("one",))
    assert [(r["feature"], r["style"], r["n"]) for r in rows] == [("state_sq", "all", 4), ("state_sq", "one", 2),
                                                                  ("state_sq", "1", 2)]
    # fitted 1.11, 1.64, 4.05, 4.0: ranks 1, 2, 4, 3 -> rho = 1 - 6 * 2 / (4 * 15) = 0.8
    assert rows[0]["median_abs_log_err"] == pytest.approx(0.15) and rows[0]["spearman"] == pytest.approx(0.8)
    assert rows[1]["spearman"] is None  # two rows: no rank correlation
