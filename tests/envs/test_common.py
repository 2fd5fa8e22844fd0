"""What both env backends share (pirl_sim.envs.common): the ego's projection onto its route, the ``"exit"`` task
reward and clearance, and the checks of actions and of the common config (also fuzzed with hypothesis)."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("highway_env")
pytest.importorskip("hypothesis")

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import pirl_sim.envs  # noqa: E402,F401  (registers the env ids)
from pirl_sim.envs.common import EXIT_REWARD_DEFAULTS, VEHICLE_LENGTH, _project_point, clearance  # noqa: E402
from pirl_sim.scenarios.highway.network import (  # noqa: E402
    RoundaboutGeometry,
    build_network,
    route_catalogue,
    route_set,
)


def test_scalar_projection_equals_the_route_sets():
    net = build_network(RoundaboutGeometry(20.0))
    routes = route_set(net, route_catalogue(net))
    rng = np.random.default_rng(0)
    compared = 0
    for r, path in enumerate(routes.paths):
        for _ in range(60):
            s = rng.uniform(-15.0, path.length + 15.0)  # also on the straight extensions
            xy = routes.position(routes.offsets[r] + s, rng.normal(0.0, 1.0))
            guess = s + rng.normal(0.0, 2.0)
            mine = _project_point(path, float(xy[0]), float(xy[1]), guess)
            try:
                theirs = float(routes.project([r], xy[None], [guess])[0])
            except ValueError:
                theirs = None
            assert (mine is None) == (theirs is None)
            if mine is not None:
                assert mine == pytest.approx(theirs, abs=1e-9)
                compared += 1
    assert compared > 100
    assert _project_point(routes.paths[0], 0.0, 0.0, float("nan")) is None


ENV_ID = "pirl_sim/Roundabout-v0"


def make(**config):
    return gym.make(ENV_ID, config={"reward": "exit", **config}).unwrapped


def test_exit_reward_is_its_terms_in_seconds():
    env = make(initial_vehicles=0, population={"n_vehicles": 1, "depart_interval": 1000.0}, ego_start=200.0)
    env.reset(seed=0)
    w = env.config["exit_reward"]
    assert w == EXIT_REWARD_DEFAULTS
    total, arrived, progress_s = 0.0, False, 0.0
    for a in [0.5, 0.5, -0.3, 0.0] * 40:
        _, reward, terminated, truncated, info = env.step(np.array([a], dtype=np.float32))
        t = info["rewards"]
        assert t["time"] == pytest.approx(0.2) and 0.0 <= t["near_miss_time"] <= 0.2
        assert t["comfort_time"] > 0  # the ego accelerates or drives round the ring
        parts = [t["comfort_acc_time"], t["comfort_jerk_time"], t["comfort_lateral_time"]]
        assert min(parts) >= 0 and sum(parts) == pytest.approx(t["comfort_time"])
        expected = (t["progress_time"] - t["time"] - w["comfort"] * t["comfort_time"]
                    - w["near_miss"] * t["near_miss_time"] + w["arrival"] * t["arrival"])
        assert reward == pytest.approx(expected)
        total += reward
        progress_s += t["progress_time"]
        if terminated or truncated:
            arrived = info["arrived"]
            break
    assert arrived and info["time"] == pytest.approx(env.time)
    # progress [s at v_max] adds up to the distance driven / v_max
    assert progress_s == pytest.approx((env.vehicle.route_s - 200.0) / env.config["drivers"].v_max)


def test_clearance_and_near_misses():
    assert clearance([0.0, 0.0], np.zeros((0, 2))) == np.inf
    assert clearance([0.0, 0.0], [[3.0, 4.0], [0.0, 8.0]]) == pytest.approx(5.0 - VEHICLE_LENGTH)
    # an ego following a vehicle 6 m ahead (centre to centre: 1 m bumper to bumper) is in a near miss
    env = make(initial_vehicles=0, population={"n_vehicles": 1, "depart_interval": 1000.0})
    env.reset(seed=0)
    cost = env._ego_cost
    cost.begin_step()
    cost.log_frame(env.vehicle.position, 8.0, 0.0, clearance=1.0)
    cost.log_frame(env.vehicle.position, 8.0, 0.0, clearance=3.0)
    terms = cost.step_terms(progress=1.6, crashed=False, arrived=False, time=0.2)
    assert terms["near_miss_time"] == pytest.approx(0.1)  # one of two 0.1 s frames nearer than 2 m


@pytest.mark.parametrize("value, match", [
    ([1.0], r"exit_reward must be a mapping name -> weight >= 0"),
    ({"colision": 1.0}, r"exit_reward: unknown key\(s\) 'colision'; valid keys: progress, time"),
    ({"collision": -1.0}, r"exit_reward\['collision'\] must be a finite number >= 0, got -1.0"),
    ({"time": "1"}, r"exit_reward\['time'\] must be a finite number"),
])
def test_bad_exit_reward_values_are_rejected(value, match):
    with pytest.raises(ValueError, match=match):
        make(exit_reward=value)


def test_partial_exit_reward_keeps_the_other_defaults():
    env = make(exit_reward={"collision": 80.0})
    assert env.config["exit_reward"] == {**EXIT_REWARD_DEFAULTS, "collision": 80.0}


TOML_SCALAR = st.one_of(st.booleans(), st.integers(-2**40, 2**40), st.floats(allow_nan=True, allow_infinity=True),
                        st.text(max_size=8), st.sampled_from(["full", "weird", "poisson", "regular", "tirl",
                                                              "pirl-gmm", "paper", "online", "synthetic"]))


ACTIONS = st.one_of(
    st.none(), st.booleans(), st.text(max_size=3), st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-10**30, 10**30), st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=3),
    st.lists(st.floats(-5, 5), min_size=1, max_size=1).map(lambda v: np.array(v, dtype=np.float32)),
    st.lists(st.lists(st.floats(-2, 2), max_size=2), max_size=2),
)


@settings(max_examples=200, deadline=None)
@given(action=ACTIONS)
def test_fuzz_env_action_check(action):
    from pirl_sim.envs.common import acceleration, check_action

    try:
        x = check_action(action)
    except (TypeError, ValueError) as exc:
        assert "action must be" in str(exc)
        return
    value = float(np.asarray(action, dtype=float).reshape(-1)[0])
    assert np.isfinite(value) and x == min(max(value, -1.0), 1.0)
    assert -4.0 <= acceleration(action, (-4.0, 3.0)) <= 3.0


ENV_VALUES = st.one_of(TOML_SCALAR, st.none(), st.lists(TOML_SCALAR, max_size=3),
                       st.dictionaries(st.sampled_from(["type", "features", "vehicles_count", "acceleration_range",
                                                        "order", "clip"]), TOML_SCALAR, max_size=3))


@settings(max_examples=80, deadline=None)
@given(key=st.sampled_from(["policy_frequency", "duration", "ego_speed", "reward", "reward_theta", "action",
                            "observation", "progress_reward", "record_tracks", "population"]),
       value=ENV_VALUES)
def test_fuzz_env_common_config(key, value):
    from pirl_sim.envs.common import check_common, check_kinematics, common_defaults

    c = common_defaults()
    c[key] = value
    try:
        check_common(c)
        if key == "observation" and isinstance(value, dict):
            check_kinematics(value, ("presence", "x", "y"), "observation")
    except (TypeError, ValueError) as exc:
        assert str(exc)


def test_check_action_accepts_the_action_space_and_clips():
    from pirl_sim.envs.common import check_action

    assert check_action(np.array([0.25], dtype=np.float32)) == pytest.approx(0.25)
    assert check_action(0.5) == 0.5 and check_action(np.float64(-2.0)) == -1.0 and check_action([3]) == 1.0
