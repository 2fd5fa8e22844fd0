"""``pirl_sim/Roundabout-v0`` on highway-env (pirl_sim.envs.roundabout): gymnasium's checker, seeded determinism,
config and action checks, rewards, the neighbours' ground truth in ``info``, resets through the simulator
contract, and a stable-baselines3 agent (slow, when SB3 is installed)."""

import warnings

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("highway_env")

from gymnasium.utils.env_checker import check_env, data_equivalence  # noqa: E402

import pirl_sim.envs  # noqa: E402,F401  (registers the env ids)
from pirl_sim.scenarios.contract import EgoSpec  # noqa: E402

from env_checks import BAD_ACTIONS, ENV_CONFIG_ERRORS, spy_on_start  # noqa: E402


ENV_ID = "pirl_sim/Roundabout-v0"
#: warnings check_env may raise on these envs without failing the test: none (it raises none today); add an
#: entry here, with the reason, before tolerating one
TOLERATED_WARNINGS: tuple[str, ...] = ()


def make(**config):
    return gym.make(ENV_ID, config=config or None)


@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
def test_check_env_passes(render_mode):
    env = gym.make(ENV_ID, render_mode=render_mode)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    unexpected = [str(w.message) for w in caught if not any(t in str(w.message) for t in TOLERATED_WARNINGS)]
    assert not unexpected
    if render_mode == "rgb_array":
        env.reset(seed=0)
        frame = env.render()
        assert frame.shape == (600, 600, 3) and frame.dtype == np.uint8
    env.close()


def rollout(env, seed, n=25):
    obs, info = env.reset(seed=seed)
    out = [(obs, info)]
    actions = np.sin(np.arange(n))[:, None].astype(np.float32)
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out.append((obs, reward, terminated, truncated, info))
        if terminated or truncated:
            break
    return out


def test_seeded_resets_are_deterministic():
    a = rollout(make(initial_vehicles=12), seed=11)
    b = rollout(make(initial_vehicles=12), seed=11)
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert data_equivalence(x, y, exact=True)
    c = rollout(make(initial_vehicles=12), seed=12)
    assert not np.array_equal(a[0][0], c[0][0])


@pytest.mark.parametrize("config, match", [
    ({"vehicles_count": 20}, r"config: unknown key\(s\) 'vehicles_count'; valid keys: observation, action"),
    ({"other_vehicles_type": "x"}, r"unknown key\(s\) 'other_vehicles_type'"),
    ({"observation": {"type": "Kinematics", "vehicle_count": 5}},
     r"observation \(Kinematics\): unknown key\(s\) 'vehicle_count'; valid keys: type, features, vehicles_count"),
    ({"observation": {"type": "Pixels"}}, r"observation must be a mapping with a type in"),
    ({"action": {"type": "DiscreteMetaAction"}}, r"action must be \{'type': 'LongitudinalAcceleration'"),
    ({"population": {"n_vehicle": 3}}, r"config population: unknown key\(s\) 'n_vehicle'"),
    ({"drivers": {"horizn": 3}}, r"config drivers: unknown key\(s\) 'horizn'"),
    ({"simulation_frequency": 15}, r"simulation_frequency must be 10 Hz"),
    ({"policy_frequency": 3}, r"policy_frequency must divide 10 Hz"),
    ({"reward": "speed"}, r"reward must be one of \('task', 'theta', 'exit'\)"),
    ({"reward_theta": {"speed_dev": 1.0, "accel": 1.0}}, r"reward_theta: unknown key\(s\) 'accel'"),
    ({"ego_route": "arm0_to_arm0"}, r"ego_route must be one of"),
    ({"initial_vehicles": 1000}, r"initial_vehicles = 1000 exceeds"),
])
def test_bad_config_keys_and_values_are_rejected(config, match):
    with pytest.raises(ValueError, match=match):
        gym.make(ENV_ID, config=config)


def test_bad_keys_in_reset_options_are_rejected_too():
    env = make()
    with pytest.raises(ValueError, match=r"config: unknown key\(s\) 'lanes_count'"):
        env.reset(seed=0, options={"config": {"lanes_count": 2}})
    with pytest.raises(ValueError, match=r"options: unknown key\(s\) 'confg'; valid keys: config"):
        env.reset(seed=0, options={"confg": {}})
    obs, _ = env.reset(seed=0, options={"config": {"initial_vehicles": 0, "population": {"n_vehicles": 1}}})
    assert env.unwrapped.config["population"].n_vehicles == 1


