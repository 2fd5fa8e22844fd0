"""Style-aware observations of ``pirl_sim/Roundabout-v0`` (:mod:`pirl_sim.envs.styles`): the three modes pass
gymnasium's and SB3's checkers, columns aligned with the rows, online inference near the truth, config checks."""

import warnings

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("highway_env")

import pirl_sim.envs  # noqa: E402,F401  (registers the env ids)
from gymnasium.utils.env_checker import check_env  # noqa: E402
from pirl_sim.envs.styles import LOG_WEIGHT_SCALE, STYLE_OBSERVATIONS, style_columns_of_weights  # noqa: E402

ENV_ID = "pirl_sim/Roundabout-v0"


@pytest.fixture(scope="module")
def learner():
    """PIRL-kNN (receding-horizon IRL, 2 s windows) fitted on a highway-env recording of the default population
    (seed 0: not one of the env seeds below)."""
    from pirl_sim.learners import make_learner
    from pirl_sim.scenarios.highway.scenario import HighwayScenarioConfig, run_highway_scenario
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, population_from_dict

    pop = population_from_dict({**DEFAULT_POPULATION.to_dict(), "n_vehicles": 30})
    run = run_highway_scenario(HighwayScenarioConfig(population=pop), seed=0)
    return make_learner("pirl-knn", model=run.model, n_neighbors=5, window=20, stride=5, likelihood="receding",
                        horizon=30).fit(run.demonstrations(selection="steps"))


def make(mode, learner=None, **config):
    return gym.make(ENV_ID, config={"style_observation": mode, "style_learner": learner, **config})


@pytest.mark.parametrize("mode", STYLE_OBSERVATIONS)
def test_every_mode_passes_gymnasiums_and_sb3s_checkers(mode, learner):
    env = make(mode, learner if mode == "inferred" else None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert not [str(w.message) for w in caught]
    sb3 = pytest.importorskip("stable_baselines3.common.env_checker")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3.check_env(gym.wrappers.FlattenObservation(env), warn=True)
    assert env.observation_space.shape == (8, 7 if mode == "none" else 10)


@pytest.mark.parametrize("order", ["sorted", "shuffled"])
def test_truth_columns_are_the_rows_weights(order):
    from pirl_sim.envs.roundabout import PirlRoundaboutEnv

    observation = {**PirlRoundaboutEnv.default_config()["observation"], "order": order}
    env = make("truth", initial_vehicles=15, observation=observation).unwrapped
    obs, info = env.reset(seed=2)
    for _ in range(5):
        obs, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))
    assert obs.shape == (8, 10) and obs.dtype == np.float32 and not obs[0, 7:].any()
    n_pirl = 0
    for row, is_pirl, theta in zip(obs[1:], info["neighbour_is_pirl"], info["neighbour_theta"]):
        if is_pirl:
            n_pirl += 1
            np.testing.assert_allclose(row[7:], style_columns_of_weights(theta), atol=1e-6)
            np.testing.assert_allclose(np.exp(row[8:] * LOG_WEIGHT_SCALE), theta[:2], rtol=1e-5)
        else:
            assert not row[7:].any()
    assert n_pirl >= 3
    # the kinematic columns are those of mode "none"
    plain = make("none", initial_vehicles=15, observation=observation).unwrapped
    obs0, _ = plain.reset(seed=2)
    for _ in range(5):
        obs0, _, _, _, _ = plain.step(np.zeros(1, dtype=np.float32))
    np.testing.assert_array_equal(obs[:, :7], obs0)


