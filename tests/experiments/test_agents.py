"""The sweep engine's ``agents`` scenario (`pirl_sim.experiments.agents`): what a config may put where, checked before any
work starts, and one scripted cell run and stored like any sweep cell."""

import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("highway_env")

from pirl_sim.engine.config import parse_config  # noqa: E402


def _config(learners, scenario="agents", protocols=("paper",), params=None):
    return parse_config({"seeds": [0], "experiments": [{"scenario": scenario, "protocols": list(protocols),
                                                        "learners": learners, "params": params or {}}]})


@pytest.mark.parametrize("learners, scenario, protocols, params, match", [
    (["tirl"], "agents", ("paper",), None,
     r"scenario 'agents' runs the learners \['hold-speed', 'idm', 'mpc', 'ppo'\] only, got 'tirl'"),
    (["ppo"], "synthetic", ("paper",), None, r"'ppo' runs in the scenario\(s\) \['agents'\] only, not in 'synthetic'"),
    (["hindsight"], "synthetic", ("paper",), None,
     r"'hindsight' runs in the scenario\(s\) \['recorded', 'replay'\] only, not in 'synthetic'"),
    (["idm"], "agents", ({"kind": "online", "history_steps": 5},), None,
     r"scenario 'agents' runs agents, not predictions: its one protocol is \"paper\", got 'online'"),
    ([{"name": "ppo", "params": {"style_observation": "psychic"}}], "agents", ("paper",), None,
     r"style_observation must be one of \('none', 'truth', 'inferred'\), got 'psychic'"),
    ([{"name": "ppo", "params": {"action": "teleport"}}], "agents", ("paper",), None,
     r"action must be one of \('residual-idm', 'shielded-residual-idm', 'idm-speed', 'direct'\), got 'teleport'"),
    ([{"name": "ppo", "params": {"steps": 0}}], "agents", ("paper",), None, r"steps must be an integer >= 1, got 0"),
    ([{"name": "ppo", "params": {"action": "direct", "observe_residual": True}}], "agents", ("paper",), None,
     r"observe_residual shows the agent what its action changes: it needs a residual or the 'idm-speed' action, "
     r"not 'direct'"),
    ([{"name": "ppo", "params": {"gamma": 0.0}}], "agents", ("paper",), None, r"gamma must be in \(0, 1\], got 0.0"),
    ([{"name": "mpc", "params": {"acc_sq": -1.0}}], "agents", ("paper",), None,
     r"acc_sq must be a finite number > 0, got -1.0"),
    (["idm"], "agents", ("paper",), {"duration": 0.0}, r"duration must be a finite number > 0, got 0.0"),
    (["idm"], "agents", ("paper",), {"eval_episodes": 0}, r"eval_episodes must be an integer >= 1, got 0"),
    (["idm"], "agents", ("paper",), {"reward": "theta"}, r"reward"),
])
def test_bad_agents_configs_are_refused_before_any_work(learners, scenario, protocols, params, match):
    with pytest.raises(ValueError, match=match):
        _config(learners, scenario, protocols, params)


def test_ppo_seed_is_the_cells_and_labels_follow_the_grid():
    cfg = parse_config({"seeds": [3, 4], "experiments": [{"scenario": "agents", "protocols": ["paper"], "learners": [
        {"name": "ppo", "label": "PPO", "grid": {"style_observation": ["none", "truth"]}}]}]})
    assert [(c.learner_label, c.seed, c.learner_params["random_state"]) for c in cfg.cells] == [
        ("PPO (style_observation=none)", 3, 3), ("PPO (style_observation=none)", 4, 4),
        ("PPO (style_observation=truth)", 3, 3), ("PPO (style_observation=truth)", 4, 4)]


def test_a_training_seed_among_the_evaluation_seeds_fails_the_cell():
    from pirl_sim.experiments.agents import run_agent_cells

    cfg = parse_config({"seeds": [1000], "experiments": [{"scenario": "agents", "protocols": ["paper"],
                                                          "learners": ["ppo"]}]})
    with pytest.raises(ValueError, match=r"training seed 1000 is one of the evaluation seeds 1000..1019"):
        run_agent_cells([cfg.cells[0].spec()])


