"""The agents experiment (:mod:`pirl_sim.experiments.agents_study`): config checks, intervals, a tiny end-to-end run that
writes every file, and resuming (finished runs kept, changed settings redone, a torn file redone)."""

import json
import math

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("highway_env")
pytest.importorskip("stable_baselines3")

from pirl_sim.experiments import agents_study as agents  # noqa: E402
from pirl_sim.experiments.agents_study import AgentsConfig  # noqa: E402
from pirl_sim.engine.presets import agents_config, run_agents  # noqa: E402
from pirl_sim.cli import main  # noqa: E402


@pytest.mark.parametrize("kwargs, match", [
    ({"modes": ("none", "oracle")}, r"modes must be distinct values out of \('none', 'truth', 'inferred'\), got "
                                    r"\['none', 'oracle'\]"),
    ({"baselines": ("idm", "idm")}, r"baselines must be distinct values"),
    ({"seeds": ()}, r"seeds must be a non-empty list of distinct integers >= 0, got \[\]"),
    ({"seeds": (0, 1000)}, r"training seeds and evaluation seeds must differ; both have \[1000\]"),
    ({"steps": 0}, r"steps must be an integer >= 1, got 0"),
    ({"gamma": 1.5}, r"gamma must be in \(0, 1\], got 1.5"),
    ({"depart_interval": -1.0}, r"depart_interval must be a finite number > 0, got -1.0"),
    ({"eval_seeds": (1000, 1002)}, r"eval_seeds must be consecutive integers, got \[1000, 1002\]"),
    ({"direct_modes": ("all",)}, r"direct_modes must be distinct values"),
    ({"select_seed": 995, "select_every": 100},
     r"the validation seeds 995..1004 \(select_seed, select_episodes\) must differ from the evaluation and training "
     r"seeds; both have \[1000, 1001, 1002, 1003, 1004\]"),
    ({"select_every": 0}, r"select_every must be an integer >= 1 \(environment steps\) or None, got 0"),
    ({"max_change": -0.1}, r"max_change must be a finite number > 0, got -0.1"),
    ({"residual_scale": 1.0}, r"residual_scale is the largest change of the desired-speed factor with action "
                              r"'idm-speed': it must be in \(0, 1\), got 1.0"),
    ({"action": "steer"}, r"action must be one of \('residual-idm', 'shielded-residual-idm', 'idm-speed', 'direct'\)"),
])
def test_bad_settings_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AgentsConfig(**kwargs)


def test_the_residual_observation_goes_to_the_residual_runs_only():
    for action, scale in (("idm-speed", 0.3), ("shielded-residual-idm", 1.0)):
        cfg = agents_config(AgentsConfig(action=action, observe_residual=True, direct_modes=("none",)))
        seen = {tuple(c.learner_params[k] for k in ("action", "observe_residual", "residual_scale"))
                for c in cfg.cells if c.learner == "ppo"}
        assert seen == {(action, True, scale), ("direct", False, scale)}  # the action's default scale


def test_intervals():
    m, lo, hi = agents._t_interval([1.0, 2.0, 3.0])
    assert m == 2.0 and lo == pytest.approx(2 - 4.302653 / math.sqrt(3)) and hi == pytest.approx(2 + 4.302653 / math.sqrt(3))
    assert np.isnan(agents._t_interval([5.0])[1])
    p, lo, hi = agents._wilson(0, 10)
    assert p == 0 and lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)  # a bound of 0, not a rounding error
    assert agents._wilson(10, 10)[2] == 1.0
    p, lo, hi = agents._wilson(5, 10)
    assert p == 0.5 and lo == pytest.approx(0.2366, abs=1e-4) and hi == pytest.approx(0.7634, abs=1e-4)


