"""Pieces every simulator's scenario configuration shares (simulator-neutral).

- :class:`MpcDriverConfig`: the PIRL drivers' model and MPC settings (each simulator's ``DriverConfig``
  adds its own fields to it);
- :func:`config_table` / :func:`from_table`: a TOML table into a frozen config dataclass, unknown keys
  rejected with the list of valid ones;
- :func:`scenario_from_table` and :func:`load_toml`: a whole scenario configuration from a TOML file;
- :data:`Progress`: the progress callback every ``run_*_scenario`` takes; :func:`run_timing`: the timing
  summary every run returns.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from pirl_sim.io import toml_text
from pirl_sim.paths import DEFAULT_A_LAT, DEFAULT_V_MAX
from pirl_sim.validation import check_keys, int_at_least, number

from .population_config import PopulationConfig, population_from_dict

__all__ = ["Progress", "run_timing", "MpcDriverConfig", "config_table", "from_table", "scenario_from_table",
           "load_toml", "resolve_lanelet_map", "check_lanelet_map"]

#: ``progress(simulated time [s], vehicles finished, vehicles in all)``
Progress = Callable[[float, int, int], None]


def run_timing(sim_time_s: float, wall_time_s: float, present, controller, **times: float) -> dict[str, float]:
    """A run's timing: ``sim_time_s``, ``wall_time_s``, the simulator's own ``times`` [s], the PIRL drivers'
    ``plan_time_s`` (MPC) and ``n_plans`` (:class:`~pirl_sim.scenarios.drivers.PirlDrivers` ``controller``),
    ``n_steps``, ``mean_vehicles`` / ``max_vehicles`` on the road per step (``present``: counts per step)
    and ``real_time_factor`` (simulated / wall seconds)."""
    return {
        "sim_time_s": sim_time_s,
        "wall_time_s": wall_time_s,
        **times,
        "plan_time_s": controller.plan_time_s,
        "n_steps": len(present),
        "n_plans": controller.n_plans,
        "mean_vehicles": float(np.mean(present)) if present else 0.0,
        "max_vehicles": int(max(present, default=0)),
        "real_time_factor": sim_time_s / wall_time_s if wall_time_s > 0 else math.inf,
    }


@dataclass(frozen=True)
class MpcDriverConfig:
    """The PIRL drivers' model and MPC (validated on construction), as every simulator runs them.

    Attributes
    ----------
    horizon : int                  MPC horizon [steps of 0.1 s], >= 1
    n_iter, n_qp_iter : int        Newton iterations and bounded QPs per re-plan (1 each: a real-time iteration), >= 1
    a_lat, v_max : float           desired speed: lateral acceleration [m/s^2] and speed cap [m/s], > 0
    smoothing : float              smoothing length [m], >= 0, of the routes' reference paths (2 m: within 0.2 m of
                                   the lanes' centre lines)
    speed_smoothing : float        further smoothing [m], >= 0, of the curvature for the desired speed
                                   (`~pirl_sim.scenarios.drivers.RouteSet`)
    depart_speed : float           speed [m/s] at insertion, >= 0
    stop_speed, resume_speed : float   [m/s] standstill hand-back of `~pirl_sim.scenarios.drivers.PirlDrivers`
                                   (the track is then flagged ``interacted``), 0 <= stop_speed <= resume_speed
    """

    horizon: int = 30
    n_iter: int = 1
    n_qp_iter: int = 1
    a_lat: float = DEFAULT_A_LAT
    v_max: float = DEFAULT_V_MAX
    smoothing: float = 2.0
    speed_smoothing: float = 10.0
    depart_speed: float = DEFAULT_V_MAX
    stop_speed: float = 0.5
    resume_speed: float = 3.0

    def __post_init__(self) -> None:
        for name in ("horizon", "n_iter", "n_qp_iter"):
            object.__setattr__(self, name, int_at_least(f"drivers.{name}", getattr(self, name), 1))
        for name in ("a_lat", "v_max"):
            object.__setattr__(self, name, number(f"drivers.{name}", getattr(self, name), allow_equal=False))
        for name in ("smoothing", "speed_smoothing", "depart_speed", "stop_speed", "resume_speed"):
            object.__setattr__(self, name, number(f"drivers.{name}", getattr(self, name)))
        if self.stop_speed > self.resume_speed:
            raise ValueError(f"drivers.stop_speed = {self.stop_speed} m/s must not exceed drivers.resume_speed = "
                             f"{self.resume_speed} m/s")


def config_table(label: str, data: Any, cls, extra: tuple[str, ...] = ()) -> dict[str, Any]:
    """The keyword arguments of ``cls`` (a dataclass) in the TOML table ``data``.

    Raises
    ------
    ValueError
        ``data`` is not a table, or has keys that are neither fields of ``cls`` nor in ``extra`` (the message
        lists the valid ones).
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"{label} must be a table, got {data!r}")
    check_keys(label, data, tuple(f.name for f in fields(cls) if f.init) + tuple(extra))
    return dict(data)


def from_table(label: str, data: Any, cls, **overrides):
    """``cls(**config_table(label, data, cls), **overrides)`` with every error prefixed by ``label``."""
    kwargs = {**config_table(label, data, cls), **overrides}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{label}: {exc}") from None


def scenario_from_table(cls, data: Any, source: str, population: PopulationConfig | None,
                        tables: Mapping[str, Callable[[Any, str], Any]]):
    """A simulator's scenario configuration ``cls`` from a parsed TOML file (ValueError, prefixed by ``source``, for
    unknown keys, listing the valid ones, and every invalid value).

    Parameters
    ----------
    cls : type                     the configuration: a frozen dataclass with a ``population`` field, whose fields are
                                   the top-level keys of ``data``
    data : mapping
    source : str                   named in error messages
    population : PopulationConfig or None   used instead of the ``population`` table of ``data`` (then absent)
    tables : mapping field name -> callable   ``parse(table, label)`` turns a field's sub-table into its value
    """
    kwargs = config_table(source, data, cls)
    for name, parse in tables.items():
        if name in kwargs:
            kwargs[name] = parse(kwargs[name], f"{source}: {name}")
    if "population" in kwargs:
        if population is not None:
            raise ValueError(f"{source}: has a population table and a population was given too")
        kwargs["population"] = population_from_dict(kwargs["population"], source=f"{source}: population")
    elif population is not None:
        kwargs["population"] = population
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None


def resolve_lanelet_map(data: Mapping, path) -> dict:
    """A scenario table read from the file ``path`` with a relative ``lanelet_map`` taken from the file's folder."""
    where = data.get("lanelet_map")
    if isinstance(where, str) and where and not Path(where).is_absolute():
        return {**data, "lanelet_map": str(Path(path).parent / where)}
    return dict(data)


def check_lanelet_map(where) -> str:
    """``where`` as the path string of a Lanelet2 map (``.osm``), or ``ValueError`` (the file is read later)."""
    if not isinstance(where, (str, os.PathLike)) or not os.fspath(where):
        raise ValueError(f"lanelet_map must be the path of a Lanelet2 map (.osm), got {where!r}")
    return os.fspath(where)


def load_toml(path) -> dict[str, Any]:
    """A TOML file's contents; ``FileNotFoundError`` / ``ValueError`` (naming the file) when missing or
    invalid."""
    return toml_text.load(path, "scenario config")[0]
