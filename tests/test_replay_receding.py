"""The replay with the receding-horizon likelihood: speeds in the estimate, per-step masks from driver_steps.csv,
the drivers' horizon and step from run.json, closed-loop rollouts, the horizon scan, and the errors promised for
bad input."""

import dataclasses
import warnings

import numpy as np
import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.metrics import weight_recovery_error


@pytest.fixture(scope="module")
def sumo_run(tmp_path_factory):
    """A small SUMO run (20 vehicles, drivers re-planning over 30 steps of 0.1 s), written as a recording."""
    pytest.importorskip("libsumo")
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION
    from pirl_sim.scenarios.sumo import SumoScenarioConfig, run_sumo_scenario

    out = tmp_path_factory.mktemp("receding_replay") / "run"
    pop = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=20, depart_interval=1.5)
    run_sumo_scenario(SumoScenarioConfig(population=pop), seed=1, out_dir=out)
    return out


def _load(run, **kw):
    from pirl_sim.scenarios.replay import SIMULATED_NOISE, load_replay, recording_settings

    rec = recording_settings(run)
    args = dict(dt=rec.dt, estimate="speeds", noise=SIMULATED_NOISE, selection="steps", max_steps=None,
                smoothing=rec.smoothing, speed_smoothing=rec.speed_smoothing, a_lat=rec.a_lat, v_max=rec.v_max,
                arc_length="observed")
    args.update(kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return load_replay([run / "vehicle_tracks_000.csv"], run / "map.osm", **args), rec


def test_recording_settings_and_masks_match_the_recorded_demonstrations(sumo_run):
    from pirl_sim.scenarios.replay import recording_settings
    from pirl_sim.scenarios.sumo import load_sumo_run

    scene, rec = _load(sumo_run)
    assert rec == recording_settings(sumo_run / "vehicle_tracks_000.csv")
    assert rec.horizon == 30 and rec.dt == pytest.approx(0.1)
    run = load_sumo_run(sumo_run)
    demos = {d.metadata["track_id"]: d for d in run.demonstrations(selection="steps", min_steps=10)}
    n_background = int((~run.recording.ground_truth["is_pirl"]).sum())
    assert scene.skipped["no driver steps (not a PIRL driver)"] == n_background
    assert {t.metadata["track_id"] for t in scene.selected} == set(demos)
    assert any(t.metadata["interacted"] for t in scene.selected)  # interacting tracks kept, masked
    for t in scene.selected:
        d = demos[t.metadata["track_id"]]
        np.testing.assert_array_equal(t.metadata["step_mask"], d.metadata["step_mask"])
        assert t.n_steps == d.n_steps and "theta" in t.metadata
        np.testing.assert_allclose(t.metadata["theta"], d.metadata["theta"], rtol=1e-12)
        # same speeds: both estimate from the recorded speeds with the same noise model
        assert np.abs(t.states[:, 1] - d.states[:, 1]).max() < 1e-3
    assert scene.steps["steps kept (driver's own)"] == sum(int(d.metadata["step_mask"].sum()) for d in demos.values())


def test_receding_fit_on_the_replay_recovers_the_drivers_weights(sumo_run):
    from pirl_sim.receding import fit_receding

    scene, rec = _load(sumo_run)
    tracks = scene.selected
    res = fit_receding(scene.model, tracks, horizon=rec.horizon)
    err = weight_recovery_error(res.normalized, np.stack([t.metadata["theta"] for t in tracks]), 2)
    assert np.median(err) < 0.02  # measured 0.003 on this run; 0.0026 on simulate sumo --seed 0
    # positions only and the replay's default desired speed (no speed smoothing): far off
    off, _ = _load(sumo_run, estimate="positions", speed_smoothing=0.0)
    res_off = fit_receding(off.model, off.selected[:6], horizon=rec.horizon)
    true = np.stack([t.metadata["theta"] for t in off.selected[:6]])
    assert np.median(weight_recovery_error(res_off.normalized, true, 2)) > 5 * np.median(err)


def test_closed_loop_rollout_is_the_receding_horizon_simulation(sumo_run):
    from pirl_sim.experiments.replay_report import predict_path_states
    from pirl_sim.simulate import simulate_receding_horizon

    scene, _ = _load(sumo_run)
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


@pytest.mark.slow
def test_replay_cli_receding_beats_constant_acceleration(tmp_path):
    """40 vehicles (on 20, 12 training tracks are too few for the kNN look-up: its weights miss the style)."""
    pytest.importorskip("libsumo")
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION
    from pirl_sim.scenarios.sumo import SumoScenarioConfig, run_sumo_scenario

    run = tmp_path / "run40"
    pop = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=40)
    run_sumo_scenario(SumoScenarioConfig(population=pop), seed=1, out_dir=run)
    out = tmp_path / "res"
    assert main(["replay", "--tracks", str(run), "--map", str(run / "map.osm"), "--likelihood", "receding",
                 "--learners", "tirl,pirl-knn", "--knn-k", "5", "--seeds", "3", "--out", str(out), "--quiet"]) == 0
    summary = pd.read_csv(out / "summary.csv").set_index("method")
    knn = "PIRL-kNN (k=5)"
    assert summary.loc[knn, "irl_weight_error_mean"] < 0.05
    assert summary.loc[knn, "med_mean"] < summary.loc["CA (path)", "med_mean"]
    paired = pd.read_csv(out / "paired_ca.csv").set_index("method")
    assert paired.loc[knn, "mean_difference"] < -2 * paired.loc[knn, "standard_error"]
    readme = (out / "README.md").read_text()
    assert "selection='steps'" in readme and "Paired differences against CA (path)" in readme


