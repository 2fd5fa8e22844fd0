"""highway-env roundabout scenarios: the SUMO scenario's populations on highway-env's roundabout, recorded.

One call, :func:`run_highway_scenario`, does everything for a :class:`HighwayScenarioConfig` and a seed: plan the
population (:func:`~.planning.plan_population`, the same draws as the SUMO scenario), build highway-env's
``roundabout-generic-v0`` road with one ring lane and its 12 routes (:mod:`~pirl_sim.scenarios.highway.network`),
simulate :class:`~.traffic.RoundaboutTraffic` at 0.1 s steps until every vehicle has left or ``max_duration``,
and record through :func:`pirl_sim.scenarios.recording.write_recording`. :class:`HighwayAdapter` is the
scenario's :class:`~pirl_sim.scenarios.contract.SimulatorAdapter`. :func:`load_highway_run` reads a run back as
a :class:`~pirl_sim.scenarios.demonstrations.RecordedRun`, whose ``demonstrations()`` feed the learners.

See the documentation's "highway-env roundabouts" page.
"""

from __future__ import annotations

import time as _time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pirl_sim.trajectory import Trajectory
from pirl_sim.validation import int_at_least, number

from ..demonstrations import RecordedRun, recorded_demonstrations
from ..drivers import RouteSet, RouteSetDriverModel, route_set_model
from ..planning import check_route_weights, check_routes, plan_population, random_streams, route_id
from ..population_config import DEFAULT_POPULATION, PopulationConfig
from ..recording import INFO_FILE, RecordingFiles, ScenarioRecording, read_recording, write_recording
from ..contract import ControllerWrapper, EgoSpec, run_scenario
from ..scenario_config import (Progress, check_lanelet_map, config_table, from_table, load_toml, resolve_lanelet_map,
                               scenario_from_table)
from .network import ARMS, LANE_WIDTH, RoundaboutGeometry, build_network, lane_graph, route_catalogue, route_set
from .traffic import STEP_LENGTH, DriverConfig, RoundaboutTraffic, TrafficRules
from .vehicles import EGO, PIRL

__all__ = [
    "SIMULATOR",
    "ROUTE_IDS",
    "HighwayScenarioConfig",
    "HighwayScenarioResult",
    "scenario_from_dict",
    "drivers_from_dict",
    "rules_from_dict",
    "load_scenario",
    "build_routes",
    "run_highway_scenario",
    "load_highway_run",
]

SIMULATOR = "highway-env"  #: ``simulator`` in ``run.json``

#: the route catalogue's ids in canonical order (entry arm, then first exit first), as the SUMO scenario's
ROUTE_IDS: tuple[str, ...] = tuple(route_id(i, (i + k) % len(ARMS)) for i in range(len(ARMS))
                                   for k in range(1, len(ARMS)))


