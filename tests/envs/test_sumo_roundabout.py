"""``pirl_sim/Roundabout-v0`` with ``backend="sumo"`` (pirl_sim.envs.sumo_roundabout): checker, determinism, info,
rewards, config and action checks, resets through the simulator contract, libsumo."""

import warnings

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("libsumo")

from gymnasium.utils.env_checker import check_env, data_equivalence  # noqa: E402
from gymnasium.utils.passive_env_checker import env_render_passive_checker  # noqa: E402

import pirl_sim.envs  # noqa: E402,F401  (registers the env ids)
from pirl_sim.scenarios.contract import EgoSpec  # noqa: E402

from env_checks import BAD_ACTIONS, ENV_CONFIG_ERRORS, spy_on_start  # noqa: E402


ENV_ID = "pirl_sim/Roundabout-v0"
FAST = {"backend": "sumo", "warmup": 12.0}  # a shorter warm-up keeps resets quick


def make(**config):
    return gym.make(ENV_ID, config={**FAST, **config})


def test_the_backend_option_picks_the_sumo_env_and_check_env_passes():
    env = make()
    from pirl_sim.envs.sumo_roundabout import PirlRoundaboutSumoEnv

    assert isinstance(env.unwrapped, PirlRoundaboutSumoEnv)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # its render check makes a second env per render mode while this one runs, which libsumo's one
        # simulation per process refuses: the rendering is checked below
        check_env(env.unwrapped, skip_render_check=True)
    assert not [str(w.message) for w in caught]
    env.close()


def rollout(env, seed, n=15):
    out = [env.reset(seed=seed)]
    for a in np.sin(np.arange(n))[:, None].astype(np.float32):
        step = env.step(a)
        out.append(step)
        if step[2] or step[3]:
            break
    return out


def test_seeded_resets_are_deterministic():
    env = make()
    first, second = rollout(env, 3), rollout(env, 3)
    assert data_equivalence(first, second)
    assert not data_equivalence(first[0][0], rollout(env, 4)[0][0])
    env.close()


@pytest.mark.parametrize("order", ["sorted", "shuffled"])
def test_info_names_the_vehicle_of_each_observation_row(order):
    from pirl_sim.envs.sumo_roundabout import PirlRoundaboutSumoEnv

    observation = {**PirlRoundaboutSumoEnv.default_config()["observation"], "order": order}
    env = make(observation=observation).unwrapped
    env.reset(seed=1)
    for _ in range(4):
        obs, _, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
    assert not (terminated or truncated)
    present = obs[1:, 0] > 0
    ids = np.array(info["neighbour_ids"])
    assert ((ids != "") == present).all() and present.sum() >= 2
    ego = env._controller.ego
    states = ego.others
    for row, vid, is_pirl, style, theta in zip(obs[1:], ids, info["neighbour_is_pirl"], info["neighbour_styles"],
                                               info["neighbour_theta"]):
        if vid == "":
            assert style == -2 and not theta.any()
            continue
        rel = np.array([states[vid].x - ego.ego.x, states[vid].y - ego.ego.y]) / 100.0
        np.testing.assert_allclose(row[1:3], np.clip(rel, -1, 1), atol=1e-5)
        who = env._who[vid]
        assert is_pirl == (who.kind == "pirl")
        if is_pirl:
            np.testing.assert_array_equal(theta, who.theta)
            assert 0 <= style < len(info["style_names"])
    env.close()


def test_theta_reward_is_minus_the_styles_cost_and_a_crash_ends_the_episode():
    env = make(reward="theta", reward_theta={"speed_dev": 2.0, "acc_sq": 0.5}, collision_reward=-5.0).unwrapped
    env.reset(seed=2)
    w = np.array([2.0, 0.5, 1.0])
    for _ in range(200):  # full throttle: the ego runs into traffic it does not yield to, or arrives
        obs, reward, terminated, truncated, info = env.step(np.ones(1, dtype=np.float32))
        t = info["rewards"]
        assert t["style_cost"] == pytest.approx(float(w @ info["features"]) * 0.2)
        assert reward == pytest.approx(-5.0 * t["collision"] + t["arrival"] - t["style_cost"]
                                       - t["crash_cost_to_go"])
        if terminated or truncated:
            break
    assert terminated and (info["crashed"] or info["arrived"])
    if info["crashed"]:
        assert info["rewards"]["crash_cost_to_go"] > 0
    env.close()


