"""The recorded scenario (pirl_sim.experiments.recorded): the replay protocol's checks and start states, the
closed-loop rollout, sweep configs of recorded data run into the tidy table with keys that follow the data, and
config errors that name the scenario as written."""

import numpy as np
import pytest

from pirl_sim.cli import main
from pirl_sim.engine import load_config, run_sweep
from pirl_sim.experiments.replay_report import ReplayProtocol

import replay_scenes
from replay_scenes import load_sumo_scene, replay_with_engine


def test_a_sweep_config_runs_the_recorded_scenario_into_the_tidy_table(passage_scene, tmp_path):
    """The replay's scenario is a sweep scenario like the others: a config of its own gives the tidy table, whose
    MED and FDE are those of the replay's rows (`pirl_sim.cli.replay.replay_results`) of the same cells."""
    from pirl_sim.cli.replay import replay_results
    from pirl_sim.experiments.recorded import load_scene

    out, _ = passage_scene
    cfg = tmp_path / "recorded.toml"
    cfg.write_text(f"""
seeds = [0, 1]
[[experiments]]
scenario = "recorded"
params = {{ tracks = "{out}", map = "{out / 'map.osm'}", replay = {{ fde_steps = [5, 15] }} }}
protocols = [{{ kind = "rolling", history_steps = 10, horizon = 15, stride = 5 }}]
learners = [{{ name = "cv", label = "CV (path)" }}, {{ name = "ca", label = "CA (path)" }}, "tirl"]
""")
    config = load_config(cfg)
    run = run_sweep(config, tmp_path / "out", workers=0, progress=False)
    assert not run.failed and len(run.table) == 6
    scene = load_scene(dict(config.cells[0].scenario_params))
    rows = replay_results(config, run, scene, ReplayProtocol(seeds=(0, 1), fde_steps=(5, 15)))["rows"]
    rows = rows.set_index(["seed", "method"])
    for _, r in run.table.iterrows():
        expected = rows.loc[(r["seed"], r["learner_label"])]
        assert r["med"] == expected["med"] and r["fde"] == expected["de@3.0s"]
        assert r["n_predictions"] == expected["n_windows"] and r["n_test"] == expected["n_test"]
    assert (tmp_path / "out" / "table.csv").is_file()


def test_replay_start_option_is_checked_and_changes_the_start_states(passage_scene, tmp_path):
    out, _ = passage_scene
    with pytest.raises(ValueError, match="start must be one of"):
        ReplayProtocol(start="smoothed")
    rows = {start: replay_with_engine(out / "vehicle_tracks_000.csv", out / "map.osm", ["tirl"],  # one scene
                                      ReplayProtocol(seeds=(0,), start=start), tmp_path / start)["rows"]
            for start in ("history", "track")}
    rows = {start: r.set_index("method") for start, r in rows.items()}
    assert rows["history"].loc["CA (path)", "med"] != rows["track"].loc["CA (path)", "med"]
    # the lateral floor uses recorded arc lengths, not the start states
    assert rows["history"].loc["TIRL", "lateral_floor"] == rows["track"].loc["TIRL", "lateral_floor"]


def test_a_recorded_sweep_config_reads_history_starts_with_speeds(passage_scene):
    """A hand-written ``recorded`` config that names no ``load.estimate`` replays with history starts (the
    default) and gets the speed-aided estimate, as ``pirl-sim replay`` does; with ``start = "track"`` (or an
    explicit estimate) it is read as asked."""
    from pirl_sim.experiments.recorded import load_scene

    out, _ = passage_scene
    params = {"tracks": str(out), "map": str(out / "map.osm"), "files": 0, "load": {}, "replay": {}}
    first = load_scene(params).trajectories[0].metadata["estimator"]
    assert first.estimate == "speeds"
    track = load_scene({**params, "replay": {"start": "track"}}).trajectories[0].metadata["estimator"]
    assert track.estimate == "positions"
    asked = load_scene({**params, "load": {"estimate": "positions"}}).trajectories[0].metadata["estimator"]
    assert asked.estimate == "positions"


@pytest.mark.parametrize("name", ["history", "horizon"])
@pytest.mark.parametrize("value", [0, -5])
def test_protocol_rejects_steps_that_are_not_positive(name, value):
    with pytest.raises(ValueError, match=name):
        ReplayProtocol(**{name: value})


