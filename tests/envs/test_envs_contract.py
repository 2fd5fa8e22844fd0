"""``pirl_sim/Roundabout-v0`` runs on the simulator contract: each reset starts its simulation through the backend's
adapter (spied on, not mocked), and every frame is one step of that simulation."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("highway_env")

import pirl_sim.envs  # noqa: E402,F401  (registers the env ids)
from pirl_sim.scenarios.contract import EgoSpec  # noqa: E402

ENV_ID = "pirl_sim/Roundabout-v0"


def spy_on_start(monkeypatch, adapter_type):
    """Record every ``adapter_type.start`` call (keywords and the simulation it returned), and count the steps
    of the simulations it returns; the real start runs."""
    calls, steps = [], []
    real_start = adapter_type.start

    def start(self, config, seed, plan, **kwargs):
        sim = real_start(self, config, seed, plan, **kwargs)
        if not calls:  # the simulation type's step, counted once
            real_step = type(sim).step
            monkeypatch.setattr(type(sim), "step", lambda s: (steps.append(s), real_step(s))[1])
        calls.append({"config": config, "seed": seed, "plan": plan, "sim": sim, **kwargs})
        return sim

    monkeypatch.setattr(adapter_type, "start", start)
    return calls, steps


def test_highway_env_resets_start_the_adapters_simulation_and_steps_step_it(monkeypatch):
    from pirl_sim.scenarios.highway.scenario import HighwayAdapter, HighwayScenarioConfig

    calls, steps = spy_on_start(monkeypatch, HighwayAdapter)
    env = gym.make(ENV_ID, config={"initial_vehicles": 4, "ego_start": 30.0}).unwrapped
    env.reset(seed=3)
    call = calls[-1]
    sim = call["sim"]
    assert isinstance(call["config"], HighwayScenarioConfig) and call["cache_network"]
    assert call["ego"] == EgoSpec("arm0_to_arm2", 8.0, route_s=30.0, vehicle_id="ego")
    assert call["initial_vehicles"] == 4 and call["plan"].equals(HighwayAdapter().plan(call["config"], call["seed"]))
    assert env.road is sim.traffic and env.vehicle is sim.ego_vehicle
    assert env.vehicle.route_s == pytest.approx(30.0)
    del steps[:]
    for k in range(3):
        env.step(np.zeros(1, dtype=np.float32))
        assert len(steps) == 2 * (k + 1) and all(s is sim for s in steps)  # 2 frames per step
    assert env.road.time == pytest.approx(0.6)
    env.close()


def test_sumo_env_resets_start_the_adapters_simulation_and_steps_step_it(monkeypatch):
    pytest.importorskip("libsumo")
    from pirl_sim.scenarios.sumo.scenario import SumoAdapter, SumoScenarioConfig

    calls, steps = spy_on_start(monkeypatch, SumoAdapter)
    env = gym.make(ENV_ID, config={"backend": "sumo", "warmup": 5.0, "ego_speed_mode": 7}).unwrapped
    try:
        assert not calls  # nothing runs before the first reset
        env.reset(seed=3)
        (call,) = calls
        sim = call["sim"]
        assert isinstance(call["config"], SumoScenarioConfig) and call["config"].collision_action == "remove"
        assert call["cache_network"] and call["ego"] == EgoSpec("arm0_to_arm2", 8.0, depart=5.0, speed_mode=7)
        assert call["plan"].equals(SumoAdapter().plan(call["config"], call["seed"]))
        assert env._sim is sim and env._controller is sim.batch_controller
        assert env._controller.drivers is sim.controller  # the agent's wrapper around the scenario's drivers
        assert sim.run.speed_modes == {"ego": 7} and "ego" in sim.run.pirl_ids
        n_warmup = len(steps)
        assert n_warmup >= 50 and all(s is sim for s in steps)  # the warm-up, then the ego's insertion
        env.step(np.zeros(1, dtype=np.float32))
        assert len(steps) == n_warmup + 2
        env.close()
        assert not sim.run.running  # closing the env leaves the simulation
    finally:
        env.close()

