"""SUMO roundabout scenarios: mixed-style populations of PIRL drivers with known cost weights, recorded.

One call, :func:`run_sumo_scenario`, does everything for a :class:`SumoScenarioConfig` and a seed: plan the
vehicles (:func:`plan_vehicles`: departures, background vehicles, styles, weights and routes from
``numpy.random.SeedSequence(seed)``; bad configs raise ``ValueError`` before SUMO starts), build and check the
network (:data:`DEFAULT_NETWORK`), simulate at 0.1 s steps with :class:`~.runner.SumoRun` (PIRL vehicles driven by
:class:`~pirl_sim.scenarios.drivers.PirlDrivers` under speed mode 31, background vehicles by SUMO's Krauss model)
and record through :mod:`pirl_sim.scenarios.recording` (the same seed writes byte-identical files).
:class:`SumoAdapter` is the scenario's :class:`~pirl_sim.scenarios.contract.SimulatorAdapter`.

The steps, the vehicle types and what counts as an interaction are explained in the documentation's
"SUMO roundabouts" page.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pirl_sim.io.atomic import atomic_write_text
from pirl_sim.trajectory import Trajectory
from pirl_sim.validation import number

from ..demonstrations import RecordedRun, recorded_demonstrations
from ..drivers import PirlDrivers, RouteSet, RouteSetDriverModel, route_set_model
from ..planning import check_route_weights, check_routes, plan_population, random_streams, theta_columns
from ..population_config import DEFAULT_POPULATION, PopulationConfig
from ..recording import (
    BACKGROUND_STYLE,
    DRIVER_STEP_COLUMNS,
    INFO_FILE,
    TRACK_COLUMNS,
    RecordingFiles,
    ScenarioRecording,
    read_recording,
    write_recording,
)
from ..contract import STEP, ControllerWrapper, EgoSpec, ground_truth_table, run_scenario
from ..scenario_config import (MpcDriverConfig, Progress, check_lanelet_map, from_table, load_toml,
                               resolve_lanelet_map, scenario_from_table)
from .network import NetworkFiles, RoundaboutSpec, build_network, lane_graph, load_net, route_set, \
    routes as network_routes, validate_route
from ..lanelet_graph import lanelet_route_set, map_routes
from .lanelet_network import network_from_lanelet2
from .runner import BACKENDS, COLLISION_ACTIONS, SPEED_MODE_ALL_CHECKS, SumoRecording, SumoRun, VehicleSpec

__all__ = [
    "STEP_LENGTH",
    "DEFAULT_NETWORK",
    "PIRL_VTYPE",
    "BACKGROUND_VTYPE",
    "DriverConfig",
    "SumoScenarioConfig",
    "SumoScenarioResult",
    "scenario_from_dict",
    "load_scenario",
    "plan_vehicles",
    "vehicle_types_xml",
    "run_sumo_scenario",
    "run_to_directory",
    "scenario_recording",
    "load_sumo_run",
]

STEP_LENGTH = STEP  #: [s] simulation step = INTERACTION frame = driver-model step (the contract's)
PIRL_VTYPE = "pirl"
BACKGROUND_VTYPE = "background"
NETWORK_DIR = "network"  # under out_dir
_NET_NAME = "roundabout"

#: The scenarios' default roundabout: 4 arms, single lane, ring radius 25 m, junction curves of 10 m radius,
#: ring traffic visible from 50 m before an entry. Larger than :class:`~.network.RoundaboutSpec`'s defaults
#: (20 m, 6 m) so that the entries' S-bends are drivable at the driver model's comfortable lateral
#: acceleration without near-stops (with 20 m / 6 m the desired speed dips to ~4.6 m/s at every entry and
#: the "tracks desired speed" and "no preference" styles brake to a standstill there in free flow). The
#: visibility lets SUMO override a PIRL driver at an entry only when ring traffic conflicts (with SUMO's
#: 4.5 m every PIRL vehicle, even alone in the network, was braked before every entry).
DEFAULT_NETWORK = RoundaboutSpec(radius=25.0, junction_radius=10.0, entry_visibility=50.0)


@dataclass(frozen=True)
class DriverConfig(MpcDriverConfig):
    """The PIRL drivers' model and MPC (`~pirl_sim.scenarios.scenario_config.MpcDriverConfig`, whose other attributes
    it has) and their SUMO vehicle type (validated on construction).

    Attributes
    ----------
    speed_smoothing : float     default 10 m, which rounds the S-bend where an entry meets the ring (SUMO page)
    depart_speed : float        speed [m/s] at insertion (SUMO delays the insertion while it is unsafe)
    accel, decel : float        SUMO vehicle-type limits [m/s^2] of PIRL vehicles, > 0, above the MPC's bounds
    speed_factor : float        SUMO speed factor of PIRL vehicles (their speed cap: speed limit x factor), > 0
    """

    speed_smoothing: float = 10.0
    accel: float = 3.5
    decel: float = 4.5
    speed_factor: float = 1.2

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("accel", "decel", "speed_factor"):
            object.__setattr__(self, name, number(f"drivers.{name}", getattr(self, name), low=0.0,
                                                  allow_equal=False))


@dataclass(frozen=True)
class SumoScenarioConfig:
    """A SUMO roundabout scenario (validated on construction; routes against the network once it is built).

    Attributes
    ----------
    network : RoundaboutSpec                   default `DEFAULT_NETWORK`
    population : PopulationConfig              default `~pirl_sim.scenarios.population_config.DEFAULT_POPULATION`
    drivers : DriverConfig
    routes : mapping route id -> edge ids, or None   route catalogue; None: every entry-to-exit route
    pirl_routes, background_routes : tuple of str or None   routes PIRL / background vehicles draw from; None: all
    speed_mode : int                           SUMO speed mode of PIRL vehicles, in [0, 127]
    collision_action : {"warn", "remove", "teleport", "none"}   SUMO's ``--collision.action``
    override_tol : float                       [m/s] a command is overridden when the speed misses it by more, > 0
    max_duration : float or None               longest simulated time [s]; None: last departure + 300 s
    demand_per_arm : float or None             [vehicles/h/arm] > 0: sets ``depart_interval`` (SUMO page); None: as is
    lanelet_map : str or None                  a Lanelet2 map (``.osm``) whose roundabout replaces ``network``
                                               (`~.lanelet_network.network_from_lanelet2`); ``routes`` default to
                                               its entry-to-exit routes, read from the map on construction
    route_weights : mapping route id -> float, or None   relative frequencies of the routes vehicles draw (a route
                                               not named: 0); None: every route equally often
    """

    network: RoundaboutSpec = DEFAULT_NETWORK
    population: PopulationConfig = DEFAULT_POPULATION
    drivers: DriverConfig = field(default_factory=DriverConfig)
    routes: Mapping[str, Sequence[str]] | None = None
    pirl_routes: tuple[str, ...] | None = None
    background_routes: tuple[str, ...] | None = None
    speed_mode: int = SPEED_MODE_ALL_CHECKS
    collision_action: str = "warn"
    override_tol: float = 0.01
    max_duration: float | None = None
    demand_per_arm: float | None = None
    lanelet_map: str | None = None
    route_weights: Mapping[str, float] | None = None

    def __post_init__(self) -> None:
        for name, cls in (("network", RoundaboutSpec), ("population", PopulationConfig), ("drivers", DriverConfig)):
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f"{name} must be a {cls.__name__}, got {type(getattr(self, name)).__name__}")
        if self.routes is not None:
            if not isinstance(self.routes, Mapping) or not self.routes:
                raise ValueError(f"routes must be a non-empty mapping route id -> edge ids, got {self.routes!r}")
            cat = {}
            for rid, edges in self.routes.items():
                if not isinstance(rid, str) or not rid:
                    raise ValueError(f"route ids must be non-empty strings, got {rid!r}")
                if isinstance(edges, str) or not all(isinstance(e, str) for e in edges) or not len(edges):
                    raise ValueError(f"route {rid!r} must be a non-empty list of edge ids, got {edges!r}")
                cat[rid] = tuple(edges)
            object.__setattr__(self, "routes", dict(sorted(cat.items())))  # canonical order (draws use it)
        if self.lanelet_map is not None:
            object.__setattr__(self, "lanelet_map", check_lanelet_map(self.lanelet_map))
            if self.demand_per_arm is not None:
                raise ValueError("demand_per_arm sets the demand of the parametric ring's arms: with lanelet_map, "
                                 "set population.depart_interval (and route_weights) instead")
            if self.routes is None:
                object.__setattr__(self, "routes", dict(map_routes(self.lanelet_map)))
        known = list(self.route_catalogue())
        object.__setattr__(self, "route_weights", check_route_weights(self.route_weights, known))
        for name in ("pirl_routes", "background_routes"):
            object.__setattr__(self, name, check_routes(name, getattr(self, name), known))
        sm = self.speed_mode
        if isinstance(sm, bool) or not isinstance(sm, (int, np.integer)) or not 0 <= sm < 128:
            raise ValueError(f"speed_mode must be an integer bitset in [0, 127], got {sm!r}")
        if self.collision_action not in COLLISION_ACTIONS:
            raise ValueError(f"collision_action must be one of {COLLISION_ACTIONS}, got {self.collision_action!r}")
        object.__setattr__(self, "override_tol", number("override_tol", self.override_tol, low=0.0,
                                                         allow_equal=False))
        if self.max_duration is not None:
            object.__setattr__(self, "max_duration", number("max_duration", self.max_duration, low=0.0,
                                                            allow_equal=False))
        if self.demand_per_arm is not None:
            demand = number("demand_per_arm [veh/h per arm]", self.demand_per_arm, low=0.0, allow_equal=False)
            object.__setattr__(self, "demand_per_arm", demand)
            object.__setattr__(self, "population", replace(
                self.population, depart_interval=3600.0 / (demand * self.network.n_arms)))

    def route_catalogue(self) -> dict[str, tuple[str, ...]]:
        """Route id -> edge ids of every route of the scenario (not yet checked against a built network)."""
        if self.routes is not None:
            return dict(self.routes)  # type: ignore[arg-type]
        return {rid: tuple(edges) for rid, edges in network_routes(self.network)}

    def to_dict(self) -> dict[str, Any]:
        """Plain (TOML/JSON-ready) form that :func:`scenario_from_dict` reads back."""
        net = asdict(self.network)
        net["center"] = list(net["center"])
        out: dict[str, Any] = {
            "network": net,
            "drivers": asdict(self.drivers),
            "population": self.population.to_dict(),
            "speed_mode": self.speed_mode,
            "collision_action": self.collision_action,
            "override_tol": self.override_tol,
        }
        if self.routes is not None:
            out["routes"] = {k: list(v) for k, v in self.routes.items()}
        for name in ("pirl_routes", "background_routes"):
            if getattr(self, name) is not None:
                out[name] = list(getattr(self, name))
        if self.max_duration is not None:
            out["max_duration"] = self.max_duration
        for name in ("demand_per_arm", "lanelet_map", "route_weights"):
            if getattr(self, name) is not None:
                value = getattr(self, name)
                out[name] = dict(value) if name == "route_weights" else value
        return out


def scenario_from_dict(data: Mapping[str, Any], *, source: str = "scenario",
                       population: PopulationConfig | None = None) -> SumoScenarioConfig:
    """Build a :class:`SumoScenarioConfig` from plain data (a parsed TOML file): top-level keys are its
    attributes, ``network`` and ``drivers`` tables of :class:`~.network.RoundaboutSpec` and
    :class:`DriverConfig` fields, ``population`` a table as
    :func:`~pirl_sim.scenarios.population_config.population_from_dict` reads or the given ``population``;
    errors as :func:`~pirl_sim.scenarios.scenario_config.scenario_from_table` raises them (unknown keys
    listing the valid ones, every invalid value, named by ``source``).
    """
    return scenario_from_table(SumoScenarioConfig, data, source, population, {
        "network": _network_from_table,
        "drivers": lambda table, label: from_table(label, table, DriverConfig)})


def _network_from_table(table, label: str) -> RoundaboutSpec:
    center = table.get("center") if isinstance(table, Mapping) else None  # TOML has lists, not tuples
    return from_table(label, table, RoundaboutSpec, **({"center": tuple(center)} if isinstance(center, list) else {}))


def load_scenario(path, *, population: PopulationConfig | None = None) -> SumoScenarioConfig:
    """Read a scenario TOML file (see :func:`scenario_from_dict`; a relative ``lanelet_map`` is taken from the
    file's folder)."""
    return scenario_from_dict(resolve_lanelet_map(load_toml(path), path), source=str(path), population=population)


# ----------------------------------------------------------------------------------------------
# planning
# ----------------------------------------------------------------------------------------------

def plan_vehicles(config: SumoScenarioConfig, seed: int) -> pd.DataFrame:
    """Every vehicle of the scenario, drawn from ``seed`` before anything runs.

    Parameters
    ----------
    config : SumoScenarioConfig
    seed : int                   in [0, 2**31)

    Returns
    -------
    plan : pandas.DataFrame      one row per vehicle in departure order, the columns of
                                 `~pirl_sim.scenarios.planning.plan_population` (``style`` -1 and NaN weights for
                                 background)
    """
    if not isinstance(config, SumoScenarioConfig):
        raise TypeError(f"config must be a SumoScenarioConfig, got {type(config).__name__}")
    return plan_population(config.population, list(config.route_catalogue()), seed,
                           pirl_routes=config.pirl_routes or None,
                           background_routes=config.background_routes or None, route_weights=config.route_weights)


#: SUMO's checks on drivers who interact, a safety layer only (their cost keeps the gaps and yields): Krauss's
#: safe speed with this reaction time [s] and standstill gap [m], and no right of way at junctions (speed-mode bit 3)
SAFETY_TAU, SAFETY_MIN_GAP, RIGHT_OF_WAY_BIT = 0.5, 1.0, 8


def vehicle_types_xml(drivers: DriverConfig, interacting: bool = False) -> str:
    """SUMO additional file with the vehicle types ``pirl`` and ``background`` (see the module docstring); with
    ``interacting``, the ``pirl`` type's Krauss parameters are the safety layer's (`SAFETY_TAU`, `SAFETY_MIN_GAP`)."""
    tau, min_gap = (SAFETY_TAU, SAFETY_MIN_GAP) if interacting else (1.0, 2.5)
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n<additional>\n'
        f'    <vType id="{PIRL_VTYPE}" vClass="passenger" carFollowModel="Krauss" accel="{drivers.accel!r}" '
        f'decel="{drivers.decel!r}" emergencyDecel="9.0" sigma="0" tau="{tau!r}" length="5.0" width="1.8" '
        f'minGap="{min_gap!r}" speedFactor="{drivers.speed_factor!r}" speedDev="0"/>\n'
        f'    <vType id="{BACKGROUND_VTYPE}" vClass="passenger" carFollowModel="Krauss" accel="2.6" '
        'decel="4.5" emergencyDecel="9.0" sigma="0.5" tau="1.0" length="5.0" width="1.8" minGap="2.5" '
        'speedFactor="1.0" speedDev="0.1"/>\n'
        '</additional>\n'
    )


