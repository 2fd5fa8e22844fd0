"""pirl_sim.experiments.calibrate and ``pirl-sim calibrate``: a population fitted to recorded cars, written as a
scenario TOML the simulators read."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from pirl_sim.experiments.calibrate import (FREE_INTERACTING, Calibration, calibrate, fit_styles,
                                            fit_styles_deconvolved, lognormal_moments)
from shared_sample import SAMPLE_MAP, needs_sample


def _calibration(**kw) -> Calibration:
    """A hand-made calibration of 12 cars in two styles."""
    rng = np.random.default_rng(3)
    log_w = np.vstack([rng.normal([1.0, -1.0], 0.1, (6, 2)), rng.normal([-2.0, 1.0], 0.1, (6, 2))])
    args = dict(a_lat=1.7, v_max=12.5, horizon=30, dt=0.1, cars=tuple(("f.csv", i) for i in range(12)),
                log_weights=log_w, at_bound=np.zeros((12, 2), bool), converged=np.ones(12, bool),
                style_share=np.array([0.25, 0.75]), style_log_mean=np.array([[1.0, -1.0], [-2.0, 1.0]]),
                style_log_var=np.array([[0.01, 0.04], [0.09, 0.0001]]), bic={1: 50.0, 2: 10.0},
                depart_rate=600.0, n_cars=14, duration_s=84.0)
    args.update(kw)
    return Calibration(**args)


def test_lognormal_moments_are_those_of_the_exponentiated_draws():
    rng = np.random.default_rng(0)
    mu, var = np.array([0.5, -2.0]), np.array([0.2, 0.05])
    draws = np.exp(rng.normal(mu, np.sqrt(var), (400_000, 2)))
    mean, std = lognormal_moments(mu, var)
    np.testing.assert_allclose(mean, draws.mean(axis=0), rtol=5e-3)
    np.testing.assert_allclose(std, draws.std(axis=0), rtol=2e-2)


@pytest.mark.parametrize("n_clusters", [1, 3])
def test_the_bic_chooses_as_many_styles_as_there_are_separated_clusters(n_clusters):
    rng = np.random.default_rng(n_clusters)
    centres = np.array([[1.0, -1.0], [-2.0, 1.0], [-0.5, -3.0]])[:n_clusters]
    x = np.vstack([rng.normal(c, 0.15, (40, 2)) for c in centres])
    gmm, bic = fit_styles(x, max_styles=4, seed=0)
    assert gmm.n_components == n_clusters and set(bic) == {1, 2, 3, 4}
    assert min(bic, key=bic.get) == n_clusters
    found = gmm.means_[np.lexsort(gmm.means_.T)]
    np.testing.assert_allclose(found, centres[np.lexsort(centres.T)], atol=0.1)


def test_the_scenario_toml_is_read_by_both_simulators_with_the_calibrated_styles(tmp_path):
    pytest.importorskip("sumolib")
    from pirl_sim.scenarios.highway.scenario import load_scenario as load_highway
    from pirl_sim.scenarios.sumo.scenario import load_scenario as load_sumo

    cal = _calibration()
    path = tmp_path / "calibrated.toml"
    path.write_text(cal.scenario_toml("f.csv", n_vehicles=40, background_share=0.1, road="ring"))
    for load in (load_sumo, load_highway):
        config = load(path)
        drivers = config.drivers
        assert (drivers.a_lat, drivers.v_max, drivers.depart_speed, drivers.horizon) == (1.7, 12.5, 12.5, 30)
        pop = config.population
        assert (pop.n_vehicles, pop.background_share, pop.arrivals.value) == (40, 0.1, "poisson")
        assert pop.depart_interval == pytest.approx(6.0)  # 600 cars per hour
        assert [s.name for s in pop.styles] == ["calibrated 1", "calibrated 2"]  # the larger share first
        assert [s.weight for s in pop.styles] == pytest.approx([0.75, 0.25])
        mean, std = lognormal_moments(cal.style_log_mean[1], cal.style_log_var[1])
        assert [pop.styles[0].mean[f] for f in ("speed_dev", "acc_sq")] == pytest.approx(mean)
        assert [pop.styles[0].std[f] for f in ("speed_dev", "acc_sq")] == pytest.approx(std)


def test_a_map_calibration_drives_the_recordings_roundabout_with_its_route_shares(tmp_path):
    pytest.importorskip("sumolib")
    pytest.importorskip("lanelet2")
    from pirl_sim.io.lanelet2_map import write_map
    from pirl_sim.scenarios.highway.scenario import load_scenario as load_highway
    from pirl_sim.scenarios.lanelet_graph import map_routes
    from pirl_sim.scenarios.sumo.network import RoundaboutSpec, build_network, lane_graph
    from pirl_sim.scenarios.sumo.scenario import load_scenario as load_sumo

    write_map(*lane_graph(build_network(RoundaboutSpec(), tmp_path / "net").net), tmp_path / "map.osm")
    routes = [rid for rid, _ in map_routes(tmp_path / "map.osm")]
    cal = _calibration(map_path=str(tmp_path / "map.osm"), route_counts={routes[0]: 3, routes[2]: 1})
    path = tmp_path / "calibrated.toml"
    path.write_text(cal.scenario_toml("f.csv"))  # road="map" by default
    config = load_sumo(path)
    assert config.lanelet_map == str((tmp_path / "map.osm").resolve())
    assert config.route_weights == {routes[0]: 3.0, routes[2]: 1.0} and set(config.routes) == set(routes)
    highway = load_highway(path)  # the same file drives highway-env on the map's road
    assert highway.lanelet_map == config.lanelet_map and highway.route_weights == config.route_weights
    assert set(highway.route_ids()) == set(routes)
    with pytest.raises(ValueError, match="road='map' needs the calibration's map_path and route_counts"):
        _calibration().scenario_toml()
    with pytest.raises(ValueError, match="road must be one of"):
        cal.scenario_toml(road="ft")


def test_an_interacting_calibration_writes_drivers_who_weigh_the_gaps(tmp_path):
    """With the interaction weights (`FREE_INTERACTING`) the written styles weigh headway and yielding, and the
    simulators read the population as one of drivers who interact."""
    pytest.importorskip("sumolib")
    from pirl_sim.scenarios.highway.scenario import load_scenario as load_highway
    from pirl_sim.scenarios.sumo.scenario import load_scenario as load_sumo

    rng = np.random.default_rng(4)
    log_mean = np.array([[1.0, -1.0, 0.5, 2.0], [-2.0, 1.0, -1.0, 0.0]])
    cal = _calibration(log_weights=np.repeat(log_mean, 6, axis=0) + rng.normal(0, 0.1, (12, 4)),
                       at_bound=np.zeros((12, 4), bool), style_log_mean=log_mean,
                       style_log_var=np.full((2, 4), 0.01), features=FREE_INTERACTING,
                       identified=np.arange(48).reshape(12, 4) % 5 > 0)
    text = cal.scenario_toml("f.csv", road="ring")
    assert "headway 0%, yielding 0%" in text
    assert "# cars whose data determine the weight: speed_dev 9, acc_sq 9, headway 10, yielding 10" in text
    path = tmp_path / "calibrated.toml"
    path.write_text(text)
    for load in (load_sumo, load_highway):
        pop = load(path).population
        assert pop.interacting and pop.feature_names == ("speed_dev", "acc_sq", "jerk_sq", "headway", "yielding")
        mean, _ = lognormal_moments(log_mean[1], np.full(4, 0.01))  # the larger share first
        assert [pop.styles[0].mean[f] for f in FREE_INTERACTING] == pytest.approx(mean)
    with pytest.raises(ValueError, match=r"as many as the cars \(12\), over 4 features"):
        _calibration(features=FREE_INTERACTING)  # two weights per car
    with pytest.raises(ValueError, match="features must be"):
        _calibration(features=("speed_dev", "headway"))
    with pytest.raises(ValueError, match=r"identified must be None or of shape \(12, 2\)"):
        _calibration(identified=np.ones((12, 4), bool))


def test_the_deconvolved_styles_cluster_on_the_weights_the_cars_show():
    """Two styles apart in the first weight; the second weight is shown by a third of the cars only (the others
    measured with an unknown error and a value far off): the mixture still finds two styles with the shown means."""
    from pirl_sim.experiments.recovery_styles import UNKNOWN_SE

    rng = np.random.default_rng(5)
    truth = np.repeat([[1.0, 0.5], [-2.0, 2.0]], 60, axis=0)
    x = truth + rng.normal(0, 0.1, truth.shape)
    se = np.full(x.shape, 0.05)
    hidden = rng.random(len(x)) > 1 / 3
    x[hidden, 1], se[hidden, 1] = rng.uniform(-20, 20, hidden.sum()), UNKNOWN_SE
    mix, bic = fit_styles_deconvolved(x, se, max_styles=3, seed=0)
    assert mix.n_components == 2 and min(bic, key=bic.get) == 2
    found = mix.means[np.argsort(mix.means[:, 0])]
    np.testing.assert_allclose(found, [[-2.0, 2.0], [1.0, 0.5]], atol=0.15)


def test_a_style_whose_members_show_no_interaction_weight_takes_that_of_the_cars_that_do():
    from pirl_sim.experiments.calibrate import MIN_DETERMINED, _determined_styles
    from pirl_sim.experiments.recovery_styles import UNKNOWN_SE

    rng = np.random.default_rng(6)
    x = np.column_stack([np.repeat([1.0, -2.0], 40), np.zeros(80), rng.normal(0.7, 0.2, 80), np.zeros(80)])
    x[:, 0] += rng.normal(0, 0.1, 80)
    se = np.full(x.shape, 0.05)
    known = np.ones(x.shape, bool)
    known[40:, 2] = False  # the second style's cars never come near a vehicle ahead
    known[:, 3] = False
    se[~known] = UNKNOWN_SE
    mix, _ = fit_styles_deconvolved(x[:, :3], se[:, :3], max_styles=2, seed=0)
    share, mean, var = _determined_styles(mix, x[:, :3], se[:, :3], known[:, :3], FREE_INTERACTING[:3])
    second = int(np.argmin(mean[:, 0]))
    assert MIN_DETERMINED > 0 and mean[second, 2] == pytest.approx(x[:40, 2].mean())
    assert var[second, 2] == pytest.approx(x[:40, 2].var())
    with pytest.raises(ValueError, match="no recorded car's data determine the yielding weight"):
        mix4, _ = fit_styles_deconvolved(x, se, max_styles=1, seed=0)
        _determined_styles(mix4, x, se, known, FREE_INTERACTING)


def test_a_style_beyond_the_populations_largest_weight_is_shifted_down_to_it():
    from pirl_sim.population import STYLE_VALUE_MAX

    cal = _calibration(style_log_mean=np.array([[1.0, -1.0], [-2.0, 19.0]]))
    big = cal.styles()[0]  # the larger share first
    assert max(big["mean"]["acc_sq"], big["std"]["acc_sq"]) == pytest.approx(STYLE_VALUE_MAX)
    assert cal.population().styles[0].mean["acc_sq"] <= STYLE_VALUE_MAX


def test_a_calibration_checks_its_shapes():
    with pytest.raises(ValueError, match="as many as the cars"):
        _calibration(cars=(("f.csv", 1),))
    with pytest.raises(ValueError, match="must hold 2 styles"):
        _calibration(style_log_var=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="finite"):
        _calibration(log_weights=np.full((12, 2), np.nan))


@pytest.mark.parametrize("kwargs, message", [
    ({"max_styles": 0}, "max_styles must be an integer >= 1, got 0"),
    ({"stride": 1.5}, "stride must be an integer >= 1, got 1.5"),
    ({"min_tracks": 1}, "min_tracks must be an integer >= 2, got 1"),
    ({"seed": -1}, "seed must be a non-negative integer, got -1"),
    ({"desired_speed": (0.0, 13.9)}, r"desired_speed must be 'likelihood', 'speeds' or \(a_lat, v_max\)"),
    ({"desired_speed": "fitted"}, r"desired_speed must be 'likelihood', 'speeds' or \(a_lat, v_max\)"),
    ({"drivers": {"horizon": 30}}, "drivers must be an MpcDriverConfig, got dict"),
    ({"interaction": "yes"}, "interaction must be True or False, got 'yes'"),
])
def test_bad_parameters_are_refused_before_reading(tmp_path, kwargs, message):
    error = TypeError if "drivers" in kwargs or "interaction" in kwargs else ValueError
    with pytest.raises(error, match=message):
        calibrate([tmp_path / "missing.csv"], tmp_path / "missing.osm", **kwargs)
    with pytest.raises(ValueError, match="at least one track file"):
        calibrate([], tmp_path / "missing.osm")


def test_tracks_off_the_map_leave_too_few_cars_and_the_error_says_so(real_like, tmp_path):
    """A recording that does not match the map: its cars (on a straight lane far from the ring) are not usable."""
    pytest.importorskip("sumolib")
    from pirl_sim.io.lanelet2_map import write_map
    from pirl_sim.scenarios.sumo.network import RoundaboutSpec, build_network, lane_graph

    write_map(*lane_graph(build_network(RoundaboutSpec(center=(500.0, 500.0)), tmp_path / "net").net),
              tmp_path / "ring.osm")
    with pytest.raises(ValueError, match=r"no usable track in 1 files .skipped: .'no route on the map': 6"):
        calibrate([real_like / "vehicle_tracks_000.csv"], tmp_path / "ring.osm")


@needs_sample
def test_a_map_without_a_roundabout_is_refused_before_the_tracks_are_read(tmp_path):
    pytest.importorskip("lanelet2")
    with pytest.raises(ValueError, match="no roundabout .no lanelets form a cycle in its routing graph"):
        calibrate([tmp_path / "unread.csv"], SAMPLE_MAP)


def test_the_command_refuses_a_missing_map_with_exit_2(tmp_path, real_like, capsys):
    from pirl_sim.cli import main

    rc = main(["calibrate", "--tracks", str(real_like), "--map", str(tmp_path / "none.osm"), "--out",
               str(tmp_path / "c.toml"), "--quiet"])
    assert rc == 2 and "--map" in capsys.readouterr().err and not (tmp_path / "c.toml").exists()


@pytest.mark.slow
def test_the_weights_of_simulated_drivers_that_drove_on_their_own_come_back(sumo_recording, tmp_path):
    """A SUMO recording read as real data (no sidecars): the desired speed of greatest likelihood is the drivers'
    (the speeds' own fit, its start, is 15 % low); the cars whose every step was their own MPC's get their
    weights back within 0.05 in log; cars the simulator overrode on some steps within 0.1 (median). What the
    cost cannot explain (overrides the recording does not show) is the calibration's limit."""
    from pirl_sim.cli import main
    from pirl_sim.scenarios.sumo.scenario import load_scenario

    real = tmp_path / "real"
    real.mkdir()
    for name in ("vehicle_tracks_000.csv", "map.osm"):
        shutil.copy(sumo_recording / name, real / name)
    cal = calibrate([real / "vehicle_tracks_000.csv"], real / "map.osm", min_tracks=5)
    assert cal.a_lat == pytest.approx(1.8, rel=0.02) and cal.v_max == pytest.approx(13.9, rel=0.02)
    truth = pd.read_csv(sumo_recording / "ground_truth.csv").set_index("track_id")
    steps = pd.read_csv(sumo_recording / "driver_steps.csv").groupby("track_id")[["commanded", "overridden"]].mean()
    err = {}
    for (_, track), log_w in zip(cal.cars, cal.log_weights):
        row = truth.loc[track]
        if row["is_pirl"]:
            err[track] = np.abs(log_w - np.log([row["theta_speed_dev"], row["theta_acc_sq"]])).max()
    own = steps.index[(steps["commanded"] == 1) & (steps["overridden"] == 0)]
    mostly = steps.index[(steps["commanded"] >= 0.9) & (steps["overridden"] <= 0.2)]
    assert len(own) >= 2 and max(err[t] for t in own) < 0.05
    assert len(mostly) >= 5 and np.median([err[t] for t in mostly]) < 0.1
    assert 1 <= cal.n_styles <= 4 and cal.depart_rate > 0
    out = tmp_path / "calibrated.toml"
    assert main(["calibrate", "--tracks", str(real), "--map", str(real / "map.osm"), "--out", str(out),
                 "--stride", "10", "--max-styles", "2", "--desired-speed", "speeds", "--quiet"]) == 0
    config = load_scenario(out)
    assert 1 <= len(config.population.styles) <= 2 and config.drivers.horizon == 30
    assert config.lanelet_map == str((real / "map.osm").resolve()) and config.route_weights
    assert sum(config.route_weights.values()) == sum(cal.route_counts.values()) <= len(truth)


@pytest.mark.slow
def test_drivers_who_interact_read_as_real_data_keep_their_free_weights(tmp_path):
    """SUMO drivers who interact (`INTERACTING_POPULATION`'s two styles, 24 of them, one every 2 s), read as real
    data with the interaction weights: speed_dev and acc_sq come back (median |log error| < 0.1); an interaction
    weight counts only for the cars whose data determine it, and the written population interacts."""
    pytest.importorskip("libsumo")
    import dataclasses

    from pirl_sim.scenarios.population_config import INTERACTING_POPULATION
    from pirl_sim.scenarios.sumo.scenario import SumoScenarioConfig, load_scenario, run_sumo_scenario

    pop = dataclasses.replace(INTERACTING_POPULATION, n_vehicles=24, depart_interval=2.0, background_share=0.0)
    config = SumoScenarioConfig(population=pop)
    run_sumo_scenario(config, seed=1, out_dir=tmp_path / "run")
    real = tmp_path / "real"
    real.mkdir()
    for name in ("vehicle_tracks_000.csv", "map.osm"):
        shutil.copy(tmp_path / "run" / name, real / name)
    cal = calibrate([real / "vehicle_tracks_000.csv"], real / "map.osm", min_tracks=5, interaction=True,
                    desired_speed=(config.drivers.a_lat, config.drivers.v_max))
    assert cal.features == FREE_INTERACTING and cal.identified is not None
    truth = pd.read_csv(tmp_path / "run" / "ground_truth.csv").set_index("track_id")
    true_log = np.log([[truth.loc[t, f"theta_{f}"] for f in cal.features] for _, t in cal.cars])
    err = np.abs(cal.log_weights - true_log)
    assert np.median(err[:, :2], axis=0).max() < 0.1
    assert cal.identified[:, :2].all() and 0 < cal.identified[:, 2:].sum() < cal.identified[:, 2:].size
    out = tmp_path / "calibrated.toml"
    out.write_text(cal.scenario_toml("run"))
    written = load_scenario(out).population
    assert written.interacting and len(written.styles) == cal.n_styles
