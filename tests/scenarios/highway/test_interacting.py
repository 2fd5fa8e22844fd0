"""Drivers who interact (headway and yielding in their cost) in highway-env: the gaps each driver planned with are the
ones the learner reads from the recording."""

from __future__ import annotations

import dataclasses

import pytest

pytest.importorskip("highway_env")

from pirl_sim.scenarios.highway.scenario import (  # noqa: E402
    HighwayScenarioConfig,
    load_highway_run,
    run_highway_scenario,
)
from pirl_sim.scenarios.population_config import INTERACTING_POPULATION  # noqa: E402

from obstacle_spy import assert_the_learner_reads_the_planned_gaps, planned_obstacles  # noqa: E402


@pytest.mark.slow
def test_the_learner_reads_the_gaps_the_drivers_planned_with(tmp_path):
    pop = dataclasses.replace(INTERACTING_POPULATION, n_vehicles=40, depart_interval=1.5)
    with planned_obstacles() as seen:
        run_highway_scenario(HighwayScenarioConfig(population=pop), 0, out_dir=tmp_path)
    assert_the_learner_reads_the_planned_gaps(load_highway_run(tmp_path), seen, min_compared=3000, min_near=300)