# ----------------------------------------------------------------------------------------------
# running
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SumoScenarioResult:
    """Everything a run produced.

    Attributes
    ----------
    config : SumoScenarioConfig
    seed : int
    backend : str
    vehicles : pandas.DataFrame      the plan (`plan_vehicles`)
    sumo : SumoRecording             the runner's raw per-step recording (commands, overrides, edges, lanes, ...)
    recording : ScenarioRecording    what `~pirl_sim.scenarios.recording.write_recording` writes
    routes : RouteSet                reference paths of every route on one arc-length axis
    model : RouteSetDriverModel      the drivers' model (converged MPC settings) for learning and prediction
    timing : dict                    times [s] and counts, as `pirl_sim.scenarios.contract.run_scenario` gives them
    files : RecordingFiles or None   when written
    """

    config: SumoScenarioConfig
    seed: int
    backend: str
    vehicles: pd.DataFrame
    sumo: SumoRecording
    recording: ScenarioRecording
    routes: RouteSet
    model: RouteSetDriverModel
    timing: Mapping[str, float]
    files: RecordingFiles | None = None

    def demonstrations(self, **kwargs) -> list[Trajectory]:
        """:func:`recorded_demonstrations` of this run."""
        return recorded_demonstrations(self.recording, self.routes, **kwargs)


