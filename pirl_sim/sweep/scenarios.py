"""The scenario registry of sweeps: a name -> how to build train/test data from a validated parameter dict.

Each entry is a `ScenarioSpec`: the valid parameters with their kinds and defaults, a ``check`` that turns the
parameters of a config into a complete, JSON-serialisable dict (defaults filled in, everything validated by
building the scenario's own config dataclass, so a bad value fails before any work starts), a ``build`` that
draws the data for one seed, a ``train_shape`` that tells the sweep how many training trajectories of which
lengths there will be (to reject a k larger than the training set up front) and, for scenarios that read
files, a ``fingerprint`` of their content (part of every cell key, so changed data is recomputed).

Adding a scenario is one entry::

    register_scenario(ScenarioSpec(
        name="sumo",
        summary="SUMO roundabout, mixed-style PIRL drivers",
        params={"config": Param("path", None, "scenario TOML"), "n_train": Param("int", 100, "...")},
        check=_check_sumo, build=_build_sumo, train_shape=_sumo_shape,
    ))

``build(params, seed)`` must be a module-level function or a `functools.partial` of one and must give
the same trajectories for the same parameters and seed. Heavy simulators are imported inside ``build``.

**Simulated scenarios** (``sumo``, ``highway``) also give ``simulation(params)``, the part of the parameters
that the simulation depends on, and ``simulate(simulation_params, seed, out_dir)``, which records one run. The
sweep runs each (simulation parameters, seed) once, stores the recording beside the cells
(`pirl_sim.sweep.store`), and every cell that uses it reads it back: ``build(params, seed, simulation_dir)``.
Their parameters are the population's (`pirl_sim.scenarios.population_config`): ``n_vehicles``,
``depart_interval``, ``background_share``, ``styles`` and ``mix``, ``control_noise`` (the closed-loop drivers'
finite rationality: they re-plan with their own MPC every step, so noise on the applied jerk is what makes
them less than rational), the drivers' MPC ``horizon``, and the selection of the demonstrations
(``selection``: whole non-interacting tracks, or every PIRL track with a mask of the steps whose control is
the driver's own; ``min_steps``; ``test_fraction``, the share of tracks split off by the seed for testing;
``n_train``, how many of the rest train, for recovery curves against the training-set size).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from operator import itemgetter
from pathlib import Path
from typing import Any

import numpy as np

from pirl_sim.population import Style

__all__ = [
    "Param",
    "ScenarioData",
    "ScenarioSpec",
    "TrainShape",
    "SCENARIOS",
    "register_scenario",
    "scenario_spec",
    "resolve_scenario_params",
]

PARAM_KINDS = ("int", "float", "range", "rationality", "mix", "styles", "path", "bool", "choice", "table")


@dataclass(frozen=True)
class Param:
    """One scenario parameter.

    Attributes
    ----------
    kind : {"int", "float", "range", "rationality", "mix", "styles", "path", "bool", "choice", "table"}
        ``range`` is a [low, high] pair; ``rationality`` a Boltzmann beta > 0 or ``inf`` (exact optima);
        ``mix`` a table {style name: mixture weight >= 0} over the scenario's styles (0 drops a style);
        ``styles`` a list of preset style names or tables {name, weight, mean, std} (feature name -> value);
        ``path`` a file or directory, relative paths taken from the config file's directory; ``choice`` one of
        ``choices``; ``table`` a table of values that the scenario's ``check`` validates.
    default : JSON value or None
        None for ``path`` means required.
    doc : str
        Meaning and unit.
    choices : tuple of str
        The allowed values of a ``choice``.
    """

    kind: str
    default: Any
    doc: str
    choices: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in PARAM_KINDS:
            raise ValueError(f"parameter kind must be one of {PARAM_KINDS}, got {self.kind!r}")
        if (self.kind == "choice") != bool(self.choices):
            raise ValueError("a 'choice' parameter needs its choices, and only it")


@dataclass(frozen=True)
class ScenarioData:
    """What a scenario gives a sweep cell.

    Attributes
    ----------
    model : DriverModel      dynamics, features and predictor shared by the learners
    train, test : list of Trajectory
        Test trajectories carry ``theta`` (normalised true weights) and ``style`` in their metadata when
        the truth is known.
    style_names : tuple of str   names of the style indices in the metadata, where known
    """

    model: Any
    train: list
    test: list
    style_names: tuple = ()


@dataclass(frozen=True)
class TrainShape:
    """Training set size known before any data is drawn.

    Attributes
    ----------
    n_train : int               training trajectories (an upper bound when ``exact`` is False)
    lengths : tuple of int      steps of the longest ``n_train`` trajectories that can be in the training set
                                (empty: not known before the data exist, e.g. a simulation's tracks)
    exact : bool
    """

    n_train: int
    lengths: tuple[int, ...]
    exact: bool = True

    def n_samples(self, window: int | None, windows: str, stride: int) -> int:
        """Training samples a learner looks up: trajectories, or their feature windows of ``window`` steps
        (``lengths`` empty: not known before the data exist; ``n_train`` trajectories)."""
        if not self.lengths:
            return self.n_train
        if window is None or windows == "first":
            return sum(1 for n in self.lengths if window is None or n >= window)
        return sum((n - window) // stride + 1 for n in self.lengths if n >= window)


@dataclass(frozen=True)
class ScenarioSpec:
    """A registered scenario (see module doc).

    Attributes
    ----------
    name : str
    summary : str
    params : mapping {name: Param}
    check : callable(dict) -> dict
        Complete parameters (defaults merged, kinds converted) -> normalised JSON-serialisable parameters;
        raises ValueError naming the problem.
    build : callable(dict, int) -> ScenarioData, or None (a scenario whose ``run_cells`` reads its own data)
    train_shape : callable(dict) -> TrainShape
    fingerprint : callable(dict) -> str or None
        Hash of the data files a scenario reads (None: nothing read).
    simulation : callable(dict) -> dict, or None
        Simulated scenarios: the parameters the simulation depends on (see module doc); ``build`` then takes
        the directory of the recorded run as a third argument.
    simulate : callable(dict, int, Path), or None
        Records one run of ``simulation(params)`` and a seed into a directory.
    driver_horizon : callable(dict) -> int or None
        The drivers' MPC horizon [steps], where the scenario knows it: the default ``horizon`` of learners
        with ``likelihood = "receding"``.
    run_cells : callable(specs) -> list of (scores, timings), or None
        A scenario's own cell runner (module-level), for the cells of one task (``task_group``; the sweep's
        `pirl_sim.sweep.cell.run_cells` adds the shared timings, warnings and worker); None: the
        sweep's (`pirl_sim.sweep.cell.run_cells`, learners scored by `pirl_sim.harness.experiment.evaluate`).
    task_group : callable(dict) -> str or None, or None
        Which cells run as one task (equal strings; None: alone); None: PIRL-kNN k-grids
        (`pirl_sim.sweep.cell.knn_group`).
    check_protocol : callable(dict, dict), or None
        Checked with the parameters and every protocol (`Protocol` fields) at the config check: ValueError
        (its message follows the scenario's name) for a protocol the scenario cannot run; None: every one.
    learners : tuple of str, or None
        The only learners (sweep names) this scenario runs, checked at the config check; None: the learners
        and baselines that are not some scenario's own (a learner class's ``scenarios`` names where it runs).
    code : tuple of str
        Modules (``.*``: packages) that compute this scenario's cells besides `pirl_sim.sweep.store.CELL_CODE`:
        their source is part of this scenario's cell keys only (`pirl_sim.sweep.store.code_version`).
    """

    name: str
    summary: str
    params: Mapping[str, Param]
    check: Callable[[dict], dict]
    build: Callable[..., ScenarioData] | None
    train_shape: Callable[[dict], TrainShape]
    fingerprint: Callable[[dict], str | None] = field(default=lambda params: None)
    simulation: Callable[[dict], dict] | None = None
    simulate: Callable[[dict, int, Path], None] | None = None
    driver_horizon: Callable[[dict], int | None] | None = None
    run_cells: Callable[..., list] | None = None
    task_group: Callable[[dict], str | None] | None = None
    check_protocol: Callable[[dict, dict], None] | None = None
    learners: tuple[str, ...] | None = None
    code: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if (self.simulation is None) != (self.simulate is None):
            raise ValueError(f"scenario {self.name!r}: give both simulation and simulate, or neither")


SCENARIOS: dict[str, ScenarioSpec] = {}


def register_scenario(spec: ScenarioSpec) -> ScenarioSpec:
    """Add a scenario to `SCENARIOS`; a name can be registered once."""
    if not isinstance(spec, ScenarioSpec):
        raise TypeError(f"expected a ScenarioSpec, got {type(spec).__name__}")
    if spec.name in SCENARIOS:
        raise ValueError(f"scenario {spec.name!r} is already registered")
    SCENARIOS[spec.name] = spec
    return spec


def scenario_spec(name: str) -> ScenarioSpec:
    """The registered scenario ``name``; ValueError listing the registered ones otherwise."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; registered scenarios: {', '.join(sorted(SCENARIOS))}")
    return SCENARIOS[name]


