"""The simulator contract (scenarios/contract.py): both simulators behind one run loop, one observation, one
controller protocol, one ground-truth builder and one step."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from pirl_sim.scenarios.contract import (
    STEP,
    BatchController,
    DriverObservation,
    EgoObservation,
    EgoSpec,
    EgoView,
    VehicleView,
    ground_truth_table,
    run_scenario,
)
from pirl_sim.scenarios.recording import FRAME_DT_S, GROUND_TRUTH_COLUMNS


def _small(config_type, n_vehicles: int):
    cfg = config_type()
    return dataclasses.replace(cfg, population=dataclasses.replace(cfg.population, n_vehicles=n_vehicles))


def test_one_step_everywhere():
    from pirl_sim.envs.common import FRAME_DT
    from pirl_sim.envs.sumo_roundabout import STEP as ENV_STEP
    from pirl_sim.scenarios.highway.traffic import STEP_LENGTH as HIGHWAY_STEP
    from pirl_sim.scenarios.sumo.scenario import STEP_LENGTH as SUMO_STEP

    assert STEP == FRAME_DT_S == 0.1
    assert SUMO_STEP == HIGHWAY_STEP == ENV_STEP == FRAME_DT == STEP


def test_observations_and_controller_follow_the_protocols():
    from pirl_sim.scenarios.drivers import PirlDrivers
    from pirl_sim.scenarios.sumo.runner import VehicleState

    view = EgoView(1.0, 2.0, 3.0, 0.5)
    assert isinstance(view, VehicleView) and isinstance(EgoObservation(view), DriverObservation)
    sumo_state = VehicleState(1.0, 2.0, 1.5, 2.0, 0.0, 3.0, 0.5, 5.0, 1.8, "e", "e_0", 3.0)
    assert isinstance(sumo_state, VehicleView)
    assert not isinstance(object(), VehicleView)
    assert issubclass(PirlDrivers, BatchController)


@pytest.mark.parametrize("simulator", ["sumo", "highway"])
def test_both_simulators_run_through_the_contract(simulator, tmp_path):
    if simulator == "sumo":
        from pirl_sim.scenarios.sumo.scenario import SumoAdapter, SumoScenarioConfig, run_sumo_scenario

        adapter, config, direct = SumoAdapter(), _small(SumoScenarioConfig, 6), run_sumo_scenario
    else:
        from pirl_sim.scenarios.highway.scenario import HighwayAdapter, HighwayScenarioConfig, run_highway_scenario

        adapter, config, direct = HighwayAdapter(), _small(HighwayScenarioConfig, 6), run_highway_scenario
    calls = []
    res = run_scenario(adapter, config, 1, out_dir=tmp_path / "a", progress=lambda *a: calls.append(a))
    direct(config, 1, out_dir=tmp_path / "b")
    for name in ("vehicle_tracks_000.csv", "ground_truth.csv", "driver_steps.csv", "run.json", "*.xml"):
        matches = sorted((tmp_path / "a").rglob(name))
        assert matches or (name == "*.xml" and simulator == "highway"), name
        for path in matches:
            other = tmp_path / "b" / path.relative_to(tmp_path / "a")
            assert path.read_bytes() == other.read_bytes(), path
    info = res.recording.info
    assert info["simulator"] == adapter.name and info["step_length_s"] == STEP and info["seed"] == 1
    assert info["n_vehicles"] == 6 and list(info)[-3:] == ["n_vehicles", "n_not_departed", "sim_time_s"]
    gt = res.recording.ground_truth
    assert list(gt.columns) == list(GROUND_TRUTH_COLUMNS) and gt["interacted"].dtype == "boolean"
    assert gt.loc[~gt["is_pirl"], "interacted"].isna().all()
    assert gt.loc[gt["is_pirl"], "interacted"].notna().all()
    t = res.timing
    assert t["n_steps"] >= 1 and 1 <= t["max_pirl"] <= t["max_vehicles"] and t["mean_pirl"] <= t["mean_vehicles"]
    assert calls and calls[-1][2] == 6 and calls[-1][0] == pytest.approx(info["sim_time_s"])


def test_run_scenario_rejects_another_simulators_config():
    from pirl_sim.scenarios.highway.scenario import HighwayScenarioConfig
    from pirl_sim.scenarios.sumo.scenario import SumoAdapter

    with pytest.raises(TypeError, match="SumoScenarioConfig"):
        run_scenario(SumoAdapter(), HighwayScenarioConfig(), 0)
    with pytest.raises(ValueError, match="backend"):
        SumoAdapter("carla")


def test_ground_truth_table_applies_the_conventions_once():
    gt = ground_truth_table(agent_id=["a", "b"], route_id=["r0", "r1"], is_pirl=[True, False], style=[0, -1],
                            style_name=["calm", "background"], theta=np.array([[1.0, 2.0, 3.0], [np.nan] * 3]),
                            interacted=[True, True], collided=[False, False], removed_early=[False, True],
                            overridden_fraction=[0.25, 0.9], status=["arrived", "arrived"], n_frames=[10, 12])
    assert list(gt.columns) == list(GROUND_TRUTH_COLUMNS)
    assert gt["track_id"].tolist() == [1, 2]
    assert gt["interacted"].iloc[0] is np.True_ or bool(gt["interacted"].iloc[0]) is True
    assert pd.isna(gt["interacted"].iloc[1])  # non-PIRL: NA
    assert gt["overridden_fraction"].iloc[0] == 0.25 and np.isnan(gt["overridden_fraction"].iloc[1])
    with pytest.raises(ValueError, match="one entry per track"):
        ground_truth_table(agent_id=["a"], route_id=["r0", "r1"], is_pirl=[True, False], style=[0, -1],
                           style_name=["x", "y"], theta=np.ones((2, 3)), interacted=[True, True],
                           collided=[False, False], removed_early=[False, False], overridden_fraction=[0, 0],
                           status=["a", "a"], n_frames=[1, 1])


@pytest.mark.parametrize("kwargs, match", [
    ({"route_id": ""}, "ego route_id must be a non-empty string"),
    ({"speed": -1.0}, r"ego speed must be a finite number >= 0"),
    ({"depart": float("nan")}, r"ego depart must be a finite number >= 0"),
    ({"route_s": -5.0}, r"ego route_s must be a finite number >= 0"),
    ({"speed_mode": 128}, r"ego speed_mode must be None or an integer bitset in \[0, 127\]"),
    ({"speed_mode": True}, r"ego speed_mode must be None or an integer bitset"),
    ({"vehicle_id": 3}, "ego vehicle_id must be a non-empty string"),
])
def test_ego_spec_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        EgoSpec(**{"route_id": "arm0_to_arm2", "speed": 8.0, **kwargs})


def test_adapters_reject_ego_settings_their_simulator_cannot_honour():
    from pirl_sim.scenarios.highway.scenario import HighwayAdapter, HighwayScenarioConfig
    from pirl_sim.scenarios.sumo.scenario import SumoAdapter, SumoScenarioConfig

    highway, sumo = _small(HighwayScenarioConfig, 2), _small(SumoScenarioConfig, 2)
    with pytest.raises(ValueError, match="depart must be 0 and speed_mode None"):
        HighwayAdapter().start(highway, 0, HighwayAdapter().plan(highway, 0),
                               ego=EgoSpec("arm0_to_arm2", 8.0, depart=3.0))
    with pytest.raises(ValueError, match="initial_vehicles must be an integer >= 0"):
        HighwayAdapter().start(highway, 0, HighwayAdapter().plan(highway, 0), initial_vehicles=-1)
    with pytest.raises(ValueError, match="route_s must be 0"):
        SumoAdapter().start(sumo, 0, SumoAdapter().plan(sumo, 0), ego=EgoSpec("arm0_to_arm2", 8.0, route_s=20.0))