def run_sumo_scenario(config: SumoScenarioConfig | None = None, seed: int = 0, *, out_dir=None,
                      backend: str = "libsumo", progress: Progress | None = None) -> SumoScenarioResult:
    """Plan, simulate and record one scenario (see the module docstring).

    Parameters
    ----------
    config : SumoScenarioConfig, optional   default: 4-arm, 20 m roundabout, the default population
    seed : int                              seeds every draw and SUMO (same seed, byte-identical files)
    out_dir : str or os.PathLike, optional  where to write the recording and ``network/``, once the simulation ends
    backend : {"libsumo", "traci"}
    progress : callable, optional           ``progress(time_s, n_finished, n_vehicles)``, every simulated second

    Returns
    -------
    result : SumoScenarioResult             ValueError before SUMO starts for a bad seed or backend, or a route
                                            that is not drivable in the built network
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    return run_scenario(SumoAdapter(backend), config, seed, out_dir=out_dir,  # type: ignore[arg-type]
                        progress=progress)


@dataclass(frozen=True)
class SumoAdapter:
    """SUMO behind the simulator contract (:class:`~pirl_sim.scenarios.contract.SimulatorAdapter`).

    Parameters
    ----------
    backend : {"libsumo", "traci"}
    """

    backend: str = "libsumo"
    name = "sumo"
    config_type = SumoScenarioConfig

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")

    def plan(self, config: SumoScenarioConfig, seed: int) -> pd.DataFrame:
        return plan_vehicles(config, seed)

    def start(self, config: SumoScenarioConfig, seed: int, plan: pd.DataFrame, *, ego: EgoSpec | None = None,
              wrap_controller: ControllerWrapper | None = None, cache_network: bool = False) -> _SumoSimulation:
        """The SUMO run of ``plan`` (see :meth:`~pirl_sim.scenarios.contract.SimulatorAdapter.start`): the ego,
        if any, is a ``pirl``-type vehicle inserted at its route's start at ``ego.depart`` [s], commanded by
        ``wrap_controller``'s controller, with its own speed mode; collisions as ``config.collision_action``."""
        if ego is not None and ego.route_s != 0.0:
            raise ValueError(f"SUMO inserts the ego at its route's start: route_s must be 0, got {ego.route_s!r}")
        return _SumoSimulation(config, seed, plan, self.backend, ego=ego, wrap_controller=wrap_controller,
                               cache_network=cache_network)

    def info(self, config: SumoScenarioConfig) -> tuple[dict, dict]:
        return ({"backend": self.backend},
                {"routes": [[k, list(v)] for k, v in config.route_catalogue().items()],  # in catalogue order
                 "network_file": f"{NETWORK_DIR}/{_NET_NAME}.net.xml"})

    def write(self, sim: _SumoSimulation, recording: ScenarioRecording, out_dir, config: SumoScenarioConfig):
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / INFO_FILE).unlink(missing_ok=True)  # incomplete until write_recording puts it back
        for p in sim.network_files:
            atomic_write_text(out / NETWORK_DIR / p.name, _without_generator_comment(p.read_text("utf-8")))
        return write_recording(recording, out, lane_width=config.network.lane_width)

    def result(self, config, seed, plan, sim: _SumoSimulation, recording, timing, files) -> SumoScenarioResult:
        drv = config.drivers
        learner_model = route_set_model(sim.routes, dt=STEP_LENGTH, a_lat=drv.a_lat, v_max=drv.v_max)
        return SumoScenarioResult(config, seed, self.backend, plan, sim.sumo_recording,  # type: ignore[arg-type]
                                  recording, sim.routes,
                                  learner_model, timing, files)


