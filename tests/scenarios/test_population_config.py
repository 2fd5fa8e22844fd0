"""PopulationConfig: validation, TOML with unknown keys rejected, the embedded default, seeded draws, bounds on
vehicles, noise and style weights, and fuzzed configs (hypothesis)."""

from __future__ import annotations

import dataclasses
import math
import tomllib

import numpy as np
import pytest

from pirl_sim.cli import main
from pirl_sim.population import Population
from pirl_sim.scenarios.passage import THREE_STYLES
from pirl_sim.scenarios.population_config import (
    DEFAULT_POPULATION,
    DEFAULT_POPULATION_TOML,
    FEATURE_NAMES,
    PRESET_STYLES,
    Arrivals,
    PopulationConfig,
    StyleConfig,
    load_population,
    population_from_dict,
    population_from_toml,
)

pytest.importorskip("hypothesis")

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from toml_fuzz import FUZZ, mutated_mapping, read_or_error_naming_it  # noqa: E402


def test_default_is_the_papers_three_styles_with_20_percent_background():
    pop = DEFAULT_POPULATION
    assert pop.style_names == tuple(s.name for s in THREE_STYLES)
    for cfg, style in zip(pop.styles, THREE_STYLES):
        assert dict(cfg.mean) == {k: v for k, v in style.mean.items() if k != "jerk_sq"}
        assert dict(cfg.std) == dict(style.std)
    assert pop.background_share == 0.2
    assert pop.n_background == 16 and pop.n_pirl == 64
    assert pop == PopulationConfig()  # the embedded TOML and the dataclass defaults agree
    assert population_from_toml(DEFAULT_POPULATION_TOML) == pop
    assert pop.depart_rate == pytest.approx(3600.0 / pop.depart_interval)


def test_to_dict_round_trips():
    cov_style = StyleConfig("c", 2.0, {"speed_dev": 1.0, "acc_sq": 1.0},
                            cov={"speed_dev": {"speed_dev": 0.04, "acc_sq": 0.01}, "acc_sq": {"acc_sq": 0.04}})
    pop = PopulationConfig(styles=(cov_style, PRESET_STYLES["no preference"]), background_share=0.5,
                           n_vehicles=7, depart_interval=3.0, arrivals="poisson", control_noise=0.2)
    assert population_from_dict(pop.to_dict()) == pop
    np.testing.assert_allclose(cov_style.covariance(), [[0.04, 0.01], [0.01, 0.04]])


def test_toml_file_with_presets_rates_and_cov(tmp_path):
    path = tmp_path / "pop.toml"
    path.write_text("""
n_vehicles = 12
depart_rate = 1200.0          # [veh/h]
arrivals = "poisson"
background_share = 0.25

[[styles]]
preset = "tracks desired speed"
weight = 2.0

[[styles]]
name = "correlated"
mean = { speed_dev = 1.0, acc_sq = 1.0, jerk_sq = 1.0 }
cov = { speed_dev = { speed_dev = 0.04, acc_sq = 0.01 }, acc_sq = { acc_sq = 0.04 } }
""")
    pop = load_population(path)
    assert pop.depart_interval == pytest.approx(3.0)
    assert pop.arrivals is Arrivals.POISSON
    assert pop.styles[0].name == "tracks desired speed" and pop.styles[0].weight == 2.0
    assert pop.styles[0].mean == PRESET_STYLES["tracks desired speed"].mean
    assert pop.n_background == 3