def test_actions_map_to_the_acceleration_range():
    env = make().unwrapped
    env.reset(seed=0)
    act = env.action_type
    assert act.acceleration(np.array([1.0])) == 3.0 and act.acceleration(np.array([-1.0])) == -4.0
    assert act.acceleration(np.array([0.0])) == 0.0 and act.acceleration(np.array([2.0])) == 3.0
    v0 = env.vehicle.speed
    env.step(np.array([0.5], dtype=np.float32))  # 1.5 m/s^2 for 0.2 s
    assert env.vehicle.speed == pytest.approx(v0 + 0.3)


def _default_observation() -> dict:
    from pirl_sim.envs.roundabout import PirlRoundaboutEnv

    return dict(PirlRoundaboutEnv.default_config()["observation"])


@pytest.mark.parametrize("order", ["sorted", "shuffled"])
def test_info_carries_the_neighbours_ground_truth_aligned_with_the_observation(order):
    observation = {**_default_observation(), "order": order}
    env = make(initial_vehicles=15, observation=observation).unwrapped
    obs, info = env.reset(seed=2)
    for _ in range(5):
        obs, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))
    present = obs[1:, 0] > 0  # presence of observation rows 1..V-1
    ids = np.array(info["neighbour_ids"])
    assert ((ids != "") == present).all() and present.sum() >= 3
    plan_theta = {v.vehicle_id: v.theta for v in env.road.vehicles if getattr(v, "kind", "") == "pirl"}
    for vid, is_pirl, style, theta in zip(ids, info["neighbour_is_pirl"], info["neighbour_styles"],
                                          info["neighbour_theta"]):
        if vid == "":
            assert style == -2 and not theta.any()
        elif is_pirl:
            np.testing.assert_array_equal(theta, plan_theta[vid])
            assert 0 <= style < len(info["style_names"])
        else:
            assert style == -1 and not theta.any()
    # the observation's rows are these vehicles, in this order (relative positions)
    by_id = {v.vehicle_id: v for v in env.road.vehicles}
    ego = env.vehicle
    for row, vid in zip(obs[1:][present], ids[present]):
        rel = (by_id[vid].position - ego.position) / 100.0
        np.testing.assert_allclose(row[1:3], np.clip(rel, -1, 1), atol=1e-5)


@pytest.mark.parametrize("overrides", [
    {},  # the env's default
    {"order": "shuffled"},
    {"absolute": True, "see_behind": False, "vehicles_count": 5},
    {"features": ["presence", "x", "vx", "heading", "long_off", "lat_off", "cos_d"], "clip": False},  # to_dict
    {"features_range": None},  # highway-env's default ranges
    {"normalize": False},
])
def test_kinematics_observation_equals_highway_envs(overrides):
    """The env's pandas-free Kinematics observation gives highway-env's KinematicObservation's values, rows
    and (shuffled) permutation on the same states."""
    from highway_env.envs.common.observation import KinematicObservation

    observation = {**_default_observation(), **overrides}
    env = make(initial_vehicles=15, observation=observation).unwrapped
    env.reset(seed=4)
    ours = env.observation_type
    params = {k: v for k, v in observation.items() if k != "type"}
    theirs = KinematicObservation(env, **params)
    for _ in range(6):
        env.step(np.array([0.3], dtype=np.float32))
        state = env.np_random.bit_generator.state
        a = ours.observe()
        env.np_random.bit_generator.state = state  # the same shuffle draw for both
        b = theirs.observe()
        assert a.dtype == b.dtype == np.float32 and a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)


def test_theta_reward_is_minus_the_styles_cost_of_the_egos_step():
    theta = {"speed_dev": 2.0, "acc_sq": 0.5}
    env = make(reward="theta", reward_theta=theta, collision_reward=0.0, arrival_reward=0.0,
               initial_vehicles=0).unwrapped
    env.reset(seed=0)
    for a in (0.5, -0.2, 0.0):
        _, reward, terminated, _, info = env.step(np.array([a], dtype=np.float32))
        f = info["features"]
        assert f.shape == (3,) and (f >= 0).all()
        assert reward == pytest.approx(-(2.0 * f[0] + 0.5 * f[1] + 1.0 * f[2]) * 0.2)
        assert info["rewards"]["style_cost"] == pytest.approx(-reward)
    # the features are the driver model's: acceleration squared of the frames in the step
    env.step(np.array([0.5], dtype=np.float32))
    _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
    assert info["features"][1] == pytest.approx(1.5**2) and info["features"][2] == pytest.approx(0.0)


def test_task_reward_pays_progress_and_ends_on_arrival():
    env = make(initial_vehicles=0, ego_start=250.0, ego_speed=10.0, comfort_reward=0.0).unwrapped
    env.reset(seed=0)
    total, steps = 0.0, 0
    while True:
        _, reward, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        total += reward
        steps += 1
        if terminated or truncated:
            break
    assert terminated and info["arrived"] and not info["crashed"]
    assert env.vehicle.route_s >= env.road.routes["arm0_to_arm2"].length
    progress = env.vehicle.route_s - 250.0  # [m]
    step = 1.0 / env.config["policy_frequency"]  # [s]
    # progress term (1 per step at the speed limit) + arrival reward
    assert total == pytest.approx(progress / (env.config["drivers"].v_max * step) + 1.0)