@dataclass(frozen=True)
class _Network:
    """A built network: its files in ``directory``, the loaded net, the route catalogue (every route checked
    against the net) and the routes' reference paths."""

    directory: tempfile.TemporaryDirectory
    files: NetworkFiles
    net: Any
    catalogue: dict[str, tuple[str, ...]]
    routes: RouteSet


#: networks built with ``cache_network``, by (spec, catalogue, smoothing [m], speed smoothing [m]); their
#: temporary directories live as long as the process
_NETWORKS: dict[tuple, _Network] = {}


def _built_network(config: SumoScenarioConfig, cache: bool) -> _Network:
    """The network of ``config`` built into a temporary directory (from :data:`_NETWORKS` when ``cache``)."""
    drv = config.drivers
    catalogue = config.route_catalogue()
    key = (config.network, config.lanelet_map, tuple(catalogue.items()), drv.smoothing, drv.speed_smoothing)
    if cache and key in _NETWORKS:
        return _NETWORKS[key]
    tmp = tempfile.TemporaryDirectory(prefix="pirl_sumo_")
    try:
        if config.lanelet_map is None:
            files = build_network(config.network, tmp.name, name=_NET_NAME)
        else:
            made = network_from_lanelet2(config.lanelet_map, tmp.name, name=_NET_NAME)
            files = NetworkFiles(made.nodes, made.edges, made.connections, made.net, config.network)
        net = load_net(files.net)
        for rid, edges in catalogue.items():
            validate_route(net, edges, route_id=rid)
        if config.lanelet_map is None:
            routes = route_set(net, catalogue, smoothing=drv.smoothing, speed_smoothing=drv.speed_smoothing)
        else:
            routes = lanelet_route_set(config.lanelet_map, catalogue, smoothing=drv.smoothing,
                                       speed_smoothing=drv.speed_smoothing)
    except BaseException:
        tmp.cleanup()
        raise
    built = _Network(tmp, files, net, catalogue, routes)
    if cache:
        _NETWORKS[key] = built
    return built