@pytest.mark.parametrize("text, match", [
    ("n_vehicle = 3", r"unknown key\(s\) 'n_vehicle'; valid keys: styles, background_share, n_vehicles"),
    ('[[styles]]\nname = "a"\nmean = { speed_dev = 1.0, acc_sq = 1.0 }\nsigma = 1.0',
     r"styles\[0\]: unknown key\(s\) 'sigma'; valid keys: name, preset, weight, mean, std, cov"),
    ('[[styles]]\nname = "a"\nmean = { speed_dev = 1.0, acc_sq = 1.0, jerk = 1.0 }',
     r"unknown feature name\(s\) 'jerk'; allowed: speed_dev, acc_sq, headway, yielding, jerk_sq"),
    ('[[styles]]\nname = "a"\nmean = { speed_dev = 1.0, acc_sq = 1.0 }\nstd = { speed = 0.1 }',
     r"std: unknown feature name\(s\) 'speed'"),
    ('[[styles]]\npreset = "aggressive"',
     r"unknown style name 'aggressive' for preset; known styles: 'tracks desired speed'"),
    ('[[styles]]\nname = "a"\nmean = { speed_dev = 1.0, acc_sq = 1.0 }\n'
     'cov = { speed_dev = { speed_dev = 0.04, acc_sq = 0.05 }, acc_sq = { acc_sq = 0.04 } }',
     r"cov must be positive definite, its smallest eigenvalue is -0.01"),
    ('[[styles]]\nname = "a"\nmean = { speed_dev = 1.0, acc_sq = 1.0 }\n'
     'cov = { speed_dev = { speed_dev = 0.04, acc_sq = 0.01 }, acc_sq = { speed_dev = 0.02, acc_sq = 0.04 } }',
     "cov is not symmetric"),
    ('[[styles]]\nname = "a"\nmean = { speed_dev = 1.0, acc_sq = 1.0 }\ncov = { speed_dev = { speed_dev = 0.04 } }',
     r"cov misses the entry for \('speed_dev', 'acc_sq'\)"),
    ('[[styles]]\nname = "a"\nmean = { speed_dev = 1.0, acc_sq = 1.0, jerk_sq = 2.0 }',
     "the reference feature 'jerk_sq' is fixed at 1"),
    ('[[styles]]\nname = "a"\nmean = { speed_dev = 1.0 }', r"mean misses feature\(s\) 'acc_sq'"),
    ('[[styles]]\nname = "a"\nmean = { speed_dev = -1.0, acc_sq = 1.0 }', r"mean\['speed_dev'\] must be > 0"),
    ("n_vehicles = 0", "n_vehicles must be >= 1, got 0"),
    ("background_share = 1.5", r"background_share must be in \[0, 1\]"),
    ("depart_interval = 0.0", "depart_interval must be > 0 s"),
    ("depart_interval = 2.0\ndepart_rate = 100.0", "not both"),
    ('arrivals = "bursty"', "arrivals must be one of"),
    ("control_noise = -0.1", "control_noise must be >= 0"),
    ("styles = []", "a population needs at least one style"),
    ('[[styles]]\npreset = "no preference"\n[[styles]]\npreset = "no preference"', "style names must be unique"),
    ("n_vehicles = ", "not valid TOML"),
])
def test_bad_configs_raise_value_errors_naming_the_problem(text, match):
    with pytest.raises(ValueError, match=match):
        population_from_toml(text)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="population config not found"):
        load_population(tmp_path / "nope.toml")


def test_config_is_frozen_and_style_mappings_are_read_only():
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULT_POPULATION.n_vehicles = 3
    with pytest.raises(TypeError):
        DEFAULT_POPULATION.styles[0].mean["speed_dev"] = 9.0


def test_sample_weights_are_seeded_positive_and_follow_the_styles():
    pop = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=3000)
    theta, style = pop.sample_weights(3000, np.random.default_rng(0))
    theta2, style2 = pop.sample_weights(3000, np.random.default_rng(0))
    np.testing.assert_array_equal(theta, theta2)
    np.testing.assert_array_equal(style, style2)
    assert theta.shape == (3000, len(FEATURE_NAMES)) and np.all(theta > 0)
    np.testing.assert_array_equal(theta[:, 2], 1.0)
    for j, cfg in enumerate(pop.styles):
        mine = theta[style == j]
        assert abs(len(mine) / 3000 - 1 / 3) < 0.04
        for k, name in enumerate(("speed_dev", "acc_sq")):
            assert mine[:, k].mean() == pytest.approx(cfg.mean[name], rel=0.02)
            assert mine[:, k].std() == pytest.approx(cfg.std[name], rel=0.1)


