"""The simulator contract: what every roundabout simulator adapter (SUMO, highway-env) implements.

:data:`STEP` [s] (0.1 s: the simulation step, the driver model's step and the INTERACTION frame); what a driver
observes (:class:`VehicleView` inside a :class:`DriverObservation`; :class:`EgoView` / :class:`EgoObservation`
the plain implementations); the controller protocol (:class:`BatchController`: one call per step,
``commands(time, {vehicle id: observation}) -> {vehicle id: speed [m/s] one step ahead, or None}``, and
``frame=`` every vehicle's :class:`Frame` for a controller whose ``needs_frame`` is true); an agent's
vehicle (:class:`EgoSpec`); the ground truth (:func:`ground_truth_table`); and the run: :func:`run_scenario`
``(adapter, config, seed)`` plans, steps, records and writes a run for any :class:`SimulatorAdapter`.
Units: SI throughout (m, s, m/s, m/s^2).

The contract is explained in the documentation's "Simulators and data" page.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
import pandas as pd

from pirl_sim.validation import number

from .planning import check_seed
from .population_config import FEATURE_NAMES, INTERACTION_FEATURES
from .recording import FRAME_DT_S, GROUND_TRUTH_COLUMNS, INTERACTING_GROUND_TRUTH_COLUMNS, ScenarioRecording
from .scenario_config import Progress, run_timing

__all__ = ["STEP", "EXTRA_TIME_S", "VehicleView", "DriverObservation", "EgoView", "EgoObservation", "Frame",
           "BatchController",
           "EgoSpec", "ControllerWrapper", "Simulation", "SimulatorAdapter", "ground_truth_table", "run_scenario"]

STEP = FRAME_DT_S  #: [s] simulation step = driver-model step = INTERACTION frame
EXTRA_TIME_S = 300.0  #: [s] simulated after the last departure when a config gives no ``max_duration``


@runtime_checkable
class VehicleView(Protocol):
    """A driven vehicle as its driver sees it: position ``x``, ``y`` [m] (the reference point the simulator
    records), ``speed`` [m/s] and ``accel`` [m/s^2] along its heading."""

    x: float
    y: float
    speed: float
    accel: float


@runtime_checkable
class DriverObservation(Protocol):
    """What a controller is told about one driven vehicle at one step: at least ``ego`` (a VehicleView)."""

    ego: VehicleView


@dataclass(frozen=True)
class EgoView:
    """A plain :class:`VehicleView` (x, y [m], speed [m/s], accel [m/s^2])."""

    x: float
    y: float
    speed: float
    accel: float


@dataclass(frozen=True)
class EgoObservation:
    """A plain :class:`DriverObservation`: the driven vehicle only."""

    ego: EgoView


@dataclass(frozen=True, eq=False)
class Frame:
    """Every vehicle in the simulation at one step, as the recording holds it (for drivers who interact).

    Attributes
    ----------
    ids : tuple of str (n,)     vehicle ids
    xy : array (n, 2) [m]       centre positions
    psi : array (n,) [rad]      headings
    speed : array (n,) [m/s]    speeds
    length : array (n,) [m]     lengths
    routes : tuple of str (n,)  route ids ("" where unknown: such a vehicle is never yielded to)
    """

    ids: tuple[str, ...]
    xy: np.ndarray
    psi: np.ndarray
    speed: np.ndarray
    length: np.ndarray
    routes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        n = len(self.ids)
        routes = tuple(self.routes) or ("",) * n
        if len(routes) != n:
            raise ValueError(f"Frame.routes must have one route id per id ({n}), got {len(routes)}")
        object.__setattr__(self, "routes", routes)
        shapes = {"xy": (n, 2), "psi": (n,), "speed": (n,), "length": (n,)}
        for name, shape in shapes.items():
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != shape:
                raise ValueError(f"Frame.{name} must have shape {shape} (one entry per id), got {a.shape}")
            object.__setattr__(self, name, a)

    def leaders(self) -> tuple[np.ndarray, np.ndarray]:
        """Gap [m] to each vehicle's vehicle ahead and its speed [m/s] (`pirl_sim.scenarios.leaders.frame_leaders`,
        bumper to bumper; inf and NaN where there is none)."""
        from .leaders import frame_leaders

        return frame_leaders(self.xy, self.psi, self.speed, self.length)


@runtime_checkable
class BatchController(Protocol):
    """A controller that commands all its vehicles of a step in one call.

    ``commands(time [s], observations: Mapping[vehicle id, DriverObservation]) -> Mapping[vehicle id, float |
    None]``: commanded speeds [m/s] one step ahead (None, or a missing id, hands that vehicle back to the
    simulator's own driver model for the step).
    """

    def commands(self, time: float, observations: Mapping[str, DriverObservation]) -> Mapping[str, float | None]:
        ...  # pragma: no cover - protocol


@dataclass(frozen=True)
class EgoSpec:
    """An extra vehicle, not in the plan, that the caller drives (an env's agent); validated on construction.

    Attributes
    ----------
    route_id : str                 its route, one of the simulation's catalogue
    speed : float                  [m/s] at insertion, >= 0
    depart : float                 [s] insertion time, >= 0 (SUMO: once the entry has room; highway-env: 0 only)
    route_s : float                [m] route coordinate where highway-env places it (at most 10 m before the
                                   route's end), >= 0; SUMO inserts at the route's start (0 only)
    speed_mode : int or None       SUMO speed mode of this vehicle, in [0, 127]; None: the scenario's (highway-env)
    vehicle_id : str
    """

    route_id: str
    speed: float
    depart: float = 0.0
    route_s: float = 0.0
    speed_mode: int | None = None
    vehicle_id: str = "ego"

    def __post_init__(self) -> None:
        for name in ("route_id", "vehicle_id"):
            if not isinstance(getattr(self, name), str) or not getattr(self, name):
                raise ValueError(f"ego {name} must be a non-empty string, got {getattr(self, name)!r}")
        for name in ("speed", "depart", "route_s"):
            object.__setattr__(self, name, number(f"ego {name}", getattr(self, name), low=0.0))
        m = self.speed_mode
        if m is not None and (isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 0 <= m < 128):
            raise ValueError(f"ego speed_mode must be None or an integer bitset in [0, 127], got {m!r}")


#: ``wrap(drivers) -> controller``: what a simulation asks for commands instead of its PIRL drivers
ControllerWrapper = Callable[[BatchController], BatchController]


class Simulation(Protocol):
    """One running simulation (a context manager; leaving it releases the simulator).

    Read by :func:`run_scenario` after every :meth:`step`: ``n_present`` (vehicles in the network),
    ``n_present_pirl`` (PIRL vehicles in it), ``n_finished`` (vehicles that left) and ``done`` (nothing left to
    depart or drive); after :meth:`finish`: ``time`` (simulated [s]), ``wall_time_s`` (wall time of the
    stepping [s]), ``n_not_departed``, ``own_times`` (the simulator's own timings [s] by name) and
    ``controller`` (the PIRL drivers: ``plan_time_s``, ``n_plans``).
    """

    time: float
    n_present: int
    n_present_pirl: int
    n_finished: int
    n_not_departed: int
    done: bool
    wall_time_s: float
    own_times: Mapping[str, float]
    controller: Any

    def step(self) -> None:
        """Advance by :data:`STEP`: the controller commands, the simulator moves, the frame is recorded."""

    def finish(self) -> None:
        """Stop stepping (the simulator's own recording is taken)."""

    def recording(self, info: Mapping[str, Any]) -> ScenarioRecording:
        """The run as a recording with the run's ``info`` (``run.json``)."""


class SimulatorAdapter(Protocol):
    """One simulator behind :func:`run_scenario`.

    Attributes
    ----------
    name : str
        ``simulator`` in ``run.json``.
    config_type : type
        The simulator's scenario configuration class (its default instance is the default scenario).
    """

    name: str
    config_type: type

    def plan(self, config, seed: int) -> pd.DataFrame:
        """The vehicles to run (one row each; ``depart`` [s], ``is_pirl``, route, style and weights), drawn from
        ``seed`` before anything runs."""

    def start(self, config, seed: int, plan: pd.DataFrame, *, ego: EgoSpec | None = None,
              wrap_controller: ControllerWrapper | None = None,
              cache_network: bool = False) -> AbstractContextManager[Simulation]:
        """The simulation of ``plan``, ready to step once entered.

        Parameters
        ----------
        config : config_type
        seed : int                      seeds the drivers' control noise, background behaviour and the simulator
        plan : pandas.DataFrame         from `plan`
        ego : EgoSpec, optional         an extra vehicle the caller drives; recorded as a non-PIRL track, style "ego"
        wrap_controller : callable, optional   ``wrap_controller(drivers)``: the batch controller asked every step
                                        instead of the PIRL drivers (the simulation's ``controller`` stays the drivers)
        cache_network : bool            reuse the road and paths built for an equal network in this process (resets)
        """

    def info(self, config) -> tuple[dict[str, Any], dict[str, Any]]:
        """The simulator's own entries of ``run.json``: those written after ``simulator`` and those written after
        ``config`` (the common ones are :func:`run_scenario`'s)."""

    def write(self, simulation: Simulation, recording: ScenarioRecording, out_dir, config):
        """Write the recording (and the simulator's own files) to ``out_dir``; returns the written files."""

    def result(self, config, seed: int, plan: pd.DataFrame, simulation: Simulation, recording: ScenarioRecording,
               timing: Mapping[str, float], files):
        """The run's result object."""


def run_scenario(adapter: SimulatorAdapter, config=None, seed: int = 0, *, out_dir=None,
                 progress: Progress | None = None):
    """Plan, simulate and record one scenario of ``adapter``'s simulator (TypeError / ValueError before it starts).

    Parameters
    ----------
    adapter : SimulatorAdapter
    config : adapter.config_type, optional    default ``adapter.config_type()``
    seed : int                                seeds every draw and the simulator (same seed, byte-identical files)
    out_dir : str or os.PathLike, optional    where to write the recording, once the simulation has finished
    progress : callable, optional             ``progress(time_s, n_finished, n_vehicles)``, every simulated second

    Returns
    -------
    The adapter's result; its ``timing`` holds ``sim_time_s``, ``wall_time_s``, ``plan_time_s``, ``n_plans``,
    ``n_steps``, the mean and max vehicles and PIRL vehicles per step, ``real_time_factor`` and the simulator's own.
    """
    config = adapter.config_type() if config is None else config
    if not isinstance(config, adapter.config_type):
        raise TypeError(f"config must be a {adapter.config_type.__name__}, got {type(config).__name__}")
    seed = check_seed(seed)
    plan = adapter.plan(config, seed)
    duration = config.max_duration or float(plan["depart"].max()) + EXTRA_TIME_S  # type: ignore[attr-defined]
    n_max = max(1, round(duration / STEP))
    present, present_pirl = [], []
    with adapter.start(config, seed, plan) as sim:
        for k in range(n_max):
            sim.step()
            present.append(sim.n_present)
            present_pirl.append(sim.n_present_pirl)
            if progress is not None and (k + 1) % 10 == 0:
                progress((k + 1) * STEP, sim.n_finished, len(plan))
            if sim.done:
                break
        sim.finish()
        if progress is not None:
            progress(sim.time, sim.n_finished, len(plan))
        head, tail = adapter.info(config)
        info = {"simulator": adapter.name, **head, "seed": seed, "step_length_s": STEP,
                "config": config.to_dict(),  # type: ignore[attr-defined]
                **tail, "n_vehicles": int(len(plan)), "n_not_departed": int(sim.n_not_departed),
                "sim_time_s": round(sim.time, 6)}
        recording = sim.recording(info)
        files = adapter.write(sim, recording, out_dir, config) if out_dir is not None else None
    timing = {**run_timing(sim.time, sim.wall_time_s, present, sim.controller, **sim.own_times),
              "mean_pirl": float(np.mean(present_pirl)) if present_pirl else 0.0,
              "max_pirl": int(max(present_pirl, default=0))}
    return adapter.result(config, seed, plan, sim, recording, timing, files)


def ground_truth_table(*, agent_id: Sequence[str], route_id: Sequence[str], is_pirl, style, style_name, theta,
                       interacted, collided, removed_early, overridden_fraction, status, n_frames) -> pd.DataFrame:
    """``ground_truth.csv``'s table (columns :data:`~pirl_sim.scenarios.recording.GROUND_TRUTH_COLUMNS`), one row
    per recorded track in track-id order (ids 1, 2, ...).

    Parameters
    ----------
    agent_id, route_id, style_name, status : sequences of str (n,)
    is_pirl, collided, removed_early : bool arrays (n,)
    style : int array (n,)
    theta : array (n, K) of the drivers' normalised weights in ``FEATURE_NAMES`` order (any value for non-PIRL); K = 5:
        drivers who interact (then ``headway`` and ``yielding``, `INTERACTING_GROUND_TRUTH_COLUMNS`)
    interacted : bool array (n,); recorded as NA for non-PIRL tracks
    overridden_fraction : float array (n,); share of the driver's commands the simulator overrode, NaN for
        non-PIRL tracks
    n_frames : int array (n,)
    """
    is_pirl = np.asarray(is_pirl, dtype=bool)
    n = len(is_pirl)
    theta = np.asarray(theta, dtype=float)
    names = FEATURE_NAMES + (INTERACTION_FEATURES if theta.ndim == 2 and theta.shape[1] > len(FEATURE_NAMES)
                             else ())
    theta = theta.reshape(n, len(names))
    columns = {"agent_id": agent_id, "route_id": route_id, "style": style, "style_name": style_name,
               "interacted": interacted, "collided": collided, "removed_early": removed_early,
               "overridden_fraction": overridden_fraction, "status": status, "n_frames": n_frames}
    wrong = {k: len(v) for k, v in columns.items() if len(v) != n}
    if wrong:
        raise ValueError(f"ground truth columns must have one entry per track ({n}), got lengths {wrong}")
    return pd.DataFrame({
        "track_id": np.arange(1, n + 1, dtype=np.int64),
        "agent_id": list(agent_id),
        "route_id": list(route_id),
        "is_pirl": is_pirl,
        "style": np.asarray(style, dtype=np.int64),
        "style_name": list(style_name),
        **{f"theta_{f}": theta[:, i] for i, f in enumerate(names)},
        "interacted": pd.array([bool(x) if p else pd.NA for x, p in zip(interacted, is_pirl)], dtype="boolean"),
        "collided": np.asarray(collided, dtype=bool),
        "removed_early": np.asarray(removed_early, dtype=bool),
        "overridden_fraction": np.where(is_pirl, np.asarray(overridden_fraction, dtype=float), np.nan),
        "status": list(status),
        "n_frames": np.asarray(n_frames, dtype=np.int64),
    }, columns=list(INTERACTING_GROUND_TRUTH_COLUMNS if len(names) > len(FEATURE_NAMES) else GROUND_TRUTH_COLUMNS))
