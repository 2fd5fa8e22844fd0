"""SUMO roundabout populations end to end: planning, bad input, determinism, flags, files, replay, CLI."""

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("libsumo")
pytest.importorskip("lanelet2")

import libsumo  # noqa: E402

from pirl_sim.io.interaction import read_tracks  # noqa: E402
from pirl_sim.io.lanelet2_map import load_map, match_route  # noqa: E402
from pirl_sim.scenarios.drivers import PirlDrivers  # noqa: E402
from pirl_sim.scenarios.population_config import DEFAULT_POPULATION  # noqa: E402
from pirl_sim.scenarios.recording import GROUND_TRUTH_COLUMNS, read_recording  # noqa: E402
from pirl_sim.scenarios.sumo import (  # noqa: E402
    DEFAULT_NETWORK,
    SumoScenarioConfig,
    load_sumo_run,
    plan_vehicles,
    run_in_subprocess,
    run_sumo_scenario,
    run_to_directory,
    scenario_from_dict,
    speed_mode,
)
from pirl_sim.cli import build_parser, main  # noqa: E402

SMALL = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=16)
FILES = ("vehicle_tracks_000.csv", "ground_truth.csv", "map.osm", "run.json", "network/roundabout.net.xml",
         "driver_steps.csv")


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "a"
    return run_sumo_scenario(SumoScenarioConfig(population=SMALL), seed=3, out_dir=out), out


@pytest.fixture
def no_sumo(monkeypatch):
    """Fail the test if SUMO is started (libsumo or TraCI)."""
    import traci

    def refuse(*args, **kwargs):
        raise AssertionError("SUMO was started")

    monkeypatch.setattr(libsumo, "start", refuse)
    monkeypatch.setattr(traci, "start", refuse)


# ----------------------------------------------------------------------------------------------
# planning and bad input
# ----------------------------------------------------------------------------------------------

def test_plan_is_seeded_and_follows_the_population():
    cfg = SumoScenarioConfig(population=dataclasses.replace(DEFAULT_POPULATION, n_vehicles=300))
    plan = plan_vehicles(cfg, 7)
    pd.testing.assert_frame_equal(plan, plan_vehicles(cfg, 7))
    assert not plan.equals(plan_vehicles(cfg, 8))
    assert (~plan["is_pirl"]).sum() == 60  # round(0.2 * 300)
    bg = plan[~plan["is_pirl"]]
    assert (bg["style"] == -1).all() and bg[["theta_speed_dev", "theta_acc_sq"]].isna().all().all()
    pirl = plan[plan["is_pirl"]]
    assert (pirl["theta_jerk_sq"] == 1.0).all() and (pirl[["theta_speed_dev", "theta_acc_sq"]] > 0).all().all()
    means = pirl.groupby("style_name")["theta_speed_dev"].mean()
    assert means["tracks desired speed"] == pytest.approx(3.0, rel=0.05)
    assert means["minimises acceleration"] == pytest.approx(0.1, rel=0.05)
    assert set(plan["route_id"]) == set(cfg.route_catalogue())
    np.testing.assert_allclose(plan["depart"], 4.0 * np.arange(300))


@pytest.mark.parametrize("data, match", [
    ({"population": {"styles": [{"name": "a", "mean": {"speed_dev": 1.0, "acc_sq": 1.0, "brake_sq": 1.0}}]}},
     r"unknown feature name\(s\) 'brake_sq'"),
    ({"population": {"styles": [{"preset": "reckless"}]}}, "unknown style name 'reckless'"),
    ({"network": {"radius": -25.0}}, "network: radius must be > 0"),
    ({"population": {"styles": [{"name": "a", "mean": {"speed_dev": 1.0, "acc_sq": 1.0},
                                 "cov": {"speed_dev": {"speed_dev": 1.0, "acc_sq": 2.0},
                                         "acc_sq": {"acc_sq": 1.0}}}]}}, "cov must be positive definite"),
    ({"population": {"n_vehicles": 0}}, "n_vehicles must be >= 1"),
    ({"pirl_routes": ["arm0_to_arm7"]}, r"pirl_routes: unknown route\(s\) \['arm0_to_arm7'\]"),
    ({"drivers": {"horizon": 0}}, "drivers.horizon must be an integer >= 1"),
    ({"drivers": {"horizon_s": 3.0}}, r"drivers: unknown key\(s\) 'horizon_s'; valid keys: horizon"),
    ({"speed": 3}, r"unknown key\(s\) 'speed'; valid keys: network, population"),
    ({"collision_action": "explode"}, "collision_action must be one of"),
])
def test_bad_configs_raise_before_anything_runs(data, match, no_sumo):
    with pytest.raises(ValueError, match=match):
        scenario_from_dict(data)