def test_population_checks_the_feature_set():
    from pirl_sim.model import synthetic_model

    with pytest.raises(ValueError, match="features must be"):
        DEFAULT_POPULATION.population(synthetic_model().features)


def test_depart_times():
    reg = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=5, depart_interval=2.5)
    np.testing.assert_allclose(reg.depart_times(np.random.default_rng(0)), [0.0, 2.5, 5.0, 7.5, 10.0])
    poi = dataclasses.replace(reg, n_vehicles=4000, arrivals="poisson")
    t = poi.depart_times(np.random.default_rng(1))
    assert t[0] == 0.0 and np.all(np.diff(t) >= 0)
    assert np.diff(t).mean() == pytest.approx(2.5, rel=0.05)


def test_population_object_matches_the_config():
    from pirl_sim.scenarios.population_config import _naming_features

    pop = DEFAULT_POPULATION.population(_naming_features())
    assert isinstance(pop, Population) and pop.style_names == DEFAULT_POPULATION.style_names
    mean, cov = pop.styles[0].moments(pop.features)
    np.testing.assert_allclose(mean, [3.0, 0.3, 1.0])
    np.testing.assert_allclose(np.diag(cov), [0.09, 0.0009, 0.0])


def test_n_vehicles_beyond_the_limit_is_an_error_not_a_memory_error(tmp_path, capsys):
    from pirl_sim.scenarios.population_config import MAX_VEHICLES, PopulationConfig

    with pytest.raises(ValueError, match=rf"n_vehicles must be >= 1 and <= {MAX_VEHICLES}, got 100000000000"):
        PopulationConfig(n_vehicles=100_000_000_000)
    assert main(["simulate", "highway", "--n-vehicles", "100000000000", "--quiet",
                 "--out", str(tmp_path / "o")]) == 2
    assert "n_vehicles must be >= 1 and <=" in capsys.readouterr().err


def test_control_noise_beyond_the_jerk_bound_is_rejected_up_front():
    from pirl_sim.scenarios.population_config import population_from_toml

    with pytest.raises(ValueError, match=r"pop.toml: control_noise must be >= 0 and <= 8 m/s\^3.*got 1000000.0"):
        population_from_toml("control_noise = 1e6\n", source="pop.toml")
    assert population_from_toml("control_noise = 8.0\n").control_noise == 8.0


POPULATION_KEYS = ["n_vehicles", "depart_interval", "depart_rate", "arrivals", "background_share", "control_noise",
                   "styles"]


@st.composite
def population_dicts(draw):
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION_TOML

    data = tomllib.loads(DEFAULT_POPULATION_TOML)
    if draw(st.booleans()):
        mutated_mapping(draw, data, POPULATION_KEYS)
    else:
        style = data["styles"][draw(st.integers(0, 2))]
        target = draw(st.sampled_from(["style", "mean", "std"]))
        if target == "style":
            mutated_mapping(draw, style, ["name", "weight", "mean", "std", "cov", "preset"])
        else:
            mutated_mapping(draw, style[target], ["speed_dev", "acc_sq", "jerk_sq"])
    return data


@FUZZ
@given(data=population_dicts())
def test_fuzz_population_config(data):
    from pirl_sim.scenarios.population_config import population_from_dict

    try:
        pop = population_from_dict(data, source="fuzz.toml")
    except (ValueError, TypeError) as exc:
        assert "fuzz.toml" in str(exc)
        return
    # accepted: the values are the given ones, unchanged
    for key in ("n_vehicles", "background_share", "control_noise"):
        if key in data:
            assert getattr(pop, key) == data[key] and not isinstance(data[key], bool)
    if "depart_interval" in data:
        assert pop.depart_interval == data["depart_interval"]
    assert 1 <= pop.n_vehicles <= 100_000 and math.isfinite(pop.depart_interval) and pop.depart_interval > 0
    weights, styles = pop.sample_weights(5, np.random.default_rng(0))
    assert np.isfinite(weights).all() and (weights > 0).all()