class _SumoSimulation:
    """One SUMO run of a plan (:class:`~pirl_sim.scenarios.contract.Simulation`): the network built in a
    temporary directory (or taken from the process's cache), every route checked against it, PIRL drivers
    (and an ego, if given) on :class:`~.runner.SumoRun`.

    Attributes
    ----------
    ego_spec : EgoSpec or None
    run : SumoRun
        Once entered: the running simulation (its clock, collisions and command overrides).
    controller : PirlDrivers
        The PIRL drivers.
    batch_controller : BatchController
        What SUMO asks every step: the drivers, or what ``wrap_controller`` made of them.
    """

    def __init__(self, config: SumoScenarioConfig, seed: int, plan: pd.DataFrame, backend: str, *,
                 ego: EgoSpec | None = None, wrap_controller: ControllerWrapper | None = None,
                 cache_network: bool = False):
        self.config, self.seed, self.plan, self.backend = config, seed, plan, backend
        self.ego_spec, self.wrap_controller, self.cache_network = ego, wrap_controller, cache_network
        self.sumo_recording: SumoRecording | None = None
        self._owned: tempfile.TemporaryDirectory | None = None  # the network's directory, when not cached

    def __enter__(self) -> _SumoSimulation:
        config, plan, ego = self.config, self.plan, self.ego_spec
        _, noise_rng, _ = random_streams(self.seed)
        drv = config.drivers
        built = _built_network(config, self.cache_network)
        self._owned = None if self.cache_network else built.directory
        try:
            self.net, self.routes = built.net, built.routes
            vtypes = built.files.net.with_name("vtypes.add.xml")
            interacting = config.population.interacting
            atomic_write_text(vtypes, vehicle_types_xml(drv, interacting))
            files = built.files
            self.network_files = (files.nodes, files.edges, files.connections, files.net, vtypes)
            model = route_set_model(self.routes, dt=STEP_LENGTH, a_lat=drv.a_lat, v_max=drv.v_max, n_iter=drv.n_iter,
                                    n_qp_iter=drv.n_qp_iter, interacting=interacting)
            pirl = plan[plan["is_pirl"]]
            theta_cols = theta_columns(plan)
            self.controller = PirlDrivers(
                model, {r.vehicle_id: (r.route_id, np.array([getattr(r, c) for c in theta_cols]))
                        for r in pirl.itertuples(index=False)},
                horizon=drv.horizon, control_noise=config.population.control_noise, rng=noise_rng,
                override_tol=config.override_tol, stop_speed=drv.stop_speed, resume_speed=drv.resume_speed)
            first = {rid: self.net.getEdge(edges[0]).getLength() for rid, edges in built.catalogue.items()}
            self.specs = [VehicleSpec(r.vehicle_id, r.route_id, float(r.depart),
                                      depart_speed=(insertion_speed(drv, first[r.route_id]) if r.is_pirl else "max"),
                                      type_id=PIRL_VTYPE if r.is_pirl else BACKGROUND_VTYPE)
                          for r in plan.itertuples(index=False)]
            driven, speed_modes = set(pirl["vehicle_id"]), None
            if ego is not None:
                self.specs.append(VehicleSpec(ego.vehicle_id, ego.route_id, ego.depart, depart_speed=ego.speed,
                                              type_id=PIRL_VTYPE))
                driven.add(ego.vehicle_id)
                if ego.speed_mode is not None:
                    speed_modes = {ego.vehicle_id: int(ego.speed_mode)}
            self.batch_controller = (self.controller if self.wrap_controller is None
                                     else self.wrap_controller(self.controller))
            self.run = SumoRun(files.net, built.catalogue, self.specs, pirl_ids=driven,
                               controller=self.batch_controller,  # type: ignore[arg-type]
                               seed=self.seed, step_length=STEP_LENGTH,
                               backend=self.backend, speed_mode=config.speed_mode & ~RIGHT_OF_WAY_BIT if interacting else config.speed_mode,
                               override_tol=config.override_tol,
                               collision_action=config.collision_action, speed_modes=speed_modes,
                               extra_args=("--additional-files", str(vtypes), "--step-method.ballistic", "true"))
            self.run.__enter__()
        except BaseException:
            self._release()
            raise
        return self

    def _release(self) -> None:
        if self._owned is not None:
            self._owned.cleanup()
            self._owned = None

    def __exit__(self, *exc) -> None:
        try:
            if self.sumo_recording is None:
                self.run.__exit__(*exc)
        finally:
            self._release()

    def step(self) -> None:
        self.run.step()

    @property
    def n_present(self) -> int:
        return self.run.n_present

    @property
    def n_present_pirl(self) -> int:
        return self.run.n_present_controlled

    @property
    def n_finished(self) -> int:
        if self.sumo_recording is not None:
            return int(self.sumo_recording.summary["status"].isin(("arrived", "vanished")).sum())
        return self.run.n_finished

    @property
    def done(self) -> bool:
        return self.run.expected() == 0

    def finish(self) -> None:
        self.sumo_recording = self.run.recording()
        self.run.__exit__(None, None, None)
        self.time = self.sumo_recording.sim_time_s
        self.wall_time_s = self.sumo_recording.wall_time_s
        self.n_not_departed = int((self.sumo_recording.summary["status"] == "not_departed").sum())
        self.own_times = {"control_time_s": self.controller.control_time_s}

    def recording(self, info) -> ScenarioRecording:
        """The run (before :meth:`finish`: so far) as a recording; the ego is a non-PIRL track named by its id
        with style name "ego"."""
        lanes, successors = lane_graph(self.net)
        plan, spec = self.plan, self.ego_spec
        if spec is not None:
            ego = {"vehicle_id": spec.vehicle_id, "depart": spec.depart, "route_id": spec.route_id,
                   "is_pirl": False, "style": BACKGROUND_STYLE, "style_name": "ego",
                   **{c: np.nan for c in theta_columns(plan)}}
            plan = pd.concat([plan, pd.DataFrame([ego])], ignore_index=True)
        sumo = self.sumo_recording if self.sumo_recording is not None else self.run.recording()
        return scenario_recording(plan, sumo, lanes, successors, info, set(self.controller.handbacks))