# ------------------------------------------------------------------------------------------ conversion
def _number(label: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{label} must be a number, got {value!r}")
    return float(value)


def _convert(kind: str, label: str, value, base_dir: Path | None, choices: tuple[str, ...] = ()):
    """A TOML value of a parameter as its normalised JSON value."""
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{label} must be an integer, got {value!r}")
        return int(value)
    if kind == "float":
        v = _number(label, value)
        if not math.isfinite(v):
            raise ValueError(f"{label} must be finite, got {value!r}")
        return v
    if kind == "choice":
        if value not in choices or not isinstance(value, str):
            raise ValueError(f"{label} must be one of {', '.join(map(repr, choices))}, got {value!r}")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"{label} must be true or false, got {value!r}")
        return value
    if kind == "range":
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ValueError(f"{label} must be a [low, high] pair, got {value!r}")
        lo, hi = (_number(label, v) for v in value)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"{label} must be [low, high] with finite low <= high, got {value!r}")
        return [lo, hi]
    if kind == "rationality":
        if value is None:
            return None
        v = _number(label, value)
        if v == math.inf:
            return None  # beta -> infinity: exactly optimal demonstrations
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{label} must be a Boltzmann beta > 0 or inf (exact optima), got {value!r}")
        return v
    if kind == "mix":
        if value is None:
            return None
        if not isinstance(value, Mapping) or not value:
            raise ValueError(f"{label} must be a table {{style name = weight}}, got {value!r}")
        out = {}
        for name, w in value.items():
            w = _number(f"{label}[{name!r}]", w)
            if not (math.isfinite(w) and w >= 0):
                raise ValueError(f"{label}[{name!r}] must be a weight >= 0, got {w!r}")
            out[str(name)] = w
        if not any(w > 0 for w in out.values()):
            raise ValueError(f"{label} gives every style weight 0")
        return out
    if kind == "styles":
        if value is None:
            return None
        if not isinstance(value, (list, tuple)) or not value:
            raise ValueError(f"{label} must be a non-empty list of styles, got {value!r}")
        out = []
        for i, s in enumerate(value):
            if isinstance(s, str):
                out.append(s)
                continue
            if not isinstance(s, Mapping):
                raise ValueError(f"{label}[{i}] must be a preset name or a table {{name, weight, mean, std}}")
            valid = ("name", "weight", "mean", "std")
            unknown = [k for k in s if k not in valid]
            if unknown:
                raise ValueError(f"{label}[{i}]: unknown key(s) {unknown}; valid keys: {', '.join(valid)}")
            if "name" not in s or "mean" not in s:
                raise ValueError(f"{label}[{i}] needs at least a name and a mean")
            entry = {"name": str(s["name"]), "weight": _number(f"{label}[{i}].weight", s.get("weight", 1.0))}
            for part in ("mean", "std"):
                table = s.get(part, {})
                if not isinstance(table, Mapping):
                    raise ValueError(f"{label}[{i}].{part} must be a table {{feature name = value}}")
                entry[part] = {str(k): _number(f"{label}[{i}].{part}[{k!r}]", v) for k, v in table.items()}
            out.append(entry)
        return out
    if kind == "table":
        if value is not None and not isinstance(value, Mapping):
            raise ValueError(f"{label} must be a table, got {value!r}")
        return dict(value or {})  # absent: empty
    if kind == "path":
        if value is None:
            raise ValueError(f"{label} is required")
        if not isinstance(value, str) or not value:
            raise ValueError(f"{label} must be a path string, got {value!r}")
        p = Path(value).expanduser()
        if not p.is_absolute() and base_dir is not None:
            p = base_dir / p
        return str(p.resolve())
    raise AssertionError(kind)  # pragma: no cover - Param validates kinds