def test_closed_loop_rollout_is_the_receding_horizon_simulation(sumo_recording):
    from pirl_sim.experiments.replay_report import predict_path_states
    from pirl_sim.simulate import simulate_receding_horizon

    scene, _ = load_sumo_scene(sumo_recording)
    t = scene.selected[0]
    x0 = t.states[[0, 5]]
    theta = np.broadcast_to(t.metadata["theta"], (2, 3))
    closed = predict_path_states(scene.model, x0, theta, 12, rollout="closed", mpc_horizon=20)
    ref = simulate_receding_horizon(scene.model, x0, theta, 12, 20)
    np.testing.assert_allclose(closed, np.stack([r.states for r in ref]))
    open_ = predict_path_states(scene.model, x0, theta, 12, rollout="open", mpc_horizon=20)
    np.testing.assert_allclose(open_, scene.model.predict_states(x0, theta, 20)[:, :13])
    with pytest.raises(ValueError, match="needs mpc_horizon"):
        predict_path_states(scene.model, x0, theta, 12, rollout="closed")


# ---------------------------------------------------------------------------------------------- replay
@pytest.fixture(scope="module")
def replay_dir(tmp_path_factory):
    return replay_scenes.passage_scene(tmp_path_factory.mktemp("scene"), n_trajectories=60, n_train=45, seed=2)[0]


def test_replay_scenario_runs_and_its_key_follows_the_data(replay_dir, tmp_path):
    import shutil

    scene = tmp_path / "scene"
    shutil.copytree(replay_dir, scene)
    cfg_path = tmp_path / "replay.toml"
    cfg_path.write_text("""
seeds = [0]
[[experiments]]
scenario = "replay"
params = { tracks = "scene", map = "scene/map.osm" }    # relative to this file
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 5 }]
learners = ["tirl", { name = "pirl-knn", params = { n_neighbors = 5, stride = 2 } }]
""")
    cfg = load_config(cfg_path)
    assert cfg.cells[0].scenario_params["tracks"] == str(scene.resolve())
    run = run_sweep(cfg, tmp_path / "out", workers=0, progress=False)
    assert not run.failed and len(run.table) == 2
    assert run.table["n_train"].iloc[0] + run.table["n_test"].iloc[0] == 60
    assert run.table["weight_error"].notna().all()  # the ground-truth sidecar is read
    key = cfg.cells[0].key("v")
    with open(scene / "ground_truth.csv", "a") as fh:
        fh.write("\n")
    assert load_config(cfg_path).cells[0].key("v") != key  # changed data, new key
    bad = cfg_path.read_text().replace("n_neighbors = 5", "n_neighbors = 5000")
    cfg_path.write_text(bad)
    with pytest.raises(ValueError, match="larger than the training set .*at most"):
        load_config(cfg_path)


def test_recorded_configs_fail_their_check_naming_the_scenario_as_written(replay_out, tmp_path, capsys):
    """``replay`` is another name of the recorded scenario: its errors name the scenario the config names, and both
    take the rolling protocol only and fde_steps within its horizon (rejected at the config check, not in every
    cell)."""
    scene = replay_out.parent / "scene"
    cfg = tmp_path / "recorded.toml"
    for scenario in ("recorded", "replay"):
        text = f"""
seeds = [0]
[[experiments]]
scenario = "{scenario}"
params = {{ tracks = "{scene}", map = "{scene / 'map.osm'}" }}
protocols = [{{ kind = "paper" }}]
learners = ["tirl"]
"""
        cfg.write_text(text)
        assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 2
        assert f"scenario '{scenario}' runs the rolling protocol, not 'paper'" in capsys.readouterr().err
        rolling = text.replace('kind = "paper"', 'kind = "rolling", history_steps = 5, horizon = 5, stride = 5')
        cfg.write_text(rolling.replace("map = ", "files = -1, map = "))
        assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 2
        assert f"scenario '{scenario}': files must be >= 0 (0: every file), got -1" in capsys.readouterr().err
        cfg.write_text(rolling.replace("map = ", "replay = { fde_steps = [5, 10] }, map = "))  # beyond the horizon
        assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 2
        assert (f"scenario '{scenario}' parameter 'replay': fde_steps must lie in [1, horizon=5], got (5, 10)"
                in capsys.readouterr().err)
        cfg.write_text(rolling)
        assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 0
        assert "1 cells (1 distinct)" in capsys.readouterr().out