def test_paired_difference_uses_the_same_evaluation_seeds():
    rows = [{"policy": "idm", "mode": "", "train_seed": -1, "eval_seed": s, "return": r, "arrived": True,
             "crashed": False, "time": 20.0, "time_to_exit": 20.0, "near_miss_time": 0.0}
            for s, r in ((1, 0.0), (2, 10.0))]
    rows += [{"policy": "ppo (none)", "mode": "none", "train_seed": t, "eval_seed": s, "return": r + d,
              "arrived": True, "crashed": False, "time": 20.0, "time_to_exit": 20.0, "near_miss_time": 0.0}
             for t, d in ((0, 1.0), (1, 3.0)) for s, r in ((1, 0.0), (2, 10.0))]
    table = agents.summary_table(pd.DataFrame(rows)).set_index("policy")
    assert table.loc["ppo (none)", "vs_idm"] == pytest.approx(2.0)  # +2 on both seeds: no spread
    assert table.loc["ppo (none)", "vs_idm_lo"] == pytest.approx(2.0)
    assert table.loc["ppo (none)", "return"] == pytest.approx(7.0)  # mean of the seeds' means 6 and 8
    assert table.loc["idm", "success"] == 1.0 and table.loc["idm", "collision"] == 0.0
    assert table.loc["ppo (none)", "tte_vs_idm"] == pytest.approx(0.0)


def test_paired_time_to_exit_counts_seeds_where_both_arrived():
    def row(policy, train_seed, seed, tte):
        return {"policy": policy, "mode": "", "train_seed": train_seed, "eval_seed": seed, "return": 0.0,
                "arrived": not np.isnan(tte), "crashed": False, "time": 40.0 if np.isnan(tte) else tte,
                "time_to_exit": tte, "near_miss_time": 0.0}

    rows = [row("idm", -1, 1, 30.0), row("idm", -1, 2, np.nan), row("idm", -1, 3, 28.0)]
    rows += [row("ppo", 0, 1, 26.0), row("ppo", 1, 1, 28.0), row("ppo", 0, 2, 25.0), row("ppo", 1, 2, np.nan),
             row("ppo", 0, 3, np.nan), row("ppo", 1, 3, 27.0)]
    table = agents.summary_table(pd.DataFrame(rows)).set_index("policy")
    # seed 1: 27 - 30; seed 2: the IDM did not arrive; seed 3: 27 (the arriving training seed) - 28
    assert table.loc["ppo", "tte_vs_idm"] == pytest.approx(-2.0)
    assert "Δtime to exit vs idm [s]" in agents.markdown_table(table.reset_index())


def test_return_terms_add_up_to_the_return_of_real_episodes():
    """The logged terms, weighted as the exit reward weighs them, give back each episode's return: an IDM
    episode that arrives and a hold-speed episode that crashes (env seeds 1000 and 1004 of the committed
    evaluation, where hold speed arrives and crashes)."""
    import gymnasium as gym

    from pirl_sim.envs.baselines import make_baseline
    from pirl_sim.experiments import agents as cells

    params = {name: p.default for name, p in cells._PARAMS.items()}
    env = gym.make(cells.ENV_ID, config=cells.env_config(params)).unwrapped
    rows = []
    for name, seed in (("idm", 1000), ("hold-speed", 1004)):
        policy = make_baseline(name)
        e = cells.episode(env, lambda obs: policy.act(env), seed, policy.reset)
        rows.append({"policy": name, "mode": "", "train_seed": -1, **e})
    env.close()
    episodes = pd.DataFrame(rows)
    assert list(episodes["arrived"]) == [True, False] and list(episodes["crashed"]) == [False, True]
    terms = agents.terms_table(episodes).set_index("policy")
    assert terms["total"].to_numpy() == pytest.approx(terms["return"].to_numpy(), abs=1e-6)
    assert terms.loc["hold-speed", "collision"] == -50.0 and terms.loc["idm", "arrival"] == 10.0
    assert (terms[["time", "acceleration", "jerk", "lateral", "near miss"]] <= 0).all().all()
    assert "| idm | +" in agents.terms_markdown(terms.reset_index())
    # episodes stored before the terms were logged: no decomposition, no error
    assert agents.terms_table(episodes.drop(columns="comfort_jerk_time")).empty