def resolve_scenario_params(name: str, given: Mapping[str, Any], base_dir: Path | None = None) -> dict:
    """Validate the parameters of scenario ``name`` and complete them with its defaults.

    Parameters
    ----------
    name : str                   a registered scenario
    given : mapping              parameters from a config (TOML values)
    base_dir : Path or None      directory that relative paths are taken from

    Returns
    -------
    dict
        Normalised, JSON-serialisable parameters: what a cell key hashes and what ``build`` receives.

    Raises
    ------
    ValueError
        Unknown scenario or parameter (the valid ones are listed), or a bad value.
    """
    spec = scenario_spec(name)
    unknown = [k for k in given if k not in spec.params]
    if unknown:
        raise ValueError(
            f"scenario {name!r}: unknown parameter(s) {', '.join(map(repr, unknown))}; valid parameters: "
            f"{', '.join(spec.params)}"
        )
    full = {key: _convert(p.kind, f"scenario {name!r} parameter {key!r}", given.get(key, p.default), base_dir,
                          p.choices) for key, p in spec.params.items()}
    try:
        return spec.check(full)
    except TypeError as exc:  # the scenario config's own type checks
        raise ValueError(f"scenario {name!r}: {exc}") from None
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(msg if msg.startswith(f"scenario {name!r}") else f"scenario {name!r}: {msg}") from None


