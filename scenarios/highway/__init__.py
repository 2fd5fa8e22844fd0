"""highway-env roundabout scenarios (optional extra ``pirl_sim[highway]``): PIRL drivers in highway-env.

The SUMO scenario's populations (:mod:`pirl_sim.scenarios.population_config`) on highway-env's
``roundabout-generic-v0`` road, recorded through the same writer: ``network`` (the road, routes, reference paths
and lanes), ``vehicles`` (route-following vehicle classes), ``traffic`` (:class:`RoundaboutTraffic`, the road that
runs the traffic), ``scenario`` (:func:`run_highway_scenario`, :func:`load_highway_run`) and
:func:`plan_population` (shared with the SUMO scenario). The gymnasium environment on the same traffic is
:mod:`pirl_sim.envs`. highway-env is imported only when a function needs it.
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
