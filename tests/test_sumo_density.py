"""Crowded SUMO roundabouts (issue 16 item 1): demand per arm, two-lane rings, drivers counted at once.

Real libsumo runs, each a few simulated minutes of a small population (seconds of wall time)."""

from __future__ import annotations

import dataclasses
import math

import pytest

pytest.importorskip("libsumo")

from pirl_sim.cli import main  # noqa: E402
from pirl_sim.scenarios.population_config import DEFAULT_POPULATION  # noqa: E402
from pirl_sim.scenarios.sumo import SumoScenarioConfig, load_net, run_sumo_scenario, scenario_from_dict  # noqa: E402
from pirl_sim.scenarios.sumo.runner import Observation, _OthersView  # noqa: E402

SEED = 3


def _config(n: int, demand: float | None, lanes: int = 1, **kw) -> SumoScenarioConfig:
    base = SumoScenarioConfig()
    return SumoScenarioConfig(network=dataclasses.replace(base.network, lanes=lanes),
                              population=dataclasses.replace(DEFAULT_POPULATION, n_vehicles=n),
                              demand_per_arm=demand, **kw)


def test_demand_sets_the_departure_interval():
    cfg = _config(10, 600.0)
    assert cfg.population.depart_interval == pytest.approx(3600.0 / (600.0 * 4))  # 1.5 s for 4 arms
    five = SumoScenarioConfig(network=dataclasses.replace(cfg.network, n_arms=5), demand_per_arm=600.0)
    assert five.population.depart_interval == pytest.approx(1.2)
    # --n-vehicles is applied by dataclasses.replace: the demand stays in force
    more = dataclasses.replace(cfg, population=dataclasses.replace(cfg.population, n_vehicles=50, depart_interval=9.0))
    assert more.population.depart_interval == pytest.approx(1.5) and more.population.n_vehicles == 50
    # the plain-data form round-trips
    again = scenario_from_dict(cfg.to_dict())
    assert again == cfg and again.to_dict()["demand_per_arm"] == 600.0


@pytest.mark.parametrize("bad", [0, -100.0, math.inf, math.nan, "600", True])
def test_bad_demand_is_named(bad):
    with pytest.raises(ValueError, match=r"demand_per_arm \[veh/h per arm\] must be a finite number > 0"):
        _config(10, bad)


def test_cli_rejects_bad_density_options(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "sumo", "--demand", "0", "--out", str(tmp_path / "a")])
    assert "--demand: expected a number > 0, got '0'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["simulate", "sumo", "--lanes", "0", "--out", str(tmp_path / "b")])
    assert "--lanes" in capsys.readouterr().err


def test_higher_demand_fills_the_roundabout():
    """Same vehicles, four times the demand: more PIRL drivers in the network at once, counted per step."""
    low = run_sumo_scenario(_config(24, 300.0), SEED)
    high = run_sumo_scenario(_config(24, 1200.0), SEED)
    for res in (low, high):
        t, frame = res.timing, res.sumo.frame
        per_step = frame[frame["pirl"]].groupby("step").size().reindex(range(1, t["n_steps"] + 1), fill_value=0)
        assert t["mean_pirl"] == pytest.approx(per_step.mean())
        assert t["max_pirl"] == per_step.max() <= t["max_vehicles"]
    assert high.timing["mean_pirl"] > 1.5 * low.timing["mean_pirl"]  # 8.1 vs 4.5 (seed 3); drain included
    assert high.timing["sim_time_s"] < low.timing["sim_time_s"]


def test_two_lane_roundabout_runs_and_records(tmp_path):
    """--lanes 2 through the command line: a ring of two lanes, PIRL drivers on it, the run recorded."""
    out = tmp_path / "run"
    assert main(["simulate", "sumo", "--lanes", "2", "--demand", "900", "--n-vehicles", "16", "--seed", str(SEED),
                 "--quiet", "--out", str(out)]) == 0
    net = load_net(out / "network" / "roundabout.net.xml")
    ring = [e for e in net.getEdges() if e.getID().startswith("ring")]
    assert ring and all(e.getLaneNumber() == 2 for e in ring)
    import pandas as pd

    truth = pd.read_csv(out / "ground_truth.csv")
    assert len(truth) == 16 and truth["is_pirl"].sum() > 0
    assert not truth["collided"].any()


def test_observation_views_are_cheap_and_exact():
    states = {"a": 1, "b": 2, "c": 3}
    view = _OthersView(states, "b")
    assert dict(view) == {"a": 1, "c": 3} and len(view) == 2 and "b" not in view and "a" in view
    with pytest.raises(KeyError):
        view["b"]
    calls = []
    obs = Observation(0.0, "b", None, view, leader_fn=lambda: calls.append(1) or ("a", 5.0))
    assert obs.leader == ("a", 5.0) and obs.leader == ("a", 5.0) and calls == [1]  # asked once, on access
    late = Observation(0.0, "b", None, view, leader_fn=lambda: ("a", 5.0))
    late._expire()
    with pytest.raises(RuntimeError, match="during the step only"):
        late.leader
    assert Observation(0.0, "b", None, view, leader=None).leader is None