@pytest.mark.parametrize("config, match", [
    ({"initial_vehicles": 3}, r"unknown key\(s\) 'initial_vehicles'; valid keys: backend"),
    ({"observation": {"type": "OccupancyGrid"}}, r"observes 'Kinematics' only"),
    ({"observation": {"type": "Kinematics", "features": ["x", "lat_off"]}}, r"\['lat_off'\] are not available"),
    ({"record_tracks": 1}, r"record_tracks must be true or false"),
    ({"network": {"radius": -1.0}}, r"config: network: radius"),
    ({"drivers": {"horizn": 3}}, r"drivers: unknown key\(s\) 'horizn'"),
    ({"ego_route": "arm0_to_arm9"}, r"ego_route must be one of arm0_to_arm1"),
    ({"sumo_binding": "pipe"}, r"sumo_binding must be one of"),
    ({"warmup": -2}, r"warmup must be a finite number >= 0"),
])
def test_bad_config_is_rejected_with_what_is_allowed(config, match):
    with pytest.raises(ValueError, match=match):
        make(**config)


def test_recording_holds_the_episode_with_the_ego_and_reads_back(tmp_path):
    from pirl_sim.scenarios.recording import read_recording, write_recording

    env = make(record_tracks=True).unwrapped
    env.reset(seed=2)
    for _ in range(200):  # full throttle until a crash or the end of the route
        _, _, terminated, truncated, info = env.step(np.ones(1, dtype=np.float32))
        if terminated or truncated:
            break
    env.close()  # the recording outlives the run
    rec = env.recording()
    gt = rec.ground_truth.set_index("agent_id")
    assert not gt.loc["ego", "is_pirl"] and gt.loc["ego", "style_name"] == "ego"
    assert gt.loc["ego", "collided"] == info["crashed"]
    pirl = gt[gt["is_pirl"]]
    assert len(pirl) >= 3
    for vid, row in pirl.iterrows():
        np.testing.assert_array_equal(row[["theta_speed_dev", "theta_acc_sq", "theta_jerk_sq"]].to_numpy(float),
                                      env._who[vid].theta)
    write_recording(rec, tmp_path)
    back = read_recording(tmp_path)
    assert len(back.ground_truth) == len(rec.ground_truth) and len(back.tracks) == len(rec.tracks)
    with pytest.raises(ValueError, match="record_tracks=False"):
        make().unwrapped.recording()


def test_unknown_backend_and_render_mode_are_rejected(monkeypatch):
    with pytest.raises(ValueError, match=r"backend must be one of \('highway', 'sumo'\)"):
        gym.make(ENV_ID, config={"backend": "carla"})
    with pytest.raises(ValueError, match=r"render_mode must be None or one of \['rgb_array', 'human'\], got 'ansi'"):
        gym.make(ENV_ID, config=FAST, render_mode="ansi")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match="needs a display"):
        gym.make(ENV_ID, config=FAST, render_mode="human")
    with pytest.raises(ValueError, match="screen_width must be a whole number of pixels >= 16, got 8"):
        make(screen_width=8)
    with pytest.raises(ValueError, match="backend must be 'highway' for this env"):
        gym.make(ENV_ID).unwrapped.configure({"backend": "sumo"})


def test_a_second_libsumo_env_in_one_process_is_refused_and_traci_works_beside_it():
    a = make()
    a.reset(seed=0)
    b = make()
    with pytest.raises(RuntimeError, match="sumo_binding='traci'"):
        b.reset(seed=0)
    c = make(sumo_binding="traci")
    obs_c, _ = c.reset(seed=0)
    obs_a, _ = a.reset(seed=0)
    np.testing.assert_array_equal(obs_a, obs_c)  # the same simulation through either binding
    for env in (a, b, c):
        env.close()


