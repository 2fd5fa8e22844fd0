"""The horizon scan (pirl_sim.experiments.horizon_scan): it prefers the drivers' own horizon and fits the desired
speed per split."""


import pandas as pd
import pytest

from pirl_sim.experiments.replay_report import ReplayProtocol
from pirl_sim.scenarios.replay import load_replay
from replay_scenes import load_sumo_scene
from weaving import weaving_scene


def test_horizon_scan_fits_the_desired_speed_per_split(tmp_path):
    from pirl_sim.experiments.horizon_scan import scan_seed

    tracks, osm = weaving_scene(tmp_path)
    scene = load_replay([tracks], osm, smoothing=0.0, features="speed-level")
    (row,) = scan_seed(scene, 0, [5], ReplayProtocol(test_fraction=0.34), step_stride=4, desired_speed="fit")
    # cars at 8-11.3 m/s on a nearly straight lane: the fitted cap sits among their speeds, not at 13.9 m/s
    assert 7.5 < row["v_max"] < 12.0
    assert row["med"] < 1.0


def test_the_scan_runs_as_cells_of_the_engine_one_per_seed_and_horizon(tmp_path, capsys):
    """``replay --scan-horizon`` is the ``horizon-scan`` kind: its cells are counted by --dry-run, stored, and
    give `scan_seed`'s rows; bad horizons are refused before any work."""
    from pirl_sim.cli import main
    from pirl_sim.experiments.horizon_scan import scan_seed

    tracks, osm = weaving_scene(tmp_path)
    args = ["replay", "--preset", "paper",
            "--tracks", str(tracks), "--map", str(osm), "--scan-horizon", "5,8", "--seeds", "2",
            "--features", "speed-level", "--out", str(tmp_path / "out"), "--quiet"]
    assert main([*args, "--dry-run"]) == 0
    assert f"4 cells, 0 already in {tmp_path / 'out'}/, 4 to run" in capsys.readouterr().out
    assert main(args) == 0
    rows = pd.read_csv(tmp_path / "out" / "horizon_scan_rows.csv")
    assert list(zip(rows["seed"], rows["horizon"])) == [(0, 5), (0, 8), (1, 5), (1, 8)]
    assert len(list((tmp_path / "out" / "cells").glob("*.json"))) == 4
    scene = load_replay([tracks], osm, dt=0.2, estimate="speeds", features="speed-level")
    (direct,) = scan_seed(scene, 1, [8], ReplayProtocol(history=10, horizon=15, stride=5, fde_steps=(5, 10, 15)))
    assert rows.iloc[3]["test_nll"] == pytest.approx(direct["test_nll"], rel=1e-5)
    assert main([*args, "--dry-run"]) == 0
    assert ", 0 to run" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_:
        main([*args[:-5], "--scan-horizon", "0,5", "--out", str(tmp_path / "bad")])
    assert exit_.value.code == 2 and "--scan-horizon" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


@pytest.mark.slow
def test_horizon_scan_prefers_the_drivers_horizon(sumo_recording, tmp_path):
    from pirl_sim.experiments.horizon_scan import scan_seed, summarize_scan
    from pirl_sim.experiments.replay_report import ReplayProtocol

    scene, _ = load_sumo_scene(sumo_recording, max_steps=200)
    proto = ReplayProtocol(history=20, horizon=30, stride=10, fde_steps=(10, 30), seeds=(0,), rollout="closed",
                           mpc_horizon=30)
    rows = pd.DataFrame(scan_seed(scene, 0, [10, 30, 50], proto, step_stride=2))
    table = summarize_scan(rows).set_index("horizon")
    assert table["own_nll"].idxmin() == 30
    assert table.loc[30, "med"] < table.loc[10, "med"]
