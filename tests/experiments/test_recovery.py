"""Weight recovery of the receding-horizon IRL on simulated runs (`pirl-sim recover`, pirl_sim.experiments.recovery).

The slow tests run the command itself on small populations (24 vehicles, one seed) of both simulators; the
full study (80 vehicles, seeds 0-3) is the committed results/recovery/.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.experiments.recovery import (
    FREE_FEATURES,
    RecoveryJob,
    check_targets,
    recovery_jobs,
    summary_row,
)

N_VEHICLES = 24  # 19 PIRL tracks: every style present, a fit of a few seconds
NOISE = 0.3  # [m/s^3]


# ---------------------------------------------------------------------------------------------- fast
def _tracks(errors_sd, errors_acc, truth_sd=None):
    n = len(errors_sd)
    truth_sd = np.linspace(0.1, 3.0, n) if truth_sd is None else np.asarray(truth_sd)
    truth_acc = np.linspace(3.0, 0.3, n)
    return pd.DataFrame({
        "track_id": np.arange(1, n + 1), "style_name": ["a"] * n, "steps": 100, "usable_steps": 90,
        "fitted_steps": 45,
        "theta_speed_dev": truth_sd, "theta_hat_speed_dev": truth_sd * np.exp(errors_sd),
        "log_err_speed_dev": np.asarray(errors_sd, dtype=float),
        "theta_acc_sq": truth_acc, "theta_hat_acc_sq": truth_acc * np.exp(errors_acc),
        "log_err_acc_sq": np.asarray(errors_acc, dtype=float),
        "sigma": 0.01, "converged": True, "at_bound": False,
    })


def _styles(err_sd=0.01, err_acc=-0.02):
    return pd.DataFrame({"style_name": ["a", "b"], "tracks": [5, 5], "fitted_steps": [400, 400],
                         "log_err_speed_dev": [err_sd, 0.0], "log_err_acc_sq": [0.0, err_acc],
                         "sigma": [0.01, 0.02], "converged": [True, False]})


def test_summary_row_figures():
    tracks = _tracks(np.linspace(-0.1, 0.1, 11), np.zeros(11))
    row = summary_row(tracks, _styles(), n_pirl_tracks=12)
    assert row["usable_tracks"] == 11 and row["pirl_tracks"] == 12
    assert row["usable_fraction"] == pytest.approx(11 / 12)
    assert row["usable_steps"] == 990 and row["fitted_steps"] == 495
    assert row["median_abs_log_err_speed_dev"] == pytest.approx(0.06)
    assert row["p90_abs_log_err_speed_dev"] == pytest.approx(0.1)
    assert row["max_abs_log_err_speed_dev"] == pytest.approx(0.1)
    assert row["median_abs_log_err_acc_sq"] == 0.0
    assert row["spearman_acc_sq"] == pytest.approx(1.0)
    assert row["tirl_max_abs_log_err_speed_dev"] == pytest.approx(0.01)
    assert row["tirl_max_abs_log_err_acc_sq"] == pytest.approx(0.02)
    assert (row["converged"], row["groups"], row["tirl_converged"], row["tirl_groups"]) == (11, 11, 1, 2)


def test_summary_row_spearman_sees_a_wrong_order():
    truth = np.array([0.1, 0.2, 0.3, 0.4])
    tracks = _tracks(np.log(truth[::-1] / truth), np.zeros(4), truth_sd=truth)  # fitted = reversed truth
    assert summary_row(tracks, _styles(), 4)["spearman_speed_dev"] == pytest.approx(-1.0)


def test_check_targets():
    row = {"median_abs_log_err_speed_dev": 0.005, "median_abs_log_err_acc_sq": 0.02}
    got = {col: met for col, _, _, _, met in check_targets(row, "highway")}
    assert got == {"median_abs_log_err_speed_dev": True, "median_abs_log_err_acc_sq": False}
    with pytest.raises(ValueError, match="simulator must be one of"):
        check_targets(row, "carla")


def test_bad_input_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="simulator must be one of"):
        RecoveryJob("carla", 0, None)
    with pytest.raises(ValueError, match="control_noise must be >= 0"):
        RecoveryJob("sumo", 0, -0.1)
    with pytest.raises(ValueError, match="simulators must be some of"):
        recovery_jobs(["carla"], [0])
    with pytest.raises(ValueError, match="at least one seed"):
        recovery_jobs(["sumo"], [])
    with pytest.raises(SystemExit):
        main(["recover", "--control-noise", "0.1,x", "--out", str(tmp_path)])
    with pytest.raises(SystemExit):
        main(["recover", "--control-noise", "-1", "--out", str(tmp_path)])
    bad = tmp_path / "pop.toml"
    bad.write_text("n_vehicles = 10\nnot_a_key = 1\n")
    assert main(["recover", "--population", str(bad), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert not (tmp_path / "out" / "table.csv").exists()


def _ring_map(folder):
    from pirl_sim.io.lanelet2_map import write_map
    from pirl_sim.scenarios.sumo.network import RoundaboutSpec, build_network, lane_graph

    write_map(*lane_graph(build_network(RoundaboutSpec(), folder / "net").net), folder / "ring.osm")
    return folder / "ring.osm"


def test_a_scenario_file_sets_the_road_of_a_sumo_recovery(tmp_path, capsys):
    """``recover --scenario``: the file's road, demand and drivers in the runs' parameters (its population unless
    --population), SUMO only, checked before any run."""
    pytest.importorskip("sumolib")
    pytest.importorskip("lanelet2")
    from pirl_sim.engine.config import parse_config

    _ring_map(tmp_path)
    (tmp_path / "s.toml").write_text('lanelet_map = "ring.osm"\n[drivers]\nhorizon = 20\n[population]\n'
                                     'n_vehicles = 7\n')
    jobs = recovery_jobs(["sumo"], [0], scenario={"lanelet_map": str(tmp_path / "ring.osm"), "drivers": {"horizon": 20}},
                         population={"n_vehicles": 7})
    params = parse_config({"experiments": [j.experiment() for j in jobs]}).cells[0].scenario_params
    assert params["scenario"]["lanelet_map"] == str(tmp_path / "ring.osm") and params["scenario"]["routes"]
    assert params["scenario"]["drivers"]["horizon"] == 20 and params["population"]["n_vehicles"] == 7
    plain = parse_config({"experiments": [j.experiment() for j in recovery_jobs(["sumo"], [0])]}).cells[0]
    assert "scenario" not in plain.scenario_params  # the keys of ring runs do not change
    assert main(["recover", "--scenario", str(tmp_path / "s.toml"), "--dry-run", "--out", str(tmp_path / "o")]) == 0
    assert "4 cells, 0 already in" in capsys.readouterr().out  # the default seeds 0 1 2 3
    hw = parse_config({"experiments": [j.experiment() for j in recovery_jobs(
        ["highway"], [0], scenario={"lanelet_map": str(tmp_path / "ring.osm")})]}).cells[0].scenario_params
    assert hw["simulator"] == "highway" and hw["scenario"]["lanelet_map"] == str(tmp_path / "ring.osm")
    (tmp_path / "sumo_only.toml").write_text('lanelet_map = "ring.osm"\nspeed_mode = 31\n')
    assert main(["recover", "--scenario", str(tmp_path / "sumo_only.toml"), "--simulator", "highway", "--out",
                 str(tmp_path / "o"), "--quiet"]) == 2
    assert "speed_mode" in capsys.readouterr().err  # a SUMO key highway-env does not know
    (tmp_path / "bad.toml").write_text('lanelet_map = "ring.osm"\ndemand_per_arm = 600.0\n')
    assert main(["recover", "--scenario", str(tmp_path / "bad.toml"), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "demand_per_arm sets the demand of the parametric" in capsys.readouterr().err
    assert not (tmp_path / "o" / "table.csv").exists()


# ---------------------------------------------------------------------------------------------- slow
def _recover(out, simulator, *extra):
    code = main(["recover", "--simulator", simulator, "--seeds", "0", "--n-vehicles", str(N_VEHICLES),
                 "--out", str(out), "--quiet", *extra])
    assert code == 0
    return pd.read_csv(out / "table.csv", dtype={"seed": str})


@pytest.fixture(scope="module")
def sumo_study(tmp_path_factory):
    pytest.importorskip("libsumo")
    pytest.importorskip("lanelet2")
    out = tmp_path_factory.mktemp("recover_sumo")
    table = _recover(out, "sumo", "--control-noise", str(NOISE), "--workers", "2")
    return out, table


PER_TRACK = ("median", "p90", "spearman", "usable")  # the targets on per-track fits


@pytest.mark.slow
def test_sumo_recovery_meets_the_per_track_targets(sumo_study):
    """SUMO, default styles, one seed of 24 vehicles: the stated per-track targets on every PIRL track with
    enough usable steps (median |log err| <= 0.05, 90th percentile <= 0.3, Spearman >= 0.9 for speed_dev,
    >= 90 % of the PIRL tracks usable)."""
    _, table = sumo_study
    row = table.iloc[0].to_dict()
    assert row["pirl_tracks"] >= 15
    checked = [t for t in check_targets(row, "sumo") if t[0].startswith(PER_TRACK)]
    assert len(checked) == 6
    assert all(t[-1] for t in checked), checked
    assert row["converged"] == row["groups"] and row["at_bound"] == 0
    assert row["sigma_median"] < 0.01  # [m/s^3] no control noise: residuals are the state estimate's


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="one weight vector for a style's drivers is not their mean weight when "
                   "the drivers differ (default styles: 10 % std): 'minimises acceleration' TIRL is off by "
                   "0.4-0.6 in log on this seed; without the spread it is exact (test below)")
def test_sumo_style_tirl_within_005_of_the_style_mean(sumo_study):
    _, table = sumo_study
    checked = [t for t in check_targets(table.iloc[0].to_dict(), "sumo") if t[0].startswith("tirl")]
    assert checked and all(t[-1] for t in checked), checked


@pytest.mark.slow
def test_sumo_fitted_sigma_recovers_the_control_noise(sumo_study):
    out, _ = sumo_study
    noise = pd.read_csv(out / "noise.csv", dtype={"seed": str}).iloc[0]
    assert noise["control_noise"] == NOISE
    # the state estimate smooths the recorded jerks a little (its jerk prior): measured 0.27-0.28 for 0.3
    assert noise["sigma_median"] == pytest.approx(NOISE, rel=0.2)
    for f in FREE_FEATURES:  # noise costs accuracy but the weights stay recognisable
        assert noise[f"median_abs_log_err_{f}"] < 0.3
    assert noise["spearman_speed_dev"] > 0.8  # measured 0.875 on these 19 tracks, 0.90 on 64 (results/)


@pytest.fixture(scope="module")
def no_spread_study(tmp_path_factory):
    """The default styles with 100x smaller spread within each style (std 0.1 % of the mean)."""
    pytest.importorskip("libsumo")
    pytest.importorskip("lanelet2")
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION_TOML

    out = tmp_path_factory.mktemp("recover_no_spread")
    text = DEFAULT_POPULATION_TOML
    for old, new in (("{ speed_dev = 0.3, acc_sq = 0.03 }", "{ speed_dev = 0.003, acc_sq = 0.0003 }"),
                     ("{ speed_dev = 0.01, acc_sq = 0.3 }", "{ speed_dev = 0.0001, acc_sq = 0.003 }"),
                     ("{ speed_dev = 0.03, acc_sq = 0.03 }", "{ speed_dev = 0.0003, acc_sq = 0.0003 }")):
        assert old in text
        text = text.replace(old, new)
    pop = out / "population.toml"
    pop.write_text(text)
    extra = ("--population", str(pop))
    return out, _recover(out, "sumo", *extra), extra


@pytest.mark.slow
def test_sumo_style_tirl_is_exact_without_spread_within_styles(no_spread_study):
    _, table, _ = no_spread_study
    row = table.iloc[0].to_dict()
    missed = [t for t in check_targets(row, "sumo") if not t[-1] and not t[0].startswith("spearman")]
    assert not missed, missed  # (Spearman within a style of nearly equal weights means little)
    for f in FREE_FEATURES:
        assert row[f"tirl_max_abs_log_err_{f}"] < 0.01


@pytest.mark.slow
def test_rerun_reuses_the_runs_and_writes_the_same_bytes(no_spread_study):
    out, _, extra = no_spread_study
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    _recover(out, "sumo", *extra)
    times = pd.read_csv(out / "times.csv")
    assert not times["simulated"].any()
    after = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert set(after) == set(before)
    for name in sorted(before):
        if name != "times.csv":  # wall times
            assert after[name] == before[name], name
    assert {"table.csv", "table.md", "styles.csv", "tracks.csv", "style_mixtures.csv", "selection.csv", "README.md",
            ".gitignore", "scene_sumo_weights.png", "scene_sumo_errors.png"} <= set(after)
    assert "![sumo weights](scene_sumo_weights.png)" in (out / "README.md").read_text()
    assert "## Styles in weight space" in (out / "README.md").read_text()
    mixtures = pd.read_csv(out / "style_mixtures.csv")
    assert (mixtures["ari"] == 1.0).all()  # three styles of nearly equal drivers, weights fitted noise-free
    sel = pd.read_csv(out / "selection.csv")
    assert {"overridden", "not_commanded", "collided", "usable", "tracks_kept"} <= set(sel.columns)


@pytest.fixture(scope="module")
def highway_table(tmp_path_factory):
    pytest.importorskip("highway_env")
    pytest.importorskip("lanelet2")
    return _recover(tmp_path_factory.mktemp("recover_highway"), "highway").iloc[0].to_dict()


@pytest.mark.slow
def test_highway_recovery_meets_the_target(highway_table):
    """highway-env, one seed of 24 vehicles: per-track median |log err| <= 0.01 for both free weights."""
    row = highway_table
    missed = [t for t in check_targets(row, "highway") if not t[-1]]
    assert not missed, missed
    assert row["usable_fraction"] >= 0.9 and row["converged"] == row["groups"]
    assert row["spearman_speed_dev"] >= 0.9


def test_summary_of_nothing_is_nan():
    row = summary_row(_tracks([], []), _styles().iloc[:0], 0)
    assert row["usable_tracks"] == 0 and math.isnan(row["usable_fraction"])
