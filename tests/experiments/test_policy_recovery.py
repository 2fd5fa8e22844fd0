"""Policy recovery (pirl_sim.experiments.policy_recovery): the scripted MPC ego of pirl_sim/Roundabout-v0, recorded
with record_tracks, gives back its weights within stated tolerances (pirl_sim.recovery, pirl_sim.testing); bad
settings refused; the engine kind ``policy-recovery``: its cells and a smoke test of them (its figure is
results/policy_recovery, no pass/fail)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pirl_sim.recovery import RecoveryReport
from pirl_sim.testing import assert_recovered, recovery_misses


def _swapped_truth(report: RecoveryReport) -> RecoveryReport:
    """The same fits compared with other tracks' true weights: what a broken pipeline would claim."""
    order = np.roll(np.arange(report.n_tracks), report.n_tracks // 2)
    return RecoveryReport.from_weights(report.true[order], report.estimated, features=report.features,
                                       styles=report.styles, track_ids=report.track_ids)


# ---------------------------------------------------------------------------------------------- (b) MPC ego
#: the MPC ego is exactly rational (no control noise): every episode's weights within 2 % (|log| 0.02)
EGO_TOLERANCES = {"median": {"*": 0.01}, "p90": {"*": 0.02}}


@pytest.fixture(scope="module")
def mpc_ego():
    pytest.importorskip("highway_env")
    from pirl_sim.experiments.policy_recovery import STYLES, mpc_ego_report

    return mpc_ego_report(STYLES, seeds=(0, 1, 2, 3), ego_speeds=(5.0, 8.0, 11.0, 13.0))


@pytest.mark.slow
def test_mpc_ego_weights_are_recovered_from_its_recorded_tracks(mpc_ego):
    rep, episodes = mpc_ego
    assert rep.n_tracks == 8 and set(rep.style_names) == {"tracks desired speed", "minimises acceleration"}
    assert rep.converged.all()
    # the traffic capped some commands: those steps left the likelihood, the rest are the policy's own
    assert all(e["own_steps"] > 0.6 * e["steps"] for e in episodes)
    assert any(e["own_steps"] < e["steps"] for e in episodes)
    assert_recovered(rep, EGO_TOLERANCES, styles="each")
    assert_recovered(rep, {"median": {"*": 0.02}}, bound="high", styles="each")
    # the two policies' weights are told apart: swapping them is far out of tolerance
    misses = recovery_misses(_swapped_truth(rep), EGO_TOLERANCES, styles="each")
    assert {m.style for m in misses} >= {"tracks desired speed", "minimises acceleration"}


def test_policy_recovery_rejects_bad_settings():
    from pirl_sim.experiments.policy_recovery import PpoRecoveryConfig, mpc_ego_demonstrations

    with pytest.raises(ValueError, match="training seeds and evaluation seeds must differ; both have \\[1\\]"):
        PpoRecoveryConfig(seeds=(0, 1), eval_seeds=(1, 2))
    with pytest.raises(ValueError, match="theta must give speed_dev, acc_sq"):
        PpoRecoveryConfig(theta=(("speed_dev", 1.0),))
    with pytest.raises(ValueError, match="steps must be an integer >= 1"):
        PpoRecoveryConfig(steps=0)
    with pytest.raises(ValueError, match="initial_vehicles = 5 exceeds n_vehicles = 3"):
        PpoRecoveryConfig(n_vehicles=3, initial_vehicles=5)
    with pytest.raises(ValueError, match="normalize_reward must be true or false"):
        PpoRecoveryConfig(normalize_reward=1)
    with pytest.raises(ValueError, match="config sets 'policy_frequency'"):
        mpc_ego_demonstrations({"a": {"speed_dev": 1.0, "acc_sq": 1.0}}, [0], config={"policy_frequency": 5})
    with pytest.raises(ValueError, match="ego_speeds must be 1 speeds"):
        mpc_ego_demonstrations({"a": {"speed_dev": 1.0, "acc_sq": 1.0}}, [0], ego_speeds=[1.0, 2.0])
    with pytest.raises(ValueError, match="seeds must be a non-empty list"):
        mpc_ego_demonstrations({"a": {"speed_dev": 1.0, "acc_sq": 1.0}}, [])


# ---------------------------------------------------------------------------------------------- (c) the engine kind
def _config(**changes):
    from pirl_sim.engine.config import parse_config
    from pirl_sim.experiments.policy_recovery import PpoRecoveryConfig

    cfg = PpoRecoveryConfig(**{"seeds": (0,), "steps": 64, "n_steps": 64, "batch_size": 32, "n_epochs": 1,
                               "eval_seeds": (1000,), "duration": 4.0, **changes})
    return cfg, parse_config(cfg.sweep_data())


def test_the_kind_has_a_cell_per_training_seed_and_one_for_the_mpc_ego():
    from pirl_sim.engine.config import parse_config

    _, config = _config(seeds=(3, 4))
    assert [(c.learner, c.seed, c.learner_params.get("random_state")) for c in config.cells] == [
        ("mpc-theta", 0, None), ("ppo-theta", 3, 3), ("ppo-theta", 4, 4)]
    assert dict(config.cells[0].learner_params) == {"eval_seeds": [1000]}  # PPO's settings leave its key alone
    assert config.cells[0].scenario_params["duration"] == 4.0
    exp = {"scenario": "policy-recovery", "learners": [{"name": "ppo-theta", "params": {"eval_seeds": [5, 6]}}]}
    for changes, message in (
            ({"seeds": [6]}, "training seeds and evaluation seeds must differ; both have \\[6\\]"),
            ({"params": {"n_vehicles": 3, "initial_vehicles": 5}}, "initial_vehicles = 5 exceeds n_vehicles = 3"),
            ({"params": {"acc_sq": 0.0}}, "theta must give speed_dev, acc_sq each a finite weight > 0"),
            ({"protocols": [{"kind": "online", "history_steps": 5}]}, 'its one protocol is "paper"'),
            ({"learners": ["mpc"]}, "runs the learners \\['ppo-theta', 'mpc-theta'\\] only")):
        with pytest.raises(ValueError, match=message):
            parse_config({"seeds": [0], "experiments": [{**exp, **changes}]})


@pytest.mark.slow
def test_ppo_recovery_cells_run_end_to_end(tmp_path):
    pytest.importorskip("stable_baselines3")
    from pirl_sim.experiments.policy_recovery import collect_records, run_policy_cells, write_results

    cfg, config = _config()
    records = [record for record, _ in run_policy_cells([c.spec() for c in config.cells])]
    result = collect_records(json.loads(json.dumps(records, sort_keys=True)))  # as the store keeps them
    ppo = result["reports"]["ppo"]
    assert ppo.n_tracks == 1 and ppo.style_names == ("ppo seed 0",)
    assert np.allclose(ppo.true, [[3.0, 0.3]])
    assert list(result["episodes"]["policy"]) == ["mpc", "ppo"]
    assert list(result["episodes"].columns[:3]) == ["policy", "seed", "return"]
    assert list(result["episodes"]["train_seed"]) == [-1, 0]
    files = write_results(result, cfg, tmp_path, "test", 1.0)
    assert "speed_dev" in files["README.md"].read_text() and (tmp_path / "tracks.csv").is_file()