def test_a_crash_terminates_the_episode_and_the_recording_says_so():
    # the ego never yields: at constant 8 m/s into the ring through dense traffic it hits someone
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, population_from_dict

    pop = population_from_dict({**DEFAULT_POPULATION.to_dict(), "depart_interval": 1.0, "n_vehicles": 60})
    env = make(population=pop, initial_vehicles=25, record_tracks=True, duration=60.0).unwrapped
    crashed = False
    for seed in range(5):
        env.reset(seed=seed)
        while True:
            _, reward, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
            if terminated or truncated:
                break
        if info["crashed"]:
            crashed = True
            break
    assert crashed and terminated and reward <= env.config["collision_reward"] + 1.0
    # in the "theta" reward a crash also costs what the stopped ego would have cost until the time limit
    expected = env.reward_weights[0] * env._ego_cost.v_des**2 * (env.config["duration"] - env.time)
    assert info["rewards"]["crash_cost_to_go"] == pytest.approx(expected) and expected > 0
    rec = env.recording()
    gt = rec.ground_truth.set_index("agent_id")
    assert gt.loc["ego", "collided"] and gt.loc["ego", "style_name"] == "ego" and not gt.loc["ego", "is_pirl"]
    assert gt["collided"].sum() >= 2  # the ego and whoever it hit


@pytest.mark.slow
def test_a_stable_baselines3_ppo_agent_trains_on_the_env():
    sb3 = pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.wrappers.FlattenObservation(make(initial_vehicles=6, duration=20.0))  # for PPO's MLP
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(env, warn=True)
    model = sb3.PPO("MlpPolicy", env, n_steps=256, batch_size=64, n_epochs=2, seed=0, verbose=0, device="cpu")
    # SB3's default logger makes a /tmp/SB3-<date> folder even when it writes nothing: a silent one instead
    model.set_logger(sb3.common.logger.Logger(folder=None, output_formats=[]))
    model.learn(total_timesteps=1024)
    obs, _ = env.reset(seed=123)
    total = 0.0
    for _ in range(50):
        action, _ = model.predict(obs, deterministic=True)
        assert env.action_space.contains(action)
        obs, reward, terminated, truncated, _ = env.step(action)
        total += reward
        if terminated or truncated:
            break
    assert np.isfinite(total)


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


@pytest.fixture(scope="module")
def highway_env():
    gym = pytest.importorskip("gymnasium")
    pytest.importorskip("highway_env")

    env = gym.make("pirl_sim/Roundabout-v0", config={"initial_vehicles": 2, "duration": 0.4}).unwrapped
    yield env
    env.close()


@pytest.mark.parametrize("action, error, message", BAD_ACTIONS)
def test_highway_backend_rejects_bad_actions_and_keeps_working(highway_env, action, error, message):
    highway_env.reset(seed=0)
    with pytest.raises(error, match=message):
        highway_env.step(action)
    assert highway_env.time == 0.0  # nothing moved
    obs, *_ = highway_env.step(np.array([0.5], dtype=np.float32))  # the env still works
    assert np.isfinite(obs).all()


def test_highway_backend_warns_when_stepping_past_truncation(highway_env):
    highway_env.reset(seed=0)
    for _ in range(2):
        *_, terminated, truncated, _ = highway_env.step(np.zeros(1, dtype=np.float32))
    assert truncated and not terminated
    with pytest.warns(UserWarning, match="already returned truncated = True"):
        highway_env.step(np.zeros(1, dtype=np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        highway_env.step(np.zeros(1, dtype=np.float32))  # once per episode
        highway_env.reset(seed=1)
        highway_env.step(np.zeros(1, dtype=np.float32))


@pytest.mark.parametrize("config, message", ENV_CONFIG_ERRORS)
def test_highway_backend_config_errors_name_the_key(config, message):
    pytest.importorskip("highway_env")
    from pirl_sim.envs.roundabout import PirlRoundaboutEnv

    with pytest.raises(ValueError, match=message):
        PirlRoundaboutEnv(config=config)


def test_env_ego_start_beyond_the_route_is_an_error_naming_its_length():
    pytest.importorskip("highway_env")
    from pirl_sim.envs.roundabout import PirlRoundaboutEnv

    with pytest.raises(ValueError, match=r"ego_start must be in \[0, 279.5\] m on route 'arm0_to_arm2' \(its "
                                         r"length 289.5 m less 10 m\), got 1000000.0"):
        PirlRoundaboutEnv(config={"ego_start": 1e6})
