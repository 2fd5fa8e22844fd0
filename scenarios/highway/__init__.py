"""highway-env roundabout scenarios (optional extra ``pirl_sim[highway]``): PIRL drivers in highway-env.

The SUMO scenario's populations (:mod:`pirl_sim.scenarios.population_config`) on highway-env's
``roundabout-generic-v0`` road, recorded through the same writer
(:func:`pirl_sim.scenarios.recording.write_recording`):

- ``network``: highway-env's roundabout (one ring lane), the route catalogue (the SUMO scenario's route
  ids), reference paths and the Lanelet2 lanes;
- :func:`plan_population` (from :mod:`pirl_sim.scenarios.planning`, shared with the SUMO scenario): the
  population plan;
- ``vehicles``: highway-env vehicle classes that follow one route (PIRL, background IDM, ego);
- ``traffic``: :class:`RoundaboutTraffic`, a highway-env ``Road`` that runs the traffic: PIRL drivers'
  batched MPC, background IDM, leaders across lane segments, yielding at entries, exits, crashes;
- ``scenario``: :func:`run_highway_scenario` (plan, simulate, record) and :func:`load_highway_run`;
- ``cli``: ``pirl-sim simulate highway``.

The gymnasium environment built on the same traffic is :mod:`pirl_sim.envs` (``pirl_sim/Roundabout-v0``).
highway-env is imported only when a function needs it.
"""

from __future__ import annotations

__all__ = [
    "ARMS",
    "RoundaboutGeometry",
    "RouteLanes",
    "build_network",
    "route_catalogue",
    "route_set",
    "lane_graph",
    "plan_population",
    "random_streams",
    "STEP_LENGTH",
    "DriverConfig",
    "TrafficRules",
    "RoundaboutTraffic",
    "idm_acceleration",
    "PirlVehicle",
    "BackgroundVehicle",
    "EgoVehicle",
    "ROUTE_IDS",
    "HighwayScenarioConfig",
    "HighwayScenarioResult",
    "scenario_from_dict",
    "load_scenario",
    "run_highway_scenario",
    "load_highway_run",
]

_LAZY = {
    **{name: "network" for name in ("ARMS", "RoundaboutGeometry", "RouteLanes", "build_network",
                                     "route_catalogue", "route_set", "lane_graph")},
    **{name: ".planning" for name in ("plan_population", "random_streams")},  # pirl_sim.scenarios.planning
    **{name: "traffic" for name in ("STEP_LENGTH", "DriverConfig", "TrafficRules", "RoundaboutTraffic",
                                     "idm_acceleration")},
    **{name: "vehicles" for name in ("PirlVehicle", "BackgroundVehicle", "EgoVehicle")},
    **{name: "scenario" for name in ("ROUTE_IDS", "HighwayScenarioConfig", "HighwayScenarioResult",
                                     "scenario_from_dict", "load_scenario",
                                     "run_highway_scenario", "load_highway_run")},
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