def test_an_unreachable_route_raises_before_sumo_starts(no_sumo):
    cfg = SumoScenarioConfig(population=SMALL, routes={"ok": ("arm0_in", "ring0_1", "arm1_out"),
                                                       "bad": ("arm0_in", "ring1_2", "arm2_out")})
    with pytest.raises(ValueError, match="route 'bad' is unreachable: edge 'arm0_in' does not lead to 'ring1_2'"):
        run_sumo_scenario(cfg, seed=0)
    with pytest.raises(ValueError, match="seed must be an integer"):
        run_sumo_scenario(SumoScenarioConfig(population=SMALL), seed=-1)


# ----------------------------------------------------------------------------------------------
# one small run
# ----------------------------------------------------------------------------------------------

def test_run_writes_every_file_and_they_read_back(small_run):
    res, out = small_run
    for name in FILES:
        assert (out / name).is_file(), name
    tracks = read_tracks(out / "vehicle_tracks_000.csv")
    assert tracks["frame_id"].min() == 1 and (tracks["timestamp_ms"] == 100 * tracks["frame_id"]).all()
    gt = pd.read_csv(out / "ground_truth.csv")
    assert tuple(gt.columns) == GROUND_TRUTH_COLUMNS and len(gt) == 16
    back = read_recording(out)
    pd.testing.assert_frame_equal(back.ground_truth, res.recording.ground_truth)
    info = json.loads((out / "run.json").read_text())
    assert info["seed"] == 3 and info["simulator"] == "sumo" and info["n_not_departed"] == 0
    assert scenario_from_dict(info["config"]) == res.config  # the run can be repeated from run.json


def test_ground_truth_matches_the_plan_and_the_per_step_flags(small_run):
    res, _ = small_run
    gt, plan, frame = res.recording.ground_truth, res.vehicles, res.sumo.frame
    merged = gt.merge(plan, left_on="agent_id", right_on="vehicle_id", suffixes=("", "_plan"))
    for col in ("route_id", "is_pirl", "style", "style_name"):
        assert (merged[col] == merged[f"{col}_plan"]).all(), col
    np.testing.assert_array_equal(merged["theta_speed_dev"], merged["theta_speed_dev_plan"])
    # PIRL steps are commanded and checked, except while SUMO drives a vehicle it stopped (hand-back);
    # interacted = overridden at least once or handed back (no collisions here)
    pirl_rows = frame[frame["pirl"]]
    free = pirl_rows.groupby("vehicle_id")["commanded_speed"].apply(lambda c: bool(c.isna().any()))
    over = pirl_rows.groupby("vehicle_id")["overridden"].apply(lambda s: bool(s.fillna(False).any()))
    p = gt[gt["is_pirl"]].set_index("agent_id")
    assert (p["interacted"].astype(bool) == (over | free).reindex(p.index)).all()
    assert not (free & ~over).any()  # a hand-back follows an override (SUMO stopped the vehicle)
    assert gt.loc[~gt["is_pirl"], "interacted"].isna().all()
    assert (gt["status"] == "arrived").all() and not gt["collided"].any()
    assert 0 < (~p["interacted"].astype(bool)).sum() < len(p)  # some clean, some interacting tracks