@pytest.mark.slow
def test_horizon_scan_prefers_the_drivers_horizon(sumo_run, tmp_path):
    from pirl_sim.experiments.horizon_scan import scan_horizons, summarize_scan
    from pirl_sim.experiments.replay_report import ReplayProtocol

    scene, _ = _load(sumo_run, max_steps=200)
    proto = ReplayProtocol(history=20, horizon=30, stride=10, fde_steps=(10, 30), seeds=(0,), rollout="closed",
                           mpc_horizon=30)
    rows = scan_horizons(scene, [10, 30, 50], proto, step_stride=2)
    table = summarize_scan(rows).set_index("horizon")
    assert table["own_nll"].idxmin() == 30
    assert table.loc[30, "med"] < table.loc[10, "med"]


# ----------------------------------------------------------------------------------------------
# bad input
# ----------------------------------------------------------------------------------------------

@pytest.fixture
def real_like(tmp_path):
    """Two straight lanes and a few tracks, no run.json: data as real data come."""
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map

    x = np.linspace(0.0, 400.0, 41)
    write_map({"A": np.column_stack([x, np.zeros_like(x)])}, {}, tmp_path / "map.osm")
    rows = []
    for i in range(6):
        n = 80
        frames = np.arange(1 + 100 * i, 1 + 100 * i + n)
        rows.append(pd.DataFrame({"track_id": i + 1, "frame_id": frames, "timestamp_ms": 100 * frames,
                                  "agent_type": "car", "x": 10.0 + np.arange(n), "y": 0.0, "vx": 10.0, "vy": 0.0,
                                  "psi_rad": 0.0, "length": 4.5, "width": 1.8}))
    write_tracks(pd.concat(rows, ignore_index=True), tmp_path / "vehicle_tracks_000.csv")
    return tmp_path


def test_receding_without_a_horizon_on_real_data_names_the_option(real_like, capsys):
    base = ["replay", "--tracks", str(real_like), "--map", str(real_like / "map.osm"), "--out",
            str(real_like / "out"), "--quiet"]
    assert main(base + ["--likelihood", "receding"]) == 2
    assert "--mpc-horizon" in capsys.readouterr().err
    assert main(base + ["--rollout", "closed"]) == 2
    assert "--mpc-horizon" in capsys.readouterr().err
    assert main(base + ["--likelihood", "receding", "--mpc-horizon", "10", "--selection", "steps"]) == 2
    assert "driver_steps.csv" in capsys.readouterr().err
    assert main(base + ["--selection", "steps"]) == 2
    assert "--likelihood receding" in capsys.readouterr().err
    for bad in ("0", "-3", "ten"):
        with pytest.raises(SystemExit) as exc:
            main(base + ["--likelihood", "receding", "--mpc-horizon", bad])
        assert exc.value.code == 2
        assert "--mpc-horizon must be a positive number of steps" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(base + ["--dt", "0"])


def test_load_replay_rejects_bad_options(real_like):
    from pirl_sim.experiments.replay_report import ReplayProtocol
    from pirl_sim.scenarios.replay import EstimateNoise, load_replay

    files, osm = [real_like / "vehicle_tracks_000.csv"], real_like / "map.osm"
    with pytest.raises(ValueError, match="estimate must be one of"):
        load_replay(files, osm, estimate="lidar")
    with pytest.raises(ValueError, match="selection must be one of"):
        load_replay(files, osm, selection="frames")
    with pytest.raises(ValueError, match="driver_steps.csv"):
        load_replay(files, osm, selection="steps")
    with pytest.raises(ValueError, match="sigma_v must be a finite number > 0"):
        EstimateNoise(0.1, 0.0, 1.0)
    with pytest.raises(ValueError, match="rollout='closed' needs mpc_horizon"):
        ReplayProtocol(rollout="closed")
    with pytest.raises(ValueError, match="mpc_horizon must be a positive number of steps"):
        ReplayProtocol(mpc_horizon=0)
    scene = load_replay(files, osm, estimate="speeds", dt=0.1)  # measured-noise defaults on a clean track
    for t in scene.trajectories:
        np.testing.assert_allclose(t.states[:, 1], 10.0, atol=1e-3)