def insertion_speed(drivers: DriverConfig, entry_length: float, vehicle_length: float = 5.0) -> float:
    """A PIRL vehicle's speed at insertion [m/s]: ``drivers.depart_speed``, or less on a first edge too short to
    stop on before its junction (SUMO refuses such an insertion and drops the vehicle; the short entry lanelets
    of real maps): the speed that stops within the edge's length past the vehicle at ``drivers.decel``."""
    room = max(entry_length - vehicle_length - 0.5, 0.0)
    return min(drivers.depart_speed, float(np.floor(10.0 * np.sqrt(2.0 * drivers.decel * room)) / 10.0))


def _without_generator_comment(xml: str) -> str:
    """XML text without netconvert's leading ``<!-- generated on <time> ... -->`` comment (a time stamp and
    temporary paths), so that equal runs write equal bytes."""
    start = xml.find("<!-- generated on ")
    if start < 0 or start > 200:
        return xml
    end = xml.find("-->", start)
    return xml if end < 0 else xml[:start] + xml[end + 3:].lstrip("\n")


def scenario_recording(plan: pd.DataFrame, rec: SumoRecording, lanes, successors, info,
                        handed_back: set[str]) -> ScenarioRecording:
    """The simulator-neutral recording of a SUMO run (track ids 1, 2, ... in departure order).

    ``interacted`` (PIRL tracks): SUMO overrode at least one command, the vehicle collided, or it was
    handed back to SUMO at a standstill (``handed_back``). ``driver_steps`` (PIRL tracks, every frame): the
    runner's per-step flags: ``commanded`` where the driver gave a speed at that frame, ``overridden`` where
    SUMO's speed one step later missed it by more than ``override_tol`` (NA, a vehicle that left before the
    check, is False), ``collided`` where SUMO reported the vehicle in a collision.
    """
    summary = rec.summary.set_index("vehicle_id")
    departed = [v for v in plan["vehicle_id"] if summary.loc[v, "n_steps"] > 0]
    track_of = {v: k + 1 for k, v in enumerate(departed)}
    frame = rec.frame
    tracks = pd.DataFrame({
        "track_id": frame["vehicle_id"].map(track_of).to_numpy(dtype=np.int64),
        "time_s": frame["time"].to_numpy(dtype=float),
        "agent_type": "car",
        **{c: frame[c].to_numpy(dtype=float) for c in ("x", "y", "vx", "vy", "psi_rad", "length", "width")},
    }, columns=list(TRACK_COLUMNS))
    overridden_any = frame.groupby("vehicle_id", sort=False)["overridden"].apply(
        lambda s: bool(s.fillna(False).astype(bool).any()))
    p = plan.set_index("vehicle_id").loc[departed]
    s = summary.loc[departed]
    pirl = p["is_pirl"].to_numpy()
    collided = s["collided"].to_numpy(dtype=bool)
    gt = ground_truth_table(
        agent_id=departed, route_id=p["route_id"].to_numpy(), is_pirl=pirl, style=p["style"].to_numpy(),
        style_name=p["style_name"].to_numpy(), theta=p[theta_columns(plan)].to_numpy(dtype=float),
        interacted=[bool(overridden_any.get(v, False)) or bool(c) or v in handed_back
                    for v, c in zip(departed, collided)],
        collided=collided, removed_early=s["removed_early"].to_numpy(dtype=bool),
        overridden_fraction=s["overridden_fraction"].to_numpy(dtype=float), status=s["status"].to_numpy(),
        n_frames=s["n_steps"].to_numpy())
    on_pirl = frame["vehicle_id"].map(dict(zip(departed, pirl))).to_numpy(dtype=bool)  # PIRL drivers (not an ego)
    steps = pd.DataFrame({
        "track_id": tracks["track_id"].to_numpy()[on_pirl],
        "frame_id": np.round(frame["time"].to_numpy(dtype=float)[on_pirl] / STEP_LENGTH).astype(np.int64),
        "commanded": frame["commanded_speed"].notna().to_numpy()[on_pirl],
        "overridden": frame["overridden"].fillna(False).to_numpy(dtype=bool)[on_pirl],
        "collided": frame["collided"].to_numpy(dtype=bool)[on_pirl],
        "command_error": (frame.groupby("vehicle_id", sort=False)["speed"].shift(-1)
                          - frame["commanded_speed"]).abs().to_numpy(dtype=float)[on_pirl],
    }, columns=list(DRIVER_STEP_COLUMNS))
    return ScenarioRecording(tracks, gt, lanes, successors, info, steps)