def test_inferred_columns_follow_the_truth_once_a_history_is_seen(learner):
    env = make("inferred", learner, initial_vehicles=15).unwrapped
    obs, _ = env.reset(seed=5)
    assert not obs[:, 7].any()  # nothing observed yet: nothing inferred
    inferred, truth = [], []
    for k in range(60):
        obs, _, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        if k < 10:  # 2 s: 20 frames, the learner's window, plus the two frames that give acceleration and jerk
            assert not obs[:, 7].any()
        for row, is_pirl, theta in zip(obs[1:], info["neighbour_is_pirl"], info["neighbour_theta"]):
            if is_pirl and row[7] == 1:
                inferred.append(row[8:])
                truth.append(style_columns_of_weights(theta)[1:])
        if terminated or truncated:
            break
    inferred, truth = np.array(inferred), np.array(truth)
    assert len(truth) > 50 and env._style.n_inferences >= len(truth)
    # 2 s windows tell the styles apart only partly (the README's online protocol): the inferred ln(theta) is
    # nearer the truth than the best constant guess (the samples' own mean), by at least a third
    error = np.median(np.abs(inferred - truth))
    constant = np.median(np.abs(truth - truth.mean(axis=0)))
    assert error < 0.67 * constant, (error * LOG_WEIGHT_SCALE, constant * LOG_WEIGHT_SCALE)


@pytest.mark.parametrize("config, error, match", [
    ({"style_observation": "oracle"}, ValueError, r"style_observation must be one of \('none', 'truth', 'inferred'\), "
                                                  r"got 'oracle'"),
    ({"style_observation": "inferred"}, ValueError, r"style_observation 'inferred' needs style_learner"),
    ({"style_observation": "inferred", "style_learner": 3}, TypeError, r"style_learner must be a fitted pirl_sim "
                                                                       r"learner, the path of a saved one, or None"),
    ({"style_history": 1}, ValueError, r"style_history must be an integer >= 2 \(frames of 0.1 s\), got 1"),
    ({"style_observation": "truth", "observation": {"type": "TimeToCollision"}}, ValueError,
     r"adds columns to the 'Kinematics' observation; got observation type 'TimeToCollision'"),
])
def test_bad_style_configs_are_rejected(config, error, match):
    with pytest.raises(error, match=match):
        gym.make(ENV_ID, config=config)


def test_unfitted_or_foreign_learners_are_rejected():
    from pirl_sim.learners import make_learner

    with pytest.raises(ValueError, match=r"style_learner PIRLKNN is not fitted"):
        make("inferred", make_learner("pirl-knn"))
    from pirl_sim.learners import TIRL
    from pirl_sim.scenarios.synthetic import SyntheticConfig, generate

    data = generate(SyntheticConfig(n_trajectories=20, n_train=10))
    synthetic = TIRL(model=data.model).fit(data.train)  # the paper's point mass, not the roundabout's routes
    with pytest.raises(ValueError, match=r"style_learner's model must be a RouteSetDriverModel"):
        make("inferred", synthetic)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["none", "truth"])
def test_sumo_backend_observations_pass_the_checkers(mode):
    pytest.importorskip("traci")
    env = gym.make(ENV_ID, config={"backend": "sumo", "style_observation": mode, "sumo_binding": "traci",
                                   "warmup": 5.0, "reward": "exit"})
    check_env(env.unwrapped)
    sb3 = pytest.importorskip("stable_baselines3.common.env_checker")
    sb3.check_env(gym.wrappers.FlattenObservation(env), warn=True)
    obs, info = env.reset(seed=1)
    w = env.unwrapped.config["exit_reward"]
    for _ in range(10):
        obs, reward, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        t = info["rewards"]  # the exit reward on SUMO: the same terms
        assert reward == pytest.approx(t["progress_time"] - t["time"] - w["comfort"] * t["comfort_time"]
                                       - w["near_miss"] * t["near_miss_time"] - w["collision"] * t["collision"]
                                       + w["arrival"] * t["arrival"])
        if terminated or truncated:
            break
    assert obs.shape == env.observation_space.shape and env.observation_space.contains(obs)
    assert info["time"] == pytest.approx(env.unwrapped.time)
    if mode == "truth":
        for row, is_pirl, theta in zip(obs[1:], info["neighbour_is_pirl"], info["neighbour_theta"]):
            expected = style_columns_of_weights(theta) if is_pirl else np.zeros(3)
            np.testing.assert_allclose(row[-3:], expected, atol=1e-6)
    env.close()
