"""The horizon scan (pirl_sim.experiments.horizon_scan): it prefers the drivers' own horizon and fits the desired
speed per split."""

import dataclasses
import warnings

import numpy as np
import pandas as pd
import pytest

from pirl_sim.experiments.replay_report import ReplayProtocol
from pirl_sim.scenarios.replay import load_replay


def _weaving_scene(tmp_path, n_tracks=12):
    """Straight lane; every car weaves across it the same way along x (a route-consistent driven path)."""
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map

    x = np.linspace(0.0, 400.0, 41)
    write_map({"A": np.column_stack([x, np.zeros_like(x)])}, {}, tmp_path / "map.osm")
    rows, frame = [], 1
    for i in range(n_tracks):
        n = 200
        frames = np.arange(frame, frame + n)
        speed = 8.0 + 0.3 * i
        xx = 10.0 + 3.0 * i + speed * 0.1 * np.arange(n)
        y = 1.2 * np.sin(xx / 15.0) + 0.1 * (i % 3 - 1)
        psi = np.arctan(1.2 / 15.0 * np.cos(xx / 15.0))
        rows.append(pd.DataFrame({"track_id": i + 1, "frame_id": frames, "timestamp_ms": 100 * frames,
                                  "agent_type": "car", "x": xx, "y": y, "vx": speed, "vy": 0.0, "psi_rad": psi,
                                  "length": 4.5, "width": 1.8}))
        frame += n + 10
    write_tracks(pd.concat(rows, ignore_index=True), tmp_path / "vehicle_tracks_000.csv")
    return tmp_path / "vehicle_tracks_000.csv", tmp_path / "map.osm"


def test_horizon_scan_fits_the_desired_speed_per_split(tmp_path):
    from pirl_sim.experiments.horizon_scan import scan_horizons

    tracks, osm = _weaving_scene(tmp_path)
    scene = load_replay([tracks], osm, smoothing=0.0, features="speed-level")
    rows = scan_horizons(scene, [5], ReplayProtocol(seeds=(0,), test_fraction=0.34), step_stride=4,
                         desired_speed="fit")
    # cars at 8-11.3 m/s on a nearly straight lane: the fitted cap sits among their speeds, not at 13.9 m/s
    assert 7.5 < rows["v_max"].iloc[0] < 12.0
    assert rows["med"].iloc[0] < 1.0


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