def test_recorded_tracks_follow_the_map(small_run):
    res, out = small_run
    lmap = load_map(out / "map.osm")
    tracks = res.recording.tracks
    for tid in res.recording.pirl_track_ids[:4]:
        g = tracks[tracks["track_id"] == tid].sort_values("time_s")
        m = match_route(lmap, g[["x", "y"]].to_numpy(), psi=g["psi_rad"].to_numpy())
        assert m.fraction_within == 1.0
        assert np.percentile(m.offsets, 95) < 0.5  # [m] box centres on the lane centre lines


def test_replay_from_disk_gives_the_same_demonstrations(small_run):
    res, out = small_run
    mem = res.demonstrations()
    disk = load_sumo_run(out).demonstrations()
    assert len(mem) == len(disk) > 0
    for a, b in zip(mem, disk):
        assert a.metadata["track_id"] == b.metadata["track_id"]
        np.testing.assert_allclose(a.states, b.states, atol=1e-6)
        assert a.metadata["style"] == b.metadata["style"] and not a.metadata["interacted"]
    # the demonstrations are the drivers' own speeds: compare with SUMO's recorded speed
    d = mem[0]
    f = res.sumo.frame
    speed = f[f["vehicle_id"] == d.metadata["agent_id"]]["speed"].to_numpy()
    assert np.abs(d.states[5:-5, 1] - speed[5:-5]).max() < 0.1


# ----------------------------------------------------------------------------------------------
# determinism
# ----------------------------------------------------------------------------------------------

def test_same_seed_byte_identical_files_different_seed_different(small_run, tmp_path):
    _, first = small_run
    run_sumo_scenario(SumoScenarioConfig(population=SMALL), seed=3, out_dir=tmp_path / "b")
    run_sumo_scenario(SumoScenarioConfig(population=SMALL), seed=4, out_dir=tmp_path / "c")
    for name in FILES:
        assert (first / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    for name in ("vehicle_tracks_000.csv", "ground_truth.csv", "run.json"):
        assert (first / name).read_bytes() != (tmp_path / "c" / name).read_bytes(), name


def test_traci_backend_writes_the_same_tracks(tmp_path):
    cfg = SumoScenarioConfig(population=dataclasses.replace(DEFAULT_POPULATION, n_vehicles=6))
    run_sumo_scenario(cfg, seed=1, out_dir=tmp_path / "lib")
    run_sumo_scenario(cfg, seed=1, out_dir=tmp_path / "traci", backend="traci")
    for name in ("vehicle_tracks_000.csv", "ground_truth.csv", "map.osm"):
        assert (tmp_path / "lib" / name).read_bytes() == (tmp_path / "traci" / name).read_bytes(), name


# ----------------------------------------------------------------------------------------------
# collisions, removals, crashes
# ----------------------------------------------------------------------------------------------

def test_collided_vehicles_are_removed_their_tracks_end_cleanly_and_are_flagged(tmp_path):
    # PIRL drivers that ignore leaders and right of way, in dense traffic: collisions, removed by SUMO
    pop = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=24, depart_interval=1.0)
    cfg = SumoScenarioConfig(population=pop, speed_mode=speed_mode(safe_speed=False, right_of_way=False),
                             collision_action="remove", max_duration=120.0)
    res = run_sumo_scenario(cfg, seed=0, out_dir=tmp_path)
    gt = res.recording.ground_truth
    hit = gt[gt["collided"]]
    assert len(hit) >= 2
    assert hit["removed_early"].all() and (hit["status"] == "vanished").all()
    assert hit.loc[hit["is_pirl"], "interacted"].astype(bool).all()
    tracks = read_tracks(tmp_path / "vehicle_tracks_000.csv")
    summary = res.sumo.summary.set_index("vehicle_id")
    for row in hit.itertuples():
        frames = tracks.loc[tracks["track_id"] == row.track_id, "frame_id"].to_numpy()
        assert np.all(np.diff(frames) == 1) and len(frames) == row.n_frames  # contiguous, no gap
        assert frames[-1] == round(summary.loc[row.agent_id, "last_time"] * 10)  # ends where SUMO removed it
        last = res.sumo.frame[res.sumo.frame["vehicle_id"] == row.agent_id].iloc[-1]
        assert last["collided"] and last["vanished"]
    assert not res.demonstrations(pirl_only=False, non_interacting=True, min_steps=1) or all(
        not d.metadata["interacted"] for d in res.demonstrations())


