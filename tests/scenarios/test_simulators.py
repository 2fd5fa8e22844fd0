"""The simulators' scenario entry points by name (pirl_sim.scenarios.simulators)."""

import pytest

from pirl_sim.scenarios.population_config import DEFAULT_POPULATION
from pirl_sim.scenarios.simulators import SIMULATORS, simulator_scenarios


@pytest.mark.parametrize("name", SIMULATORS)
def test_each_simulator_builds_its_own_configuration_from_a_table(name):
    sim = simulator_scenarios(name)
    assert sim.name == name
    config = sim.from_dict({}, population=DEFAULT_POPULATION)
    assert isinstance(config, sim.config)
    assert config.population == DEFAULT_POPULATION
    assert type(sim.config(population=DEFAULT_POPULATION)) is sim.config


def test_an_unknown_simulator_is_named_in_the_error():
    with pytest.raises(ValueError, match="'carla'"):
        simulator_scenarios("carla")