@pytest.mark.slow
def test_stable_baselines3_checks_and_trains_on_the_sumo_backend():
    sb3 = pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.wrappers.FlattenObservation(make())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(env, warn=True)
    model = sb3.PPO("MlpPolicy", env, n_steps=256, batch_size=64, n_epochs=2, seed=0, verbose=0, device="cpu",
                    policy_kwargs={"log_std_init": -1.5})
    # SB3's default logger makes a /tmp/SB3-<date> folder even when it writes nothing: a silent one instead
    model.set_logger(sb3.common.logger.Logger(folder=None, output_formats=[]))
    model.learn(total_timesteps=768)
    obs, _ = env.reset(seed=7)
    for _ in range(30):
        action, _ = model.predict(obs, deterministic=True)
        assert env.action_space.contains(action)
        obs, reward, terminated, truncated, _ = env.step(action)
        assert np.isfinite(reward) and env.observation_space.contains(obs)
        if terminated or truncated:
            break
    env.close()


@pytest.mark.parametrize("config, message", ENV_CONFIG_ERRORS)
def test_sumo_backend_config_errors_name_the_key(config, message):
    pytest.importorskip("libsumo")
    from pirl_sim.envs.sumo_roundabout import PirlRoundaboutSumoEnv

    config = dict(config)
    if "observation" in config and "features" in config["observation"] and config["observation"]["features"] != "x":
        message = r"features.*'warp'.*valid: presence"
    with pytest.raises(ValueError, match=message):
        PirlRoundaboutSumoEnv(config={"backend": "sumo", **config})


def test_sumo_backend_rejects_bad_actions_and_warns_past_truncation():
    gym = pytest.importorskip("gymnasium")
    pytest.importorskip("libsumo")

    env = gym.make("pirl_sim/Roundabout-v0", config={"backend": "sumo", "warmup": 4.0, "duration": 0.4}).unwrapped
    try:
        env.reset(seed=0)
        for action, error, message in BAD_ACTIONS:
            with pytest.raises(error, match=message):
                env.step(action)
        assert env.time == 0.0
        for _ in range(2):
            *_, terminated, truncated, _ = env.step(np.zeros(1, dtype=np.float32))
        assert truncated and not terminated
        with pytest.warns(UserWarning, match="already returned truncated = True"):
            env.step(np.zeros(1, dtype=np.float32))
    finally:
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


def test_rgb_array_frames_draw_each_vehicle_where_it_is_and_change_as_it_moves():
    from pirl_sim.viz import data_to_pixel

    env = gym.make(ENV_ID, config={**FAST, "screen_width": 480, "screen_height": 400}, render_mode="rgb_array")
    env.reset(seed=1)
    first = env.render()
    assert first.shape == (400, 480, 3) and first.dtype == np.uint8
    inner = env.unwrapped
    with pytest.raises(RuntimeError, match="call reset"):
        gym.make(ENV_ID, config=FAST, render_mode="rgb_array").unwrapped.render()
    ids, states = inner._frame
    assert ids[0] == "ego" and len(ids) > 1
    for _ in range(5):
        env.step(np.array([1.0], dtype=np.float32))
    moved = env.render()
    assert np.abs(moved.astype(int) - first).sum(axis=-1).astype(bool).sum() > 20  # vehicles moved
    # the ego's box is red at its projected centre; a PIRL driver's in its style's colour
    ego = inner._frame[1][0]
    col, row = data_to_pixel(inner._view.ax, (ego.x, ego.y)).astype(int)
    near = moved[row - 2 : row + 3, col - 2 : col + 3].reshape(-1, 3)
    assert (np.abs(near.astype(int) - (217, 26, 26)) <= 2).all(axis=1).any(), near
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env_render_passive_checker(inner)  # gymnasium's own check of a render mode's frames
    assert not [str(w.message) for w in caught]
    env.close()
