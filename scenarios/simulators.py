"""The scenario entry points of each simulator, looked up by name: what the command line and the experiments that
run either simulator (``"sumo"`` or ``"highway"``) share::

    from pirl_sim.scenarios.simulators import simulator_scenarios

    sim = simulator_scenarios("highway")            # imports highway-env's scenario module only now
    config = sim.load("calibrated.toml")            # or sim.from_dict(table, population=...), sim.config(...)
    sim.run(config, 0, out_dir="/tmp/run_0")
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["SIMULATORS", "SimulatorScenarios", "simulator_scenarios"]

#: The simulators whose scenarios a TOML file describes.
SIMULATORS = ("sumo", "highway")


@dataclass(frozen=True)
class SimulatorScenarios:
    """One simulator's scenario functions.

    Attributes
    ----------
    name : str                 ``"sumo"`` or ``"highway"``
    config : type              its scenario configuration (`~.sumo.scenario.SumoScenarioConfig`,
                               `~.highway.scenario.HighwayScenarioConfig`)
    load : callable            ``load(path, *, population=None)`` -> configuration, from a TOML file
    from_dict : callable       ``from_dict(table, *, source=..., population=None)`` -> configuration
    run : callable             ``run(config, seed, *, out_dir=None)`` -> the scenario's result, written to ``out_dir``
    """

    name: str
    config: type
    load: Callable
    from_dict: Callable
    run: Callable


def simulator_scenarios(simulator: str) -> SimulatorScenarios:
    """The scenario functions of ``simulator`` (one of `SIMULATORS`), its module imported when asked for.

    Raises
    ------
    ValueError
        For any other name.
    """
    if simulator == "sumo":
        from .sumo import scenario as sumo

        return SimulatorScenarios("sumo", sumo.SumoScenarioConfig, sumo.load_scenario, sumo.scenario_from_dict,
                                  sumo.run_sumo_scenario)
    if simulator == "highway":
        from .highway import scenario as highway

        return SimulatorScenarios("highway", highway.HighwayScenarioConfig, highway.load_scenario,
                                  highway.scenario_from_dict, highway.run_highway_scenario)
    raise ValueError(f"simulator must be one of {SIMULATORS}, got {simulator!r}")
