"""highway-env roundabout scenarios: plan -> simulate -> record through the one writer -> read back, the command
line, and PIRL-GMM recovering the three styles end to end."""

import dataclasses
import filecmp

import numpy as np
import pytest

pytest.importorskip("highway_env")
pytest.importorskip("lanelet2")

from pirl_sim.cli import main  # noqa: E402
from pirl_sim.scenarios.highway.scenario import (  # noqa: E402
    HighwayScenarioConfig,
    load_highway_run,
    load_scenario,
    run_highway_scenario,
    scenario_from_dict,
)
from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, population_from_dict  # noqa: E402
from pirl_sim.scenarios.recording import (  # noqa: E402
    DRIVER_STEPS_FILE,
    GROUND_TRUTH_FILE,
    INFO_FILE,
    MAP_FILE,
    TRACKS_FILE,
    read_recording,
)

from style_demos import assert_pirl_gmm_finds_the_styles  # noqa: E402


SMALL = population_from_dict({**DEFAULT_POPULATION.to_dict(), "n_vehicles": 16, "depart_interval": 3.0})


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("hw") / "run"
    return run_highway_scenario(HighwayScenarioConfig(population=SMALL), seed=3, out_dir=out), out


def test_run_writes_every_file_and_they_read_back(small_run):
    res, out = small_run
    for name in (TRACKS_FILE, GROUND_TRUTH_FILE, MAP_FILE, INFO_FILE):
        assert (out / name).is_file()
    back = read_recording(out)
    assert back.info["simulator"] == "highway-env" and back.info["seed"] == 3
    assert back.ground_truth.equals(res.recording.ground_truth)
    assert len(back.tracks) == len(res.recording.tracks)


def test_ground_truth_matches_the_plan_and_nobody_crashed(small_run):
    res, _ = small_run
    gt = res.recording.ground_truth.set_index("agent_id")
    plan = res.vehicles.set_index("vehicle_id")
    assert set(gt.index) == set(plan.index)  # every planned vehicle drove (and in departure order)
    assert list(gt.index) == list(plan.index)
    for col in ("route_id", "is_pirl", "style", "style_name"):
        assert (gt[col] == plan.loc[gt.index, col]).all()
    pirl = gt["is_pirl"]
    theta_cols = ["theta_speed_dev", "theta_acc_sq", "theta_jerk_sq"]
    np.testing.assert_array_equal(gt.loc[pirl, theta_cols].to_numpy(), plan.loc[pirl[pirl].index, theta_cols].to_numpy())
    assert (gt["status"] == "arrived").all() and not gt["collided"].any() and not gt["removed_early"].any()
    assert gt.loc[~pirl, "interacted"].isna().all() and gt.loc[pirl, "interacted"].notna().all()
    # interacted <=> some command overridden (no collisions here; hand-backs count too)
    summary = res.summary.set_index("vehicle_id").loc[gt.index[pirl]]
    flagged = (summary["n_overridden"] > 0) | summary["handed_back"]
    assert (gt.loc[pirl, "interacted"].astype(bool) == flagged).all()


def test_recorded_tracks_follow_their_routes(small_run):
    res, _ = small_run
    tracks, gt = res.recording.tracks, res.recording.ground_truth
    for row in gt.itertuples(index=False):
        xy = tracks.loc[tracks["track_id"] == row.track_id, ["x", "y"]].to_numpy()
        _, d = res.routes.path(row.route_id).to_frenet(xy, extrapolate=True)
        assert np.abs(d).max() < 1.5  # highway-env's steering cuts the 66 degree kinks by ~1.2 m
        assert np.hypot(*(xy[-1] - res.routes.path(row.route_id).to_cartesian(
            res.routes.path(row.route_id).length, 0.0))) < 3.0  # it drove to the end of its route


def test_demonstrations_from_disk_are_the_drivers_own_speeds(small_run):
    res, out = small_run
    mem = res.demonstrations()
    disk = load_highway_run(out).demonstrations()
    assert len(mem) == len(disk) >= 4
    assert all(not d.metadata["interacted"] for d in mem)
    for a, b in zip(mem, disk):
        assert a.metadata["track_id"] == b.metadata["track_id"]
        np.testing.assert_allclose(a.states, b.states, atol=1e-6)
    tracks = res.recording.tracks
    for d in mem:
        g = tracks[tracks["track_id"] == d.metadata["track_id"]]
        np.testing.assert_allclose(d.states[:, 1], np.hypot(g["vx"], g["vy"]).to_numpy(), atol=0.3)


def test_same_seed_byte_identical_files_different_seed_different(small_run, tmp_path):
    _, out = small_run
    again = tmp_path / "again"
    run_highway_scenario(HighwayScenarioConfig(population=SMALL), seed=3, out_dir=again)
    for name in (TRACKS_FILE, GROUND_TRUTH_FILE, MAP_FILE, INFO_FILE, DRIVER_STEPS_FILE):
        assert filecmp.cmp(out / name, again / name, shallow=False), name
    other = tmp_path / "other"
    run_highway_scenario(HighwayScenarioConfig(population=SMALL), seed=4, out_dir=other)
    assert not filecmp.cmp(out / TRACKS_FILE, other / TRACKS_FILE, shallow=False)