def test_validation_seeds_must_avoid_the_evaluation_and_training_seeds():
    from pirl_sim.experiments.agents import run_agent_cells

    def cell(seed, **params):
        cfg = parse_config({"seeds": [seed], "experiments": [{"scenario": "agents", "protocols": ["paper"],
                                                              "learners": [{"name": "ppo", "params": params}]}]})
        return cfg.cells[0].spec()

    with pytest.raises(ValueError, match=r"training seed 2003 is one of the evaluation seeds 1000..1019 or "
                                         r"validation seeds 2000..2009: use other seeds"):
        run_agent_cells([cell(2003, select_every=64)])
    with pytest.raises(ValueError, match=r"validation seeds 1015..1024 \(select_seed, select_episodes\) overlap the "
                                         r"evaluation seeds 1000..1019: choose another select_seed"):
        run_agent_cells([cell(0, select_every=64, select_seed=1015)])


def test_model_selection_evaluates_the_best_checked_policy():
    """With checks every 64 steps, the evaluated policy is the one of the best check: its evaluation equals that of
    a run trained for the selected number of steps without selection (chunked training is the same training)."""
    pytest.importorskip("stable_baselines3")
    from pirl_sim.experiments.agents import _ppo

    params = {"initial_vehicles": 4, "depart_interval": 4.0, "duration": 10.0, "reward": "exit", "eval_episodes": 2,
              "eval_seed": 1000, "learner_seed": 7}
    lp = {"style_observation": "none", "action": "shielded-residual-idm", "residual_scale": 1.0, "max_change": 0.1,
          "steps": 192, "n_steps": 64, "batch_size": 64, "n_epochs": 2, "gamma": 0.99, "learning_rate": 3e-3,
          "log_std_init": 0.0, "use_sde": False, "observe_residual": True, "select_every": 64, "select_episodes": 2,
          "select_seed": 2000}
    selected = _ppo(params, lp, 0)
    assert [s for s, _ in selected["selection"]] == [64, 128, 192]
    best = max(selected["selection"], key=lambda c: c[1])
    assert selected["selected_steps"] == best[0]
    plain = _ppo(params, {**lp, "steps": best[0], "select_every": None}, 0)
    assert "selection" not in plain
    assert selected["episodes"] == plain["episodes"]
    assert selected["curve"][: len(plain["curve"])] == plain["curve"]


def test_scripted_cell_runs_through_the_sweep_and_is_kept(tmp_path):
    from pirl_sim.engine.executors import InlineExecutor
    from pirl_sim.engine.run import run_sweep

    cfg = _config(["hold-speed"], params={"eval_episodes": 2, "initial_vehicles": 4})
    with InlineExecutor() as ex:
        run = run_sweep(cfg, tmp_path, executor=ex, progress=False, tables=False)
    (key,) = run.keys
    result = run.records[key]["result"]
    assert result["policy"] == "hold-speed" and [e["eval_seed"] for e in result["episodes"]] == [1000, 1001]
    assert all(e["time_to_exit"] is None or e["time_to_exit"] == e["time"] for e in result["episodes"])
    with InlineExecutor() as ex:
        again = run_sweep(cfg, tmp_path, executor=ex, progress=False, tables=False)
    assert again.computed == [] and again.cached == [key]


def test_the_generic_report_leaves_agents_cells_to_their_template(tmp_path, capsys):
    from pirl_sim.cli import main

    agents = """seeds = [0]
[[experiments]]
scenario = "agents"
params = { eval_episodes = 1, initial_vehicles = 4 }
protocols = ["paper"]
learners = ["hold-speed"]
"""
    cfg = tmp_path / "agents.toml"
    cfg.write_text(agents)
    assert main(["sweep", str(cfg), "--out", str(tmp_path / "a"), "--workers", "0", "--report"]) == 2
    assert "every cell is of the 'agents' scenario" in capsys.readouterr().err
    assert (tmp_path / "a" / "table.csv").is_file()  # the finished cells and the table are kept
    cfg.write_text(agents + """
[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 40, n_train = 30, n_steps = 20 }
protocols = ["paper"]
learners = ["tirl"]
""")
    assert main(["sweep", str(cfg), "--out", str(tmp_path / "a"), "--workers", "0", "--report"]) == 0
    readme = (tmp_path / "a" / "README.md").read_text()
    assert "not summarised here: 1 cells of the 'agents' scenario" in readme