# ------------------------------------------------------------------------------------------ styles
def _styles(label: str, presets, styles, mix, features):
    """Style objects from preset names / tables, mixture weights applied, validated against the features."""
    by_name = {s.name: s for s in presets}
    if styles is None:
        chosen = list(presets)
    else:
        chosen = []
        for s in styles:
            if isinstance(s, str):
                if s not in by_name:
                    raise ValueError(f"{label}: unknown preset style {s!r}; presets: {', '.join(by_name)}")
                chosen.append(by_name[s])
            else:
                chosen.append(Style(s["name"], s["weight"], dict(s["mean"]), dict(s["std"])))
    if mix is not None:
        names = [s.name for s in chosen]
        unknown = [k for k in mix if k not in names]
        if unknown:
            raise ValueError(f"{label}: mix names unknown style(s) {unknown}; styles: {', '.join(names)}")
        chosen = [
            Style(s.name, mix.get(s.name, 0.0), s.mean, s.std, s.cov) for s in chosen if mix.get(s.name, 0.0) > 0
        ]
    for s in chosen:
        s.moments(features)  # unknown feature names, bad covariance
    if len({s.name for s in chosen}) != len(chosen):
        raise ValueError(f"{label}: style names must be unique, got {[s.name for s in chosen]}")
    return chosen


def _style_dicts(styles) -> list[dict]:
    out = []
    for s in styles:
        if s.cov is not None:  # pragma: no cover - presets use std
            raise ValueError(f"style {s.name!r}: a full covariance cannot be written to a sweep config")
        out.append({"name": s.name, "weight": float(s.weight), "mean": {k: float(v) for k, v in s.mean.items()},
                    "std": {k: float(v) for k, v in s.std.items()}})
    return out


