"""SUMO roundabout scenarios through libsumo (optional extra ``pirl_sim[sumo]``).

``network`` builds parametric roundabouts (plain XML -> netconvert) and reference paths along their
routes; ``runner`` simulates them with libsumo (or TraCI), records every vehicle every step and lets a
controller drive chosen vehicles. SUMO itself (sumolib, libsumo, traci) is imported only when a function
needs it.
"""

from .network import (
    NetworkFiles,
    RoundaboutSpec,
    build_network,
    load_net,
    route_centerline,
    route_edges,
    route_id,
    routes,
    validate_route,
)
from .runner import (
    BACKENDS,
    RECORD_COLUMNS,
    SPEED_MODE_ALL_CHECKS,
    SUMMARY_COLUMNS,
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
]