@pytest.mark.parametrize("data, match", [
    ({"netwrok": {}}, r"unknown key\(s\) 'netwrok'; valid keys: geometry, population, drivers, rules"),
    ({"drivers": {"horizn": 3}}, r"drivers: unknown key\(s\) 'horizn'; valid keys: horizon, n_iter"),
    ({"rules": {"yield_time": 3}}, r"rules: unknown key\(s\) 'yield_time'; valid keys: lookahead"),
    ({"geometry": {"radius": 2.0}}, r"geometry: radius must be"),
    ({"geometry": {"lanes": 2}}, r"geometry: unknown key\(s\) 'lanes'; valid keys: radius"),
    ({"pirl_routes": ["arm0_to_arm9"]}, r"unknown route"),
    ({"population": {"n_vehicle": 3}}, r"population: unknown key\(s\) 'n_vehicle'"),
    ({"max_duration": -1}, r"max_duration must be a finite number > 0, got -1"),
    ({"rules": {"crash_removal": False, "crash_removal_delay": 1.0}}, r"exclude each other"),
])
def test_bad_configs_raise_before_anything_runs(data, match):
    with pytest.raises(ValueError, match=match):
        scenario_from_dict(data)


def test_config_round_trips_through_plain_data():
    cfg = scenario_from_dict({"rules": {"crash_removal": False}, "drivers": {"horizon": 20},
                              "background_routes": ["arm1_to_arm3"], "max_duration": 50.0})
    assert cfg.rules.crash_removal_delay is None and cfg.drivers.horizon == 20
    assert scenario_from_dict(cfg.to_dict()) == cfg


def test_cli_runs_a_tiny_scenario_and_reports(tmp_path, capsys):
    toml = tmp_path / "tiny.toml"
    toml.write_text('max_duration = 60.0\n[geometry]\nradius = 25.0\n[population]\nn_vehicles = 3\n'
                    'depart_interval = 5.0\nbackground_share = 0.0\n', encoding="utf-8")
    assert load_scenario(toml).geometry.radius == 25.0
    assert main(["simulate", "highway", "--scenario", str(toml), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "3 tracks (3 PIRL, 0 background)" in printed and "collided: 0" in printed
    assert (tmp_path / "out" / INFO_FILE).is_file()
    assert main(["simulate", "highway", "--scenario", str(tmp_path / "missing.toml"), "--quiet"]) == 2
    assert "scenario config not found" in capsys.readouterr().err


#: Measured 1.0 for seeds 0-7 (24-37 demonstrations each). With ~30 demonstrations in three styles, one
#: misassigned demonstration costs ~0.07 (ARI 0.93), two ~0.12, three ~0.17: 0.8 fails the test from the
#: third misassignment on, i.e. when clustering gets a tenth of the drivers wrong.
ARI_TARGET = 0.8
LEARNING_DT = 0.2  # [s] the learner's model step, as in the SUMO end-to-end test (IRL ~5x cheaper than at 0.1 s)


@pytest.mark.slow
def test_pirl_gmm_recovers_the_three_styles_from_a_highway_env_population(tmp_path):
    """The default scenario (80 vehicles: the paper's three styles in equal shares, 20 % highway-env IDM
    background traffic, one every 4 s, highway-env's roundabout of radius 20 m), written to disk and read
    back; the PIRL tracks without interaction become (s, v, a) demonstrations on their routes' paths, and
    PIRL-GMM with three components clusters them (~25 s)."""
    res = run_highway_scenario(seed=0, out_dir=tmp_path)
    gt = res.recording.ground_truth
    assert not gt["collided"].any() and (gt["status"] == "arrived").all()
    run = load_highway_run(tmp_path)
    demos = run.demonstrations(dt=LEARNING_DT)
    assert_pirl_gmm_finds_the_styles(demos, run.routes, gt, LEARNING_DT, ARI_TARGET)


def _collided_tracks(depart_interval: float, seed: int, population=DEFAULT_POPULATION) -> int:
    pop = dataclasses.replace(population, depart_interval=depart_interval)
    gt = run_highway_scenario(HighwayScenarioConfig(population=pop), seed=seed).recording.ground_truth
    assert (gt["status"] == "arrived").all()  # nobody stuck: the way stays clear
    return int(gt["collided"].sum())


def test_a_diverging_vehicle_waits_for_the_ring_vehicle_standing_past_its_diverge():
    """Crowded ring (a departure every 1 s), seed 7: a car leaving for its exit clipped a ring car queued just past
    the diverge node (not on its route, so not its leader); such a car is now its leader until it is clear."""
    assert _collided_tracks(1.0, 7) == 0


@pytest.mark.slow
@pytest.mark.parametrize("depart_interval", [1.5, 1.0, 0.5])
def test_no_collision_in_crowded_runs(depart_interval):
    """80 vehicles, 12 seeds per demand level (a departure every 1.5, 1 and 0.5 s; the default is 4 s): no crash
    between the simulated drivers (7 crashes in these 36 runs with the diverge's ring cars not seen as leaders)."""
    assert sum(_collided_tracks(depart_interval, seed) for seed in range(12)) == 0


@pytest.mark.slow
@pytest.mark.parametrize("depart_interval", [4.0, 1.5])
def test_no_collision_among_drivers_who_interact(depart_interval):
    """The example population of drivers who interact, whose own cost keeps their distance and yields (highway-env's
    rules only their safety layer), at its default demand (a departure every 4 s) and crowded (1.5 s), 6 seeds
    each: no crash, nobody stuck (with an IDM of time gap 0.5 s as the safety layer, a close follower ran into a
    car that stopped at the line: 1 crash in 6 crowded runs)."""
    from pirl_sim.scenarios.population_config import INTERACTING_POPULATION

    assert sum(_collided_tracks(depart_interval, seed, INTERACTING_POPULATION) for seed in range(6)) == 0