# ------------------------------------------------------------------------------------------ synthetic
_SYNTHETIC_PARAMS = {
    "n_trajectories": Param("int", 2000, "trajectories in all (train + test)"),
    "n_train": Param("int", 1800, "training trajectories; the rest are the test set"),
    "n_steps": Param("int", 50, "steps N per trajectory"),
    "dt": Param("float", 0.1, "step [s]"),
    "position_range": Param("range", [1.0, 1.0], "start positions [m], drawn uniformly"),
    "velocity_range": Param("range", [0.0, 0.0], "start velocities [m/s], drawn uniformly"),
    "rationality": Param("rationality", math.inf, "Boltzmann beta; inf: exact LQR optima (the paper's)"),
    "styles": Param("styles", None, "styles over (state_sq, control_sq); default: the paper's two kernels"),
    "mix": Param("mix", None, "mixture weights by style name (0 drops a style); default: the styles' own"),
}


#: the generated scenarios: their module (``generate``), config class, [low, high] parameters and preset styles
_GENERATED = {"synthetic": ("synthetic", "SyntheticConfig", ("position_range", "velocity_range"), "PAPER_STYLES"),
              "passage": ("passage", "PassageConfig", ("start_s", "start_v"), "THREE_STYLES")}


def generated_config(name: str, params: dict, seed: int = 0):
    """The own config dataclass (`SyntheticConfig`, `PassageConfig`) of a generated scenario's parameters."""
    module, cls, ranges, _ = _GENERATED[name]
    p = {k: tuple(v) if k in ranges else v for k, v in params.items() if k != "mix"}
    p["styles"] = tuple(Style(d["name"], d["weight"], dict(d["mean"]), dict(d["std"])) for d in p["styles"])
    return getattr(importlib.import_module(f"pirl_sim.scenarios.{module}"), cls)(**p, seed=seed)


def _build_generated(name: str, params: dict, seed: int) -> ScenarioData:
    data = importlib.import_module(f"pirl_sim.scenarios.{_GENERATED[name][0]}").generate(
        generated_config(name, params, seed))
    return ScenarioData(data.model, data.train, data.test, tuple(s["name"] for s in params["styles"]))


def _check_generated(name: str, params: dict) -> dict:
    """Styles checked against the scenario's features (its preset styles, `_GENERATED`, by name or given), the
    rest by its config dataclass (counts, ranges, dt, geometry)."""
    presets = getattr(importlib.import_module(f"pirl_sim.scenarios.{name}"), _GENERATED[name][3])
    geometry = generated_config(name, dict(params, styles=_style_dicts(presets)))  # all but the styles
    styles = _styles(f"scenario {name!r}", presets, params["styles"], params["mix"], geometry.model().features)
    out = dict(params, styles=_style_dicts(styles))
    out.pop("mix")
    generated_config(name, out)
    return out


def _shape_fixed(params: dict) -> TrainShape:
    return TrainShape(params["n_train"], (params["n_steps"],) * params["n_train"])


# ------------------------------------------------------------------------------------------ passage
_PASSAGE_PARAMS = {
    "radius": Param("float", 20.0, "ring radius [m]"),
    "approach": Param("float", 50.0, "straight approach [m]"),
    "ring_angle_deg": Param("float", 270.0, "part of the ring driven [deg]"),
    "exit_length": Param("float", 50.0, "straight exit [m]"),
    "rationality": Param("rationality", 100.0, "Boltzmann beta; inf: exactly optimal drivers"),
    "styles": Param("styles", None, "styles over (speed_dev, acc_sq, jerk_sq); default: the three user-study styles"),
    "mix": Param("mix", None, "mixture weights by style name (0 drops a style); default: equal"),
    "n_trajectories": Param("int", 600, "passages in all (train + test)"),
    "n_train": Param("int", 500, "training passages; the rest are the test set"),
    "n_steps": Param("int", 40, "steps per passage"),
    "dt": Param("float", 0.2, "step [s]"),
    "start_s": Param("range", [10.0, 40.0], "start positions along the path [m]"),
    "start_v": Param("range", [9.0, 12.0], "start speeds [m/s]"),
}


