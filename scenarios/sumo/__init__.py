"""SUMO roundabout scenarios through libsumo (optional extra ``pirl_sim[sumo]``).

``network`` builds parametric roundabouts (plain XML -> netconvert) and reference paths along their
routes; ``runner`` simulates them with libsumo (or TraCI), records every vehicle every step and lets a
controller drive chosen vehicles (the PIRL drivers are :class:`pirl_sim.scenarios.drivers.PirlDrivers`,
shared with the highway-env scenario: one batched MPC call per step); ``scenario`` plans a population,
runs it and records it (:func:`run_sumo_scenario`); ``cli`` is ``pirl-sim simulate sumo``. SUMO itself
(sumolib, libsumo, traci) is imported only when a function needs it.
"""

from .network import (
    NetworkFiles,
    RoundaboutSpec,
    build_network,
    lane_graph,
    load_net,
    route_centerline,
    route_set,
    route_edges,
    route_id,
    routes,
    validate_route,
)
from .runner import (
    BACKENDS,
    COLLISION_ACTIONS,
    RECORD_COLUMNS,
    SPEED_MODE_ALL_CHECKS,
    SUMMARY_COLUMNS,
    BatchController,
    ConstantSpeed,
    Controller,
    Observation,
    SumoRecording,
    SumoRun,
    VehicleSpec,
    VehicleState,
    run_in_subprocess,
    simulate,
    speed_mode,
    sumo_angle_to_psi,
    sumo_command,
)

__all__ = [
    "NetworkFiles",
    "RoundaboutSpec",
    "build_network",
    "load_net",
    "route_centerline",
    "route_edges",
    "route_id",
    "routes",
    "validate_route",
    "BACKENDS",
    "RECORD_COLUMNS",
    "SPEED_MODE_ALL_CHECKS",
    "SUMMARY_COLUMNS",
    "ConstantSpeed",
    "Controller",
    "Observation",
    "SumoRecording",
    "SumoRun",
    "VehicleSpec",
    "VehicleState",
    "run_in_subprocess",
    "simulate",
    "speed_mode",
    "sumo_angle_to_psi",
    "sumo_command",
    "BatchController",
    "COLLISION_ACTIONS",
    "lane_graph",
    "route_set",
    "STEP_LENGTH",
    "DEFAULT_NETWORK",
    "DriverConfig",
    "SumoScenarioConfig",
    "SumoScenarioResult",
    "scenario_from_dict",
    "load_scenario",
    "plan_vehicles",
    "run_sumo_scenario",
    "run_to_directory",
    "load_sumo_run",
]

# scenario pulls in the driver model and the MPC: loaded on first use, so that importing the
# package (e.g. for the command line's parser) stays light
_LAZY = {
    **{name: "scenario" for name in ("STEP_LENGTH", "DEFAULT_NETWORK", "DriverConfig",
                                     "SumoScenarioConfig", "SumoScenarioResult", "load_scenario",
                                     "load_sumo_run", "plan_vehicles",
                                     "run_sumo_scenario", "run_to_directory", "scenario_from_dict")},
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