def test_the_miss_rate_takes_the_recorded_speed_and_heading_where_the_track_has_them():
    """The INTERACTION rule's speed and heading at T: the track file's (vx, vy, psi_rad), as the challenge takes
    them; from the last two positions only for trajectories without them."""
    from types import SimpleNamespace

    from pirl_sim.experiments.recorded import _speed_heading_at_end

    xy = np.column_stack([np.arange(6.0), np.zeros(6)])  # moving +x at 1 m per step
    recorded = SimpleNamespace(metadata={"xy": xy, "v_obs": np.full(6, 7.0), "psi_obs": np.full(6, 0.3)})
    generated = SimpleNamespace(metadata={"xy": xy})
    speed, heading = _speed_heading_at_end([recorded, generated], [(0, 1), (1, 1)], horizon=3, dt=0.1)
    np.testing.assert_allclose(speed, [7.0, 10.0])
    np.testing.assert_allclose(heading, [0.3, 0.0])


@pytest.mark.parametrize("replay, learner, match", [
    ('rollout = "closed", mpc_horizon = 10', '{ name = "pirl-knn", params = { n_neighbors = 2, aggregate = "futures" } }',
     r"pirl-knn with aggregate = 'futures' predicts open-loop futures"),
    ('rollout = "closed", mpc_horizon = 10, n_futures = 6', '"tirl"',
     r"replay.n_futures = 6 scores open-loop futures, but replay.rollout = 'closed'"),
])
def test_a_closed_loop_sweep_refuses_open_loop_futures_at_the_config_check(passage_scene, tmp_path, replay, learner,
                                                                           match):
    out, _ = passage_scene
    cfg = tmp_path / "closed.toml"
    cfg.write_text(f"""
seeds = [0]
[[experiments]]
scenario = "recorded"
params = {{ tracks = "{out}", map = "{out / 'map.osm'}", replay = {{ fde_steps = [5], {replay} }} }}
protocols = [{{ kind = "rolling", history_steps = 10, horizon = 15, stride = 5 }}]
learners = [{learner}]
""")
    with pytest.raises(ValueError, match=match):
        load_config(cfg)


def test_entry_windows_are_those_whose_car_yields_in_its_history_or_horizon():
    from pirl_sim.experiments.recorded import entry_windows
    from pirl_sim.trajectory import Trajectory

    proto = ReplayProtocol(history=2, horizon=3, stride=1, seeds=(0,), fde_steps=(3,))
    flags = np.zeros(12, dtype=bool)
    flags[6] = True  # the car yields at step 6 only
    t = Trajectory(np.zeros((12, 3)), np.zeros((11, 1)), 0.2, {"yields": flags})
    steps = list(range(2, 10))
    # a window at `step` covers steps step - 2 .. step + 3
    expected = [step - 2 <= 6 <= step + 3 for step in steps]
    np.testing.assert_array_equal(entry_windows([t], [(0, s) for s in steps], proto), expected)
    assert entry_windows([Trajectory(np.zeros((12, 3)), np.zeros((11, 1)), 0.2)], [(0, 2)], proto) is None


def test_a_roundabout_recording_has_entry_windows_and_the_replay_scores_them_apart(sumo_recording):
    from pirl_sim.experiments.recorded import replay_seed

    scene, _ = load_sumo_scene(sumo_recording, selection="all", estimate="speeds")
    assert any(t.metadata["yields"].any() for t in scene.selected)  # cars wait to enter the ring
    proto = ReplayProtocol(history=5, horizon=10, stride=5, seeds=(0,), fde_steps=(10,))
    out = replay_seed(scene, 0, [("CA (path)", "ca", {}), ("CV (path)", "cv", {})], proto)
    row = out["methods"]["CA (path)"]["row"]
    assert 0 < row["n_entry_windows"] < row["n_windows"]
    n = row["n_entry_windows"]
    mixed = (n * row["med_entry"] + (row["n_windows"] - n) * row["med_not_entry"]) / row["n_windows"]
    assert mixed == pytest.approx(row["med"])