# ------------------------------------------------------------------------------------------ simulators
_SIMULATED_PARAMS = {
    "n_vehicles": Param("int", 24, "vehicles in the run, PIRL and background"),
    "depart_interval": Param("float", 4.0, "time between departures [s]"),
    "background_share": Param("float", 0.2, "share of vehicles driven by the simulator's own model, in [0, 1)"),
    "styles": Param("styles", None, "styles over (speed_dev, acc_sq), jerk_sq = 1: preset names "
                    "(population_config.PRESET_STYLES) or tables {name, weight, mean, std}; default: the paper's three"),
    "mix": Param("mix", None, "mixture weights by style name (0 drops a style); default: the styles' own"),
    "control_noise": Param("float", 0.0, "standard deviation of the noise on every applied jerk [m/s^3]: the "
                           "closed-loop drivers' finite rationality"),
    "horizon": Param("int", 30, "the PIRL drivers' MPC horizon [steps of 0.1 s]"),
    "selection": Param("choice", "steps", "demonstrations: 'tracks' (whole non-interacting PIRL tracks) or 'steps' "
                       "(every PIRL track, the steps whose control is the driver's own)", choices=("tracks", "steps")),
    "min_steps": Param("int", 10, "shortest demonstration kept [steps]; with 'steps': usable steps"),
    "test_fraction": Param("float", 0.25, "share of the demonstrations in the test set (split by the seed)"),
    "n_train": Param("int", 0, "training demonstrations kept, the first of the seed's random order (nested: a "
                     "smaller n_train keeps a subset of a larger one's); 0: every one the split leaves"),
}
#: parameters that choose demonstrations from a run; the rest make the run
_SELECTION_PARAMS = ("selection", "min_steps", "test_fraction", "n_train")


def _population(label: str, params: dict):
    """The run's `PopulationConfig` (validated there; errors name the parameter)."""
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, population_from_dict

    if params["styles"] is None:
        styles = [s.to_dict() for s in DEFAULT_POPULATION.styles]
    else:
        styles = [{"preset": s} if isinstance(s, str) else dict(s) for s in params["styles"]]
    data = {k: params[k] for k in ("n_vehicles", "depart_interval", "background_share", "control_noise")}
    pop = population_from_dict({**data, "styles": styles}, source=label)
    mix = params.get("mix")
    if mix is not None:
        names = [s.name for s in pop.styles]
        unknown = [k for k in mix if k not in names]
        if unknown:
            raise ValueError(f"{label}: mix names unknown style(s) {unknown}; styles: {', '.join(names)}")
        kept = [dict(s.to_dict(), weight=mix.get(s.name, 0.0)) for s in pop.styles if mix.get(s.name, 0.0) > 0]
        pop = population_from_dict({**data, "styles": kept}, source=label)
    return pop


def _simulator(name: str):
    """The simulator's scenario module (`pirl_sim.scenarios.sumo.scenario` or ``.highway.scenario``); ValueError
    naming the extra to install when its packages are missing (the config check fails so, not at a cell)."""
    try:
        return importlib.import_module(f"pirl_sim.scenarios.{name}.scenario")
    except ModuleNotFoundError as exc:
        raise ValueError(f"scenario {name!r} needs the {name} extra: pip install -e '.[{name}]' ({exc.name} is "
                         "not installed)") from None


def _simulator_config(name: str, params: dict):
    """The simulator's scenario configuration of (simulation) parameters."""
    table = {"population": _population(f"scenario {name!r}", params).to_dict(),
             "drivers": {"horizon": params["horizon"]}}
    return _simulator(name).scenario_from_dict(table, source=f"scenario {name!r}")


