"""The scripted baseline egos (pirl_sim.envs.baselines): argument checks, yielding, their ranking on the evaluation
seeds, and the residual and desired-speed actions."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("highway_env")

import pirl_sim.envs  # noqa: E402,F401  (registers the env ids)
from pirl_sim.envs.baselines import BASELINES, HoldSpeed, IdmEgo, MpcEgo, action_of, make_baseline  # noqa: E402
from pirl_sim.envs.common import EXIT_REWARD_DEFAULTS  # noqa: E402


ENV_ID = "pirl_sim/Roundabout-v0"
#: the dense traffic of the training experiment (pirl_sim.experiments.agents_study)
DENSE = {"initial_vehicles": 12, "population": {"depart_interval": 2.0}}


def make(**config):
    return gym.make(ENV_ID, config={"reward": "exit", **config}).unwrapped


def episode(env, policy, seed):
    env.reset(seed=seed)
    policy.reset(env)
    total = 0.0
    while True:
        _, reward, terminated, truncated, info = env.step(policy.act(env))
        total += reward
        if terminated or truncated:
            return total, info


def test_baseline_arguments_are_checked():
    with pytest.raises(ValueError, match=r"baseline must be one of \('hold-speed', 'idm', 'mpc'\), got 'pid'"):
        make_baseline("pid")
    with pytest.raises(ValueError, match=r"theta needs the weights speed_dev, acc_sq"):
        MpcEgo({"speed_dev": 1.0})
    with pytest.raises(ValueError, match=r"must be finite and > 0"):
        MpcEgo({"speed_dev": 1.0, "acc_sq": 0.0})
    with pytest.raises(TypeError, match=r"theta must be a mapping"):
        MpcEgo([1.0, 1.0])
    with pytest.raises(TypeError, match=r"drives the highway backend's ego"):
        IdmEgo().reset(object())
    assert set(BASELINES) == {"hold-speed", "idm", "mpc"}
    np.testing.assert_array_equal(action_of(1.5, (-4.0, 3.0)), [0.5])
    np.testing.assert_array_equal(action_of(-2.0, (-4.0, 3.0)), [-0.5])
    np.testing.assert_array_equal(action_of(-9.0, (-4.0, 3.0)), [-1.0])


def test_idm_ego_yields_where_holding_speed_crashes():
    """Dense traffic, seed 1004: holding 8 m/s runs into the ring's traffic within 10 s; the IDM ego (yielding
    at the entry) and the MPC ego reach the exit without a crash, and score more."""
    env = make(**DENSE)
    hold, hold_info = episode(env, HoldSpeed(), 1004)
    assert hold_info["crashed"] and hold < -EXIT_REWARD_DEFAULTS["collision"] + 10
    for policy in (IdmEgo(), MpcEgo({"speed_dev": 3.0, "acc_sq": 0.3})):
        ret, info = episode(env, policy, 1004)
        assert info["arrived"] and not info["crashed"] and ret > hold + 20


@pytest.mark.slow
def test_baselines_rank_as_expected_on_the_evaluation_seeds():
    """Over 8 fixed seeds of dense traffic: the yielding egos (IDM, MPC) crash less than holding the speed,
    reach the exit sooner on average when they do, and return more."""
    env = make(**DENSE)
    stats = {}
    for name in BASELINES:
        policy = make_baseline(name)
        rows = [episode(env, policy, seed) for seed in range(1000, 1008)]
        stats[name] = (np.mean([r for r, _ in rows]), sum(i["crashed"] for _, i in rows),
                       np.mean([i["time"] for _, i in rows if i["arrived"]]))
    for name in ("idm", "mpc"):
        assert stats[name][1] < stats["hold-speed"][1]
        assert stats[name][0] > stats["hold-speed"][0] + 5
        assert stats[name][2] < stats["hold-speed"][2]


def test_residual_action_zero_drives_as_the_baseline():
    from pirl_sim.envs.baselines import ResidualAction

    env = ResidualAction(gym.make(ENV_ID, config={"reward": "exit", **DENSE}), "idm", scale=0.5)
    env.reset(seed=1004)
    residual = []
    for _ in range(40):
        _, reward, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        residual.append((reward, info["applied_action"], info["speed"]))
        assert info["applied_action"] == pytest.approx(info["baseline_action"])
        if terminated or truncated:
            break
    plain = make(**DENSE)
    plain.reset(seed=1004)
    idm = IdmEgo()
    idm.reset(plain)
    for reward, applied, speed in residual:
        action = idm.act(plain)
        assert float(action[0]) == pytest.approx(applied)
        _, r, _, _, info = plain.step(action)
        assert r == pytest.approx(reward) and info["speed"] == pytest.approx(speed)
    # +1 moves the action up by the scale (clipped to 1)
    env.reset(seed=1004)
    _, _, _, _, info = env.step(np.ones(1, dtype=np.float32))
    assert info["applied_action"] == pytest.approx(min(info["baseline_action"] + 0.5, 1.0))
    with pytest.raises(ValueError, match=r"scale must be a finite number > 0"):
        ResidualAction(env.env, "idm", scale=0.0)
    with pytest.raises(TypeError, match=r"baseline must be one of"):
        ResidualAction(env.env, baseline=3)
    with pytest.raises(TypeError, match=r"shield must be True or False, got 'yes'"):
        ResidualAction(env.env, "idm", shield="yes")


def test_shielded_residual_never_exceeds_the_traffics_limits():
    """Full throttle under the shield: never above the leader and yielding limit, which binds at times (dense
    traffic), and no crash; without the shield the same actions pass the limit."""
    from pirl_sim.envs.baselines import ResidualAction, action_of, interaction_limit

    env = ResidualAction(gym.make(ENV_ID, config={"reward": "exit", **DENSE}), "idm", scale=1.0, shield=True)
    env.reset(seed=1004)
    base = env.unwrapped
    capped = 0
    for _ in range(150):
        cap = interaction_limit(base)
        _, _, terminated, truncated, info = env.step(np.ones(1, dtype=np.float32))
        if np.isfinite(cap):
            bound = float(action_of(cap, base.action_type.acceleration_range)[0])
            assert info["applied_action"] <= bound + 1e-6
            capped += info["applied_action"] < 1.0 - 1e-6
        assert not info["crashed"]
        if terminated or truncated:
            break
    assert capped > 0, "the limit never bound: the test does not test the shield"


def test_residual_observation_shows_what_the_step_will_apply():
    """``observe=True``: the observation's ``residual`` entry is the baseline's action and the shield's cap the next
    step applies, and the correction in force; the env passes gymnasium's and SB3's checkers; the actions applied
    are those without the observation."""
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    from pirl_sim.envs.baselines import ResidualAction, action_of, interaction_limit

    def residual(observe):
        return ResidualAction(gym.make(ENV_ID, config={"reward": "exit", **DENSE}), "idm", scale=0.5, shield=True,
                              max_change=0.1, observe=observe)

    env = residual(True)
    check_env(env, skip_render_check=True)
    sb3_check_env(gym.wrappers.FlattenObservation(residual(True)))
    assert set(env.observation_space.spaces) == {"kinematics", "residual"}
    obs, _ = env.reset(seed=1004)
    plain = residual(False)
    plain_obs, _ = plain.reset(seed=1004)
    np.testing.assert_array_equal(obs["kinematics"], plain_obs)
    base = env.unwrapped
    capped = 0
    for k in range(80):
        cap = interaction_limit(base)
        bound = float(action_of(cap, base.action_type.acceleration_range)[0]) if np.isfinite(cap) else 1.0
        assert obs["residual"][2] == pytest.approx(bound)
        capped += bound < 1.0
        action = np.array([np.sin(k / 4)], dtype=np.float32)
        shown = obs["residual"][0]
        obs, _, terminated, truncated, info = env.step(action)
        _, _, _, _, plain_info = plain.step(action)
        assert info["baseline_action"] == pytest.approx(shown)
        assert info["applied_action"] == plain_info["applied_action"]
        assert obs["residual"][1] == pytest.approx(env.correction / 0.5)
        if terminated or truncated:
            break
    assert capped > 0, "the cap never bound: the test does not test the cap's column"
    with pytest.raises(TypeError, match=r"observe must be True or False, got 1"):
        ResidualAction(env.env, "idm", observe=1)


def test_desired_speed_action_zero_drives_as_the_idm_ego_and_a_factor_changes_its_target():
    """``DesiredSpeedAction``: action 0 is the IDM ego step for step; +1 drives towards (1 + scale) v_des (faster
    on the free road, the factor moving at most ``max_change`` per step); the observation shows the factor and
    v_des; the env passes gymnasium's and SB3's checkers; bad settings are refused."""
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    from pirl_sim.envs.baselines import DesiredSpeedAction, idm_action

    def wrapped(**kw):
        return DesiredSpeedAction(gym.make(ENV_ID, config={"reward": "exit", **DENSE}), **kw)

    env = wrapped(scale=0.3)
    env.reset(seed=1004)
    plain = make(**DENSE)
    plain.reset(seed=1004)
    idm = IdmEgo()
    idm.reset(plain)
    for _ in range(60):
        expected = idm.act(plain)
        _, reward, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        _, r, _, _, plain_info = plain.step(expected)
        assert info["speed_factor"] == 1.0 and info["applied_action"] == pytest.approx(float(expected[0]))
        assert reward == pytest.approx(r) and info["speed"] == pytest.approx(plain_info["speed"])
        if terminated or truncated:
            break
    # full factor: the IDM towards 1.3 v_des accelerates at least as hard as towards v_des, and ends faster
    fast = wrapped(scale=0.3, max_change=0.05, on_approach=True)
    fast.reset(seed=1004)
    env.reset(seed=1004)
    factors, higher = [], 0
    for _ in range(40):
        slow_info = env.step(np.zeros(1, dtype=np.float32))[4]
        at_v_des = float(idm_action(fast.unwrapped, 1.0)[0])  # the IDM ego's action in the same state
        _, _, terminated, truncated, info = fast.step(np.ones(1, dtype=np.float32))
        factors.append(info["speed_factor"])
        assert info["applied_action"] >= at_v_des - 1e-6
        higher += info["speed"] > slow_info["speed"] + 1e-6
        if terminated or truncated:
            break
    np.testing.assert_allclose(factors[:6], [1.05, 1.1, 1.15, 1.2, 1.25, 1.3])
    assert higher > 0
    # by default the factor applies from the ring on: on the approach the IDM ego's own action
    ring = wrapped(scale=0.3)
    ring.reset(seed=1004)
    phases = set()
    for _ in range(150):
        entering = ring.unwrapped.vehicle.entering
        expected = idm_action(ring.unwrapped, 1.0 if entering else 1.3)
        _, _, terminated, truncated, info = ring.step(np.ones(1, dtype=np.float32))
        assert info["speed_factor"] == pytest.approx(1.3)
        assert info["applied_factor"] == (1.0 if entering else pytest.approx(1.3))
        assert info["applied_action"] == pytest.approx(float(expected[0]))
        phases.add(entering)
        if terminated or truncated:
            break
    assert phases == {True, False}, "the episode never reached the ring: the test does not test the rule"
    obs_env = wrapped(scale=0.3, max_change=0.05, observe=True)
    check_env(obs_env, skip_render_check=True)
    sb3_check_env(gym.wrappers.FlattenObservation(wrapped(scale=0.3, observe=True)))
    obs, _ = obs_env.reset(seed=1004)
    assert set(obs) == {"kinematics", "speed"} and obs["speed"][0] == 0.0
    obs, *_ = obs_env.step(np.ones(1, dtype=np.float32))
    base = obs_env.unwrapped
    assert obs["speed"][0] == pytest.approx(0.05 / 0.3)
    assert obs["speed"][1] == pytest.approx(base.road.v_des(base.vehicle) / base.config["drivers"].v_max)
    for bad in (0.0, 1.0, True, "0.3"):
        with pytest.raises(ValueError, match=r"scale must be a number in \(0, 1\)"):
            wrapped(scale=bad)
    with pytest.raises(ValueError, match=r"max_change must be a finite number > 0"):
        wrapped(max_change=-1.0)
    with pytest.raises(TypeError, match=r"observe must be True or False"):
        wrapped(observe="yes")
    with pytest.raises(TypeError, match=r"on_approach must be True or False, got 1"):
        wrapped(on_approach=1)