def test_a_crash_mid_run_writes_nothing_and_frees_libsumo(tmp_path, monkeypatch):
    original = PirlDrivers.commands

    def crash(self, time, observations):
        if time > 5.0:
            raise RuntimeError("simulated crash in a driver")
        return original(self, time, observations)

    monkeypatch.setattr(PirlDrivers, "commands", crash)
    out = tmp_path / "run"
    with pytest.raises(RuntimeError, match="simulated crash"):
        run_sumo_scenario(SumoScenarioConfig(population=SMALL), seed=0, out_dir=out)
    assert not out.exists() or not any(out.rglob("*"))
    monkeypatch.setattr(PirlDrivers, "commands", original)
    res = run_sumo_scenario(SumoScenarioConfig(population=dataclasses.replace(SMALL, n_vehicles=2)), seed=0)
    assert len(res.recording.ground_truth) == 2  # libsumo was closed: a new run starts


def test_runs_in_a_spawned_worker_process(tmp_path):
    cfg = SumoScenarioConfig(population=dataclasses.replace(DEFAULT_POPULATION, n_vehicles=4))
    summary = run_in_subprocess(run_to_directory, cfg, 2, tmp_path / "w")
    assert summary["n_tracks"] == 4 and (tmp_path / "w" / "run.json").is_file()


# ----------------------------------------------------------------------------------------------
# command line
# ----------------------------------------------------------------------------------------------

def _cli(argv):
    return main(argv)


def test_cli_runs_and_reports(tmp_path, capsys):
    pop = tmp_path / "pop.toml"
    pop.write_text('n_vehicles = 5\nbackground_share = 0.2\n[[styles]]\npreset = "no preference"\n')
    assert _cli(["simulate", "sumo", "--population", str(pop), "--seed", "1", "--out", str(tmp_path / "o")]) == 0
    cap = capsys.readouterr()
    assert "5 tracks (4 PIRL, 1 background)" in cap.out and "no preference: 4 PIRL tracks" in cap.out
    assert "vehicles done" in cap.err  # the progress bar
    assert (tmp_path / "o" / "run.json").is_file()
    assert _cli(["simulate", "sumo", "--n-vehicles", "3", "--quiet", "--out", str(tmp_path / "p")]) == 0
    assert "3 tracks" in capsys.readouterr().out


def test_cli_defaults_and_errors(tmp_path, capsys, no_sumo):
    parser = build_parser()
    args = parser.parse_args(["simulate", "sumo"])
    assert (args.population, args.seed, str(args.out), args.backend) == (None, 0, "results/sumo_run", "libsumo")
    assert _cli(["simulate", "sumo", "--print-default-population"]) == 0
    from pirl_sim.scenarios.population_config import population_from_toml

    assert population_from_toml(capsys.readouterr().out) == DEFAULT_POPULATION
    bad = tmp_path / "bad.toml"
    bad.write_text('[[styles]]\nname = "x"\nmean = { speed_dev = 1.0, acc_sq = 1.0, comfort = 2.0 }\n')
    assert _cli(["simulate", "sumo", "--population", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "unknown feature name(s) 'comfort'" in capsys.readouterr().err
    assert _cli(["simulate", "sumo", "--population", str(tmp_path / "missing.toml")]) == 2
    assert not (tmp_path / "o").exists()
    with pytest.raises(SystemExit):
        parser.parse_args(["simulate", "sumo", "--seed", "-4"])


def test_default_network_is_the_documented_one():
    assert SumoScenarioConfig().network == DEFAULT_NETWORK
    assert (DEFAULT_NETWORK.radius, DEFAULT_NETWORK.junction_radius, DEFAULT_NETWORK.entry_visibility) == (
        25.0, 10.0, 50.0)
