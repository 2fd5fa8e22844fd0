"""Drivers who interact (headway and yielding in their cost), in SUMO: the gaps each driver planned with are the ones
the learner reads from the recording, the ground truth holds the interaction weights, and the receding-horizon IRL
gets the headway weight back on the tracks whose data determine it (and fails when the styles' headway weights are
swapped)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("lanelet2")
pytest.importorskip("libsumo")

from pirl_sim.recovery import RecoveryReport, fit_track_weights, run_demonstrations  # noqa: E402
from pirl_sim.scenarios.population_config import INTERACTING_POPULATION  # noqa: E402
from pirl_sim.scenarios.sumo.scenario import SumoScenarioConfig, load_sumo_run, run_sumo_scenario  # noqa: E402
from pirl_sim.testing import assert_recovered  # noqa: E402

from obstacle_spy import assert_the_learner_reads_the_planned_gaps, planned_obstacles  # noqa: E402

#: the example population of drivers who interact (two styles, headway and yielding weights tenfold apart), crowded:
#: 40 vehicles, a departure every 1.5 s on 4 arms
CROWDED = dataclasses.replace(INTERACTING_POPULATION, n_vehicles=40, depart_interval=1.5)
#: stated tolerance on the median |log error| of the headway weight over the tracks that determine it (standard
#: error of its log <= `pirl_sim.experiments.recovery.IDENTIFIED_SE`, enough steps within reach of a vehicle ahead)
HEADWAY_TOLERANCE = {"median": {"headway": 0.1}}


@pytest.fixture(scope="module")
def crowded_run(tmp_path_factory):
    """The run, and what every driver planned with (`obstacle_spy.planned_obstacles`)."""
    out = tmp_path_factory.mktemp("interacting")
    with planned_obstacles() as seen:
        run_sumo_scenario(SumoScenarioConfig(population=CROWDED), 0, out_dir=out)
    return load_sumo_run(out), seen


@pytest.mark.slow
def test_the_learner_reads_the_gaps_the_drivers_planned_with(crowded_run):
    assert_the_learner_reads_the_planned_gaps(*crowded_run, min_compared=3000, min_near=300)


@pytest.mark.slow
def test_headway_weights_come_back_where_the_data_determine_them_and_a_swap_between_styles_fails(crowded_run):
    from pirl_sim.experiments.recovery import IDENTIFIED_SE, MIN_NEAR_STEPS, near_steps

    run, _ = crowded_run
    demos = run_demonstrations(run, 10)
    fits = fit_track_weights(run.model, demos, likelihood="receding", horizon=run.horizon)
    free = ["speed_dev", "acc_sq", "headway"]
    idx = [list(run.model.features.names).index(f) for f in free]
    near = np.array([near_steps(run.model, d, "headway", run.horizon) for d in demos])
    known = np.flatnonzero((fits.log_se[:, idx[2]] <= IDENTIFIED_SE) & (near >= MIN_NEAR_STEPS))
    assert 6 <= len(known) < len(demos)  # some cars never came near a vehicle ahead: their weight stays open
    truth = np.array([demos[i].metadata["theta"] for i in known])
    styles = [demos[i].metadata["style_name"] for i in known]
    report = RecoveryReport.from_weights(truth[:, idx], fits.normalized[known][:, idx], features=free, styles=styles)
    assert_recovered(report, HEADWAY_TOLERANCE)
    assert_recovered(report, {"median": {"speed_dev": 0.05, "acc_sq": 0.05}})
    swapped = truth[:, idx].copy()
    means = {s: np.mean(swapped[np.array(styles) == s, 2]) for s in set(styles)}
    other = {s: [m for t, m in means.items() if t != s][0] for s in means} if len(means) == 2 else None
    assert other is not None, "both styles have tracks that determine their headway weight"
    swapped[:, 2] = [other[s] for s in styles]
    with pytest.raises(AssertionError, match="headway"):
        assert_recovered(RecoveryReport.from_weights(swapped, fits.normalized[known][:, idx], features=free,
                                                     styles=styles),
                         HEADWAY_TOLERANCE)