@pytest.mark.slow
def test_tiny_experiment_writes_everything_and_resumes(tmp_path, capsys, monkeypatch):
    import tempfile

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))  # where SB3's default logger would make SB3-<date>
    import torch

    out = tmp_path / "agents"
    argv = ["agents", "--out", str(out), "--steps", "128", "--n-steps", "64", "--seeds", "0", "--episodes", "1",
            "--modes", "none,truth", "--direct-modes", "", "--baselines", "hold-speed", "--quiet",
            "--select-every", "64", "--select-episodes", "1"]
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        assert main(argv) == 0
        assert torch.get_num_threads() == 2  # training runs on one thread and gives the caller's setting back
    finally:
        torch.set_num_threads(threads)
    for name in ("episodes.csv", "table.csv", "table.md", "terms.csv", "learning_curves.png", "README.md",
                 "sweep.json"):
        assert (out / name).stat().st_size > 0
    cells = sorted((out / "cells").glob("*.json"))
    assert len(cells) == 3  # the sweep engine's store: one file per run
    table = pd.read_csv(out / "table.csv")
    assert list(table["policy"]) == ["hold-speed", "ppo idm-speed (none)", "ppo idm-speed (truth)"]
    episodes = pd.read_csv(out / "episodes.csv")
    assert set(episodes["eval_seed"]) == {1000} and len(episodes) == 3
    for c in cells:  # PPO's runs checked their policy twice on the validation episode and kept the better one
        res = json.loads(c.read_text())["result"]
        if res["policy"].startswith("ppo"):
            assert [s for s, _ in res["selection"]] == [64, 128]
            assert res["selected_steps"] == max(res["selection"], key=lambda c: c[1])[0]
    capsys.readouterr()

    # a rerun keeps every finished run; a torn cell file is redone; other evaluation seeds redo every run
    cfg = AgentsConfig(modes=("none", "truth"), direct_modes=(), seeds=(0,), steps=128, n_steps=64, batch_size=64,
                       eval_seeds=(1000,), baselines=("hold-speed",), select_every=64, select_episodes=1)
    first = run_agents(cfg, out)
    assert first.ran == [] and len(first.skipped) == 3
    torn = next(c for c in cells if '"mode": "none"' in c.read_text() or '"mode":"none"' in c.read_text())
    torn.write_text('{"policy": "pp')
    again = run_agents(cfg, out)
    assert again.ran == ["ppo idm-speed (none) seed 0"]
    assert [r["episodes"] for r in again.records] == [r["episodes"] for r in first.records]  # same seed, same result
    cfg = AgentsConfig(modes=("truth",), direct_modes=("none",), seeds=(0,), steps=128, n_steps=64, batch_size=64,
                       eval_seeds=(1000, 1001), baselines=("hold-speed",), select_every=None)
    result = run_agents(cfg, out)
    assert sorted(result.ran) == ["hold-speed", "ppo direct (none) seed 0", "ppo idm-speed (truth) seed 0"]
    agents.write_results(cfg, result, out, "test")
    table = pd.read_csv(out / "table.csv")
    assert list(table["policy"]) == ["hold-speed", "ppo direct (none)", "ppo idm-speed (truth)"]
    assert not list(scratch.glob("SB3-*"))  # SB3's logger made no folder in the temporary directory


def test_committed_agents_results_match_the_code(capsys):
    """Fails after a change to the agents' cell code (the envs, `pirl_sim.experiments.agents`, the cell code of every
    sweep) until ``pirl-sim agents --out results/agents --workers 2`` is rerun and committed."""
    from pathlib import Path

    results = Path(__file__).resolve().parents[2] / "results" / "agents"
    assert main(["agents", "--out", str(results), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert out.rstrip().endswith(" 0 to run"), out