def _check_simulated(name: str, params: dict) -> dict:
    for key, low in (("n_vehicles", 2), ("min_steps", 1), ("horizon", 1), ("n_train", 0)):
        if params[key] < low:
            raise ValueError(f"scenario {name!r} parameter {key!r} must be >= {low}, got {params[key]!r}")
    if not 0 < params["test_fraction"] < 1:
        raise ValueError(f"scenario {name!r} parameter 'test_fraction' must be in (0, 1), got "
                         f"{params['test_fraction']!r}")
    config = _simulator_config(name, params)  # validates the population and the drivers
    n_pirl = params["n_vehicles"] - int(math.floor(params["background_share"] * params["n_vehicles"]))
    if params["n_train"] > n_pirl - 1:
        raise ValueError(f"scenario {name!r} parameter 'n_train' = {params['n_train']} exceeds the {n_pirl - 1} "
                         f"training tracks a run of {params['n_vehicles']} vehicles can give at most")
    out = dict(params, styles=[s.to_dict() for s in config.population.styles])
    out.pop("mix")
    return out


def _simulation_params(params: dict) -> dict:
    return {k: v for k, v in params.items() if k not in _SELECTION_PARAMS}


def _simulate(name: str, params: dict, seed: int, out_dir: Path) -> None:
    config = _simulator_config(name, dict(params, mix=None))
    getattr(_simulator(name), f"run_{name}_scenario")(config, seed, out_dir=out_dir)


def _split(n: int, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) indices of n demonstrations: the seed's random order, its first test_fraction test."""
    order = np.random.default_rng(seed).permutation(n)
    n_test = max(1, int(round(test_fraction * n)))
    return order[n_test:], order[:n_test]


def _build_simulated(name: str, params: dict, seed: int, simulation_dir: Path) -> ScenarioData:
    run = getattr(_simulator(name), f"load_{name}_run")(simulation_dir)
    demos = run.demonstrations(selection=params["selection"], min_steps=params["min_steps"])
    if len(demos) < 2:
        raise ValueError(f"scenario {name!r}: only {len(demos)} demonstrations with selection "
                         f"{params['selection']!r} and min_steps {params['min_steps']} (more vehicles?)")
    train, test = _split(len(demos), params["test_fraction"], seed)
    if params["n_train"]:
        if params["n_train"] > len(train):
            raise ValueError(f"scenario {name!r}: n_train = {params['n_train']} but the run gives {len(train)} "
                             f"training demonstrations (more vehicles, or a smaller n_train)")
        train = train[:params["n_train"]]
    names = tuple(s.name for s in run.config.population.styles)
    return ScenarioData(run.model, [demos[i] for i in train], [demos[i] for i in test], names)


def _shape_simulated(params: dict) -> TrainShape:
    """At most every PIRL vehicle but one test track; lengths are known only after the run."""
    n_pirl = params["n_vehicles"] - int(math.floor(params["background_share"] * params["n_vehicles"]))
    return TrainShape(params["n_train"] or max(n_pirl - 1, 1), (), exact=False)


register_scenario(ScenarioSpec(
    "synthetic", "the paper's 1-D point mass regulated by LQR, theta = q/r from two kernels",
    _SYNTHETIC_PARAMS, partial(_check_generated, "synthetic"), partial(_build_generated, "synthetic"), _shape_fixed,
))
register_scenario(ScenarioSpec(
    "passage", "roundabout passage, drivers of the paper's three user-study styles",
    _PASSAGE_PARAMS, partial(_check_generated, "passage"), partial(_build_generated, "passage"), _shape_fixed,
))
for _name, _summary in (
        ("sumo", "SUMO roundabout (libsumo), PIRL drivers of known weights re-planning every 0.1 s among SUMO's own"),
        ("highway", "highway-env roundabout, PIRL drivers of known weights re-planning every 0.1 s among IDM "
                    "vehicles")):
    register_scenario(ScenarioSpec(
        _name, _summary, _SIMULATED_PARAMS, partial(_check_simulated, _name), partial(_build_simulated, _name),
        _shape_simulated, simulation=_simulation_params, simulate=partial(_simulate, _name),
        driver_horizon=itemgetter("horizon"),  # the drivers' own
    ))

from . import recorded as _recorded  # noqa: E402,F401  registers the 'recorded' scenario and its old name 'replay'
from . import agents as _agents  # noqa: E402,F401  registers the 'agents' scenario