def run_to_directory(config: SumoScenarioConfig | None, seed: int, out_dir, backend: str = "libsumo") -> dict:
    """:func:`run_sumo_scenario` writing to ``out_dir``, returning only a picklable summary (for
    :func:`~.runner.run_in_subprocess` and worker pools: libsumo runs one simulation per process).

    Returns
    -------
    dict
        ``out_dir``, ``n_tracks``, ``n_pirl``, ``n_interacted`` and the timing of the run.
    """
    res = run_sumo_scenario(config, seed, out_dir=out_dir, backend=backend)
    gt = res.recording.ground_truth
    return {"out_dir": os.fspath(out_dir), "n_tracks": int(len(gt)), "n_pirl": int(gt["is_pirl"].sum()),
            "n_interacted": int(gt["interacted"].fillna(False).astype(bool).sum()), **dict(res.timing)}


def load_sumo_run(directory) -> RecordedRun:
    """Read a run written by :func:`run_sumo_scenario`: recording, the routes' reference paths (from the
    network under ``network/`` and the route catalogue in ``run.json``) and the drivers' model."""
    d = Path(directory)
    rec = read_recording(d)
    info = rec.info
    if info.get("simulator") != "sumo":
        raise ValueError(f"{d}: not a SUMO recording (simulator {info.get('simulator')!r})")
    config = scenario_from_dict(info["config"], source=f"{d}/{INFO_FILE}")
    drv = config.drivers
    catalogue = [(k, tuple(v)) for k, v in info["routes"]]
    if config.lanelet_map is None:
        routes = route_set(d / info["network_file"], catalogue, smoothing=drv.smoothing,
                           speed_smoothing=drv.speed_smoothing)
    elif not Path(config.lanelet_map).is_file():
        raise FileNotFoundError(f"{d}: the run's reference paths follow the Lanelet2 map {config.lanelet_map}, "
                                "which is not there")
    else:
        routes = lanelet_route_set(config.lanelet_map, catalogue, smoothing=drv.smoothing,
                                   speed_smoothing=drv.speed_smoothing)
    model = route_set_model(routes, dt=info["step_length_s"], a_lat=drv.a_lat, v_max=drv.v_max,
                            interacting=config.population.interacting)
    return RecordedRun(rec, config, routes, model)