@dataclass(frozen=True)
class HighwayScenarioConfig:
    """A highway-env roundabout scenario (validated on construction).

    Attributes
    ----------
    geometry : RoundaboutGeometry        ring radius (default 20 m, highway-env's)
    population : PopulationConfig        default: the paper's three styles, 20 % background
    drivers : DriverConfig               the PIRL drivers' model and MPC
    rules : TrafficRules                 leaders, yielding, crash removal
    pirl_routes, background_routes : tuple of str or None   routes (of `route_ids`) PIRL / background vehicles
                                         draw from; None: all
    max_duration : float or None         longest simulated time [s], > 0; None: last departure + 300 s
    lanelet_map : str or None            a Lanelet2 map (``.osm``) whose roundabout replaces highway-env's
                                         (`~.lanelet_road.lanelet_road`; ``geometry`` must then stay the default)
    route_weights : mapping route id -> float, or None   relative frequencies of the routes vehicles draw (a route
                                         not named: 0); None: every route equally often
    """

    geometry: RoundaboutGeometry = field(default_factory=RoundaboutGeometry)
    population: PopulationConfig = DEFAULT_POPULATION
    drivers: DriverConfig = field(default_factory=DriverConfig)
    rules: TrafficRules = field(default_factory=TrafficRules)
    pirl_routes: tuple[str, ...] | None = None
    background_routes: tuple[str, ...] | None = None
    max_duration: float | None = None
    lanelet_map: str | None = None
    route_weights: Mapping[str, float] | None = None

    def __post_init__(self) -> None:
        for name, cls in (("geometry", RoundaboutGeometry), ("population", PopulationConfig),
                          ("drivers", DriverConfig), ("rules", TrafficRules)):
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f"{name} must be a {cls.__name__}, got {type(getattr(self, name)).__name__}")
        if self.lanelet_map is not None:
            object.__setattr__(self, "lanelet_map", check_lanelet_map(self.lanelet_map))
            if self.geometry != RoundaboutGeometry():
                raise ValueError("geometry sets highway-env's own roundabout: with lanelet_map the map's roundabout "
                                 f"is driven, leave geometry out (got {self.geometry})")
        known = self.route_ids()
        object.__setattr__(self, "route_weights", check_route_weights(self.route_weights, known))
        for name in ("pirl_routes", "background_routes"):
            object.__setattr__(self, name, check_routes(name, getattr(self, name), known))
        if self.max_duration is not None:
            object.__setattr__(self, "max_duration", number("max_duration", self.max_duration, low=0.0,
                                                            allow_equal=False))

    def route_ids(self) -> tuple[str, ...]:
        """The route catalogue's ids in canonical order: `ROUTE_IDS`, or the map's routes (sorted; read from the map,
        FileNotFoundError / ValueError as `~.lanelet_road.map_road` raises them)."""
        if self.lanelet_map is None:
            return ROUTE_IDS
        from .lanelet_road import map_road

        return tuple(map_road(self.lanelet_map).routes)

    def to_dict(self) -> dict[str, Any]:
        """Plain (TOML/JSON-ready) form that :func:`scenario_from_dict` reads back."""
        rules = asdict(self.rules)
        if rules["crash_removal_delay"] is None:
            del rules["crash_removal_delay"]  # TOML and JSON-from-TOML have no null: a flag instead
            rules["crash_removal"] = False
        out: dict[str, Any] = {
            "geometry": asdict(self.geometry),
            "population": self.population.to_dict(),
            "drivers": asdict(self.drivers),
            "rules": rules,
        }
        for name in ("pirl_routes", "background_routes"):
            if getattr(self, name) is not None:
                out[name] = list(getattr(self, name))
        if self.max_duration is not None:
            out["max_duration"] = self.max_duration
        if self.lanelet_map is not None:
            out["lanelet_map"] = self.lanelet_map
        if self.route_weights is not None:
            out["route_weights"] = dict(self.route_weights)
        return out