@FUZZ
@given(data=st.binary(max_size=200))
def test_fuzz_population_toml_bytes(tmp_path_factory, data):
    from pirl_sim.scenarios.population_config import load_population

    path = tmp_path_factory.mktemp("toml") / "population.toml"
    path.write_bytes(data)
    read_or_error_naming_it(load_population, path)  # an empty or comment-only file is the default population: allowed


def test_population_config_bounds_style_weights():
    from pirl_sim.scenarios.population_config import StyleConfig

    with pytest.raises(ValueError, match=r"style 'a': weight must be in \(0, 1e\+06\], got 1e\+300"):
        StyleConfig("a", 1e300, {"speed_dev": 1.0, "acc_sq": 1.0})
    with pytest.raises(ValueError, match=r"mean\['acc_sq'\] must be in \(0, 1e\+06\]"):
        StyleConfig("a", 1.0, {"speed_dev": 1.0, "acc_sq": 1e300})


_INTERACTING = """
[[styles]]
name = "close follower"
mean = { speed_dev = 3.0, acc_sq = 0.3, headway = 3.0, yielding = 1.0 }
std = { speed_dev = 0.3, headway = 0.3 }

[[styles]]
name = "keeps its distance"
mean = { speed_dev = 0.3, acc_sq = 0.3, headway = 30.0, yielding = 10.0 }
cov = { speed_dev = { speed_dev = 0.01 }, acc_sq = { acc_sq = 0.001, speed_dev = 0.0 }, headway = { headway = 4.0, speed_dev = 0.0, acc_sq = 0.0 }, yielding = { yielding = 1.0, headway = 0.0, speed_dev = 0.0, acc_sq = 0.0 } }
"""


def test_styles_that_weigh_headway_make_drivers_who_interact():
    pop = population_from_toml(_INTERACTING)
    assert pop.interacting and pop.feature_names == ("speed_dev", "acc_sq", "jerk_sq", "headway", "yielding")
    assert not DEFAULT_POPULATION.interacting
    theta, style = pop.sample_weights(400, np.random.default_rng(3))
    assert theta.shape == (400, 5) and np.all(theta > 0) and np.all(theta[:, 2] == 1.0)
    for s, mean in ((0, 3.0), (1, 30.0)):
        assert np.mean(theta[style == s, 3]) == pytest.approx(mean, rel=0.05)
    assert np.std(theta[style == 1, 3]) == pytest.approx(2.0, rel=0.2)
    assert population_from_dict(pop.to_dict()) == pop
    np.testing.assert_array_equal(pop.sample_weights(5, np.random.default_rng(1))[0],
                                  pop.sample_weights(5, np.random.default_rng(1))[0])


@pytest.mark.parametrize("text, match", [
    (_INTERACTING + '[[styles]]\nname = "free"\nmean = { speed_dev = 1.0, acc_sq = 1.0 }\n',
     r"every style weighs headway, yielding or none does: the style\(s\) \['close follower', 'keeps its distance'\]"),
    (_INTERACTING.replace(", headway = 3.0, yielding = 1.0 }", " }"), "std of 'headway', which the mean does not weigh"),
    (_INTERACTING.replace(", yielding = 1.0 }", " }"), "weighs headway and yielding; the mean gives only headway"),
    (_INTERACTING.replace("headway = 3.0,", "headway = -1.0,"), r"mean\['headway'\] must be > 0"),
    (_INTERACTING.replace("headway = 3.0,", "headwayy = 1.0,"), "unknown feature name.*'headwayy'"),
])
def test_bad_interaction_weights_are_named(text, match):
    with pytest.raises(ValueError, match=match):
        population_from_toml(text)