def rules_from_dict(data: Mapping[str, Any], *, source: str = "rules") -> TrafficRules:
    """A :class:`~.traffic.TrafficRules` from a table (``crash_removal = false`` keeps crashed vehicles)."""
    kwargs = config_table(source, data, TrafficRules, extra=("crash_removal",))
    if "crash_removal" in kwargs:
        keep = kwargs.pop("crash_removal")
        if not isinstance(keep, bool):
            raise ValueError(f"{source}: crash_removal must be true or false, got {keep!r}")
        if not keep:
            if "crash_removal_delay" in kwargs:
                raise ValueError(f"{source}: crash_removal = false and crash_removal_delay exclude each other")
            kwargs["crash_removal_delay"] = None
    try:
        return TrafficRules(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from None


def drivers_from_dict(data: Mapping[str, Any], *, source: str = "drivers") -> DriverConfig:
    """A :class:`~.traffic.DriverConfig` from a table (unknown keys rejected, listing the valid ones)."""
    return from_table(source, data, DriverConfig)


def scenario_from_dict(data: Mapping[str, Any], *, source: str = "scenario",
                       population: PopulationConfig | None = None) -> HighwayScenarioConfig:
    """Build a :class:`HighwayScenarioConfig` from plain data (a parsed TOML file): top-level keys are its
    attributes, ``geometry``, ``drivers`` and ``rules`` tables of :class:`~.network.RoundaboutGeometry`,
    :class:`~.traffic.DriverConfig` and :class:`~.traffic.TrafficRules` fields (``rules_from_dict``),
    ``population`` a table as :func:`~pirl_sim.scenarios.population_config.population_from_dict` reads or
    the given ``population``; errors as :func:`~pirl_sim.scenarios.scenario_config.scenario_from_table`
    raises them (unknown keys listing the valid ones, every invalid value, named by ``source``).
    """
    return scenario_from_table(HighwayScenarioConfig, data, source, population, {
        "geometry": lambda table, label: from_table(label, table, RoundaboutGeometry),
        "drivers": lambda table, label: drivers_from_dict(table, source=label),
        "rules": lambda table, label: rules_from_dict(table, source=label)})


def load_scenario(path, *, population: PopulationConfig | None = None) -> HighwayScenarioConfig:
    """Read a scenario TOML file (see :func:`scenario_from_dict`; a relative ``lanelet_map`` is taken from the
    file's folder)."""
    return scenario_from_dict(resolve_lanelet_map(load_toml(path), path), source=str(path), population=population)


# ----------------------------------------------------------------------------------------------
# running
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class HighwayScenarioResult:
    """Everything a run produced.

    Attributes
    ----------
    config : HighwayScenarioConfig
    seed : int
    vehicles : pandas.DataFrame      the plan (`~pirl_sim.scenarios.planning.plan_population`)
    summary : pandas.DataFrame       one row per vehicle that was on the road
                                     (`~pirl_sim.scenarios.highway.traffic.RoundaboutTraffic.summary`)
    recording : ScenarioRecording    what `~pirl_sim.scenarios.recording.write_recording` writes
    routes : RouteSet                reference paths of every route on one arc-length axis
    model : RouteSetDriverModel      the drivers' model (converged MPC settings) for learning and prediction
    timing : dict                    times [s] and counts, as `pirl_sim.scenarios.contract.run_scenario` gives them
    files : RecordingFiles or None
    """

    config: HighwayScenarioConfig
    seed: int
    vehicles: pd.DataFrame
    summary: pd.DataFrame
    recording: ScenarioRecording
    routes: RouteSet
    model: RouteSetDriverModel
    timing: Mapping[str, float]
    files: RecordingFiles | None = None

    def demonstrations(self, **kwargs) -> list[Trajectory]:
        """:func:`~pirl_sim.scenarios.demonstrations.recorded_demonstrations` of this run."""
        return recorded_demonstrations(self.recording, self.routes, **kwargs)


#: [m] the ego starts at least this far before its route's end
EGO_END_MARGIN = 10.0

#: build_routes' results kept with ``cache=True``, by (geometry, map, smoothing [m], speed smoothing [m])
_ROUTES: dict[tuple, tuple] = {}


def build_routes(config: HighwayScenarioConfig, *, cache: bool = False):
    """(network, route catalogue, RouteSet) of a configuration; with ``cache``, built once per process
    for equal geometry, map and path smoothing (shared: nothing may change them).

    On a Lanelet2 map (``config.lanelet_map``) the reference paths follow the map's lanelet centre lines as the SUMO
    scenario's and the replay's do (`~pirl_sim.scenarios.lanelet_graph.lanelet_route_set`).
    """
    key = (config.geometry, config.lanelet_map, config.drivers.smoothing, config.drivers.speed_smoothing)
    if cache and key in _ROUTES:
        return _ROUTES[key]
    if config.lanelet_map is None:
        net = build_network(config.geometry)
        catalogue = route_catalogue(net)
        if tuple(catalogue) != ROUTE_IDS:  # pragma: no cover - guards the constant against the network
            raise AssertionError(f"route catalogue {tuple(catalogue)} differs from ROUTE_IDS")
        routes = route_set(net, catalogue, smoothing=config.drivers.smoothing,
                           speed_smoothing=config.drivers.speed_smoothing)
    else:
        from ..lanelet_graph import edge_id, lanelet_route_set
        from .lanelet_road import map_road

        road = map_road(config.lanelet_map)
        net, catalogue = road.network, road.routes
        routes = lanelet_route_set(config.lanelet_map, {rid: [edge_id(lid) for lid in ids]
                                                        for rid, ids in road.lanelets.items()},
                                   smoothing=config.drivers.smoothing, speed_smoothing=config.drivers.speed_smoothing)
    if cache:
        _ROUTES[key] = (net, catalogue, routes)
    return net, catalogue, routes


def run_highway_scenario(config: HighwayScenarioConfig | None = None, seed: int = 0, *, out_dir=None,
                         progress: Progress | None = None) -> HighwayScenarioResult:
    """Plan, simulate and record one scenario (see the module docstring; ValueError before anything runs).

    Parameters
    ----------
    config : HighwayScenarioConfig, optional   default ``HighwayScenarioConfig()``
    seed : int                                 seeds every draw (same seed, byte-identical files)
    out_dir : str or os.PathLike, optional     where to write the recording, once the simulation has finished
    progress : callable, optional              ``progress(time_s, n_finished, n_vehicles)``, every simulated second
    """
    return run_scenario(HighwayAdapter(), config, seed, out_dir=out_dir, progress=progress)  # type: ignore[arg-type]


class HighwayAdapter:
    """highway-env behind the simulator contract (:class:`~pirl_sim.scenarios.contract.SimulatorAdapter`)."""

    name = SIMULATOR
    config_type = HighwayScenarioConfig

    def plan(self, config: HighwayScenarioConfig, seed: int) -> pd.DataFrame:
        return plan_population(config.population, config.route_ids(), seed, pirl_routes=config.pirl_routes,
                               background_routes=config.background_routes, route_weights=config.route_weights)

    def start(self, config: HighwayScenarioConfig, seed: int, plan: pd.DataFrame, *, ego: EgoSpec | None = None,
              wrap_controller: ControllerWrapper | None = None, cache_network: bool = False,
              initial_vehicles: int | None = None, np_random: np.random.Generator | None = None,
              record: bool = True, record_history: bool = False) -> _HighwaySimulation:
        """The highway-env run of ``plan`` (see :meth:`~pirl_sim.scenarios.contract.SimulatorAdapter.start`).

        highway-env's own parameters: the ego, if any, is placed at ``ego.route_s`` when the simulation starts
        and follows its ``command_acceleration`` [m/s^2] (the caller's); ``initial_vehicles``: that many
        vehicles of the plan are placed on the road at once (:meth:`~.traffic.RoundaboutTraffic.place_initial`)
        and the others depart counted from the next planned departure (None: the plan's own clock);
        ``np_random`` is highway-env's road generator (default: seeded by ``seed``); ``record`` keeps every
        frame for the recording, ``record_history`` highway-env's trajectory display.
        """
        if ego is not None and (ego.depart != 0.0 or ego.speed_mode is not None):
            raise ValueError(f"highway-env places the ego when the simulation starts and has no speed modes: "
                             f"depart must be 0 and speed_mode None, got {ego.depart!r} and {ego.speed_mode!r}")
        if initial_vehicles is not None:
            initial_vehicles = int_at_least("initial_vehicles", initial_vehicles, 0)
        return _HighwaySimulation(config, seed, plan, ego=ego, wrap_controller=wrap_controller,
                                  cache_network=cache_network, initial_vehicles=initial_vehicles,
                                  np_random=np_random, record=record, record_history=record_history)

    def info(self, config: HighwayScenarioConfig) -> tuple[dict, dict]:
        import highway_env

        return {"highway_env_version": highway_env.__version__}, {"routes": list(config.route_ids())}

    def write(self, sim: _HighwaySimulation, recording: ScenarioRecording, out_dir, config) -> RecordingFiles:
        return write_recording(recording, out_dir, lane_width=LANE_WIDTH)

    def result(self, config, seed, plan, sim: _HighwaySimulation, recording, timing, files) -> HighwayScenarioResult:
        model = route_set_model(sim.routes, dt=STEP_LENGTH, a_lat=config.drivers.a_lat, v_max=config.drivers.v_max,
                                interacting=config.population.interacting)
        return HighwayScenarioResult(config, seed, plan, sim.traffic.summary(), recording, sim.routes, model, timing,
                                     files)


class _HighwaySimulation:
    """One highway-env run of a plan (:class:`~pirl_sim.scenarios.contract.Simulation`) on
    :class:`~.traffic.RoundaboutTraffic` (``traffic``, the highway-env road); ``ego_vehicle`` is the vehicle of
    ``ego_spec``, if one was given, ``controller`` the PIRL drivers."""

    def __init__(self, config: HighwayScenarioConfig, seed: int, plan: pd.DataFrame, *, ego: EgoSpec | None = None,
                 wrap_controller: ControllerWrapper | None = None, cache_network: bool = False,
                 initial_vehicles: int | None = None, np_random: np.random.Generator | None = None,
                 record: bool = True, record_history: bool = False):
        self.config, self.seed, self.plan = config, seed, plan
        self.ego_spec, self.wrap_controller, self.cache_network = ego, wrap_controller, cache_network
        self.initial_vehicles, self.np_random = initial_vehicles, np_random
        self.record, self.record_history = record, record_history
        self.ego_vehicle = None

    def __enter__(self) -> _HighwaySimulation:
        config, plan = self.config, self.plan
        _, noise_rng, behaviour_rng = random_streams(self.seed)
        net, catalogue, routes = build_routes(config, cache=self.cache_network)
        self.net, self.routes = net, routes
        np_random = np.random.default_rng(self.seed) if self.np_random is None else self.np_random
        self.traffic = traffic = RoundaboutTraffic(
            net, catalogue, routes, plan, drivers=config.drivers, rules=config.rules,
            control_noise=config.population.control_noise, noise_rng=noise_rng, behaviour_rng=behaviour_rng,
            np_random=np_random, record=self.record, record_history=self.record_history)
        self.controller = traffic.controller
        if self.wrap_controller is not None:
            traffic.controller = self.wrap_controller(self.controller)  # type: ignore[assignment]
        ego = self.ego_spec
        if ego is not None:
            route_s = min(ego.route_s, catalogue[ego.route_id].length - EGO_END_MARGIN)
            self.ego_vehicle = traffic.add_vehicle(EGO, ego.vehicle_id, ego.route_id, route_s, ego.speed)
        n0 = self.initial_vehicles
        if n0 is not None:
            if n0:
                traffic.place_initial(n0)
            traffic.shift_departures(float(plan["depart"].iloc[n0]) if n0 < len(plan) else 0.0)
        self._t0 = _time.perf_counter()
        traffic.insert_due()
        return self

    def __exit__(self, *exc) -> None:
        pass

    def step(self) -> None:
        self.traffic.act()
        self.traffic.step(STEP_LENGTH)

    @property
    def n_present(self) -> int:
        return len(self.traffic.vehicles)

    @property
    def n_present_pirl(self) -> int:
        return sum(getattr(v, "kind", None) == PIRL for v in self.traffic.vehicles)

    @property
    def n_finished(self) -> int:
        return self.traffic.n_finished

    @property
    def done(self) -> bool:
        return self.traffic.n_pending == 0 and not self.traffic.vehicles

    def finish(self) -> None:
        self.wall_time_s = _time.perf_counter() - self._t0
        self.time = self.traffic.time
        self.n_not_departed = self.traffic.n_pending
        self.own_times = {"act_time_s": self.traffic.act_time_s}

    def recording(self, info) -> ScenarioRecording:
        lanes, successors = lane_graph(self.net)
        return self.traffic.recording(info, lanes, successors)


def load_highway_run(directory) -> RecordedRun:
    """Read a run written by :func:`run_highway_scenario`: the recording, its configuration, the routes'
    reference paths (rebuilt from the configuration in ``run.json``) and the drivers' model."""
    d = Path(directory)
    rec = read_recording(d)
    info = rec.info
    if info.get("simulator") != SIMULATOR:
        raise ValueError(f"{d}: not a highway-env recording (simulator {info.get('simulator')!r})")
    config = scenario_from_dict(info["config"], source=f"{d}/{INFO_FILE}")
    _, _, routes = build_routes(config)
    model = route_set_model(routes, dt=info["step_length_s"], a_lat=config.drivers.a_lat, v_max=config.drivers.v_max,
                            interacting=config.population.interacting)
    return RecordedRun(rec, config, routes, model)
