"""Sweep configs: TOML -> frozen, validated dataclasses -> the grid's cells.

A config lists experiments, each a block of the grid: a registered scenario
(`pirl_sim.experiments.registry.SCENARIOS`) with fixed ``params`` and a ``grid`` of parameters to vary,
``protocols``, ``learners`` (a name, or a table with ``params`` and a ``grid``) and ``seeds``. Its cells are the
grid points, scenario variant x protocol x learner variant x seed; a cell that appears in two experiments is
computed once. Every table rejects unknown keys, naming the valid ones, and everything is checked when the config
is built, before any work starts.

The schema and the checks are explained in the documentation's "Sweeps" page (the config).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

from pirl_sim.evaluation.protocols import PROTOCOL_KINDS, Protocol
from pirl_sim.io import toml_text
from pirl_sim.validation import SEED_LIMIT, check_keys, is_positive_int

from pirl_sim.evaluation.baselines import BASELINES
from pirl_sim.experiments.registry import PROTOCOL_FREE, resolve_scenario_params, scenario_spec

__all__ = ["Choice", "GridAxis", "LearnerGrid", "ProtocolGrid", "Experiment", "Cell", "SweepConfig", "LEARNER_DISPLAY",
           "load_config", "parse_config", "default_config", "DEFAULT_CONFIG_TEXT", "preset_text", "canonical_json",
           "sweep_learners"]

TOP_KEYS = ("name", "description", "seeds", "experiments")
EXPERIMENT_KEYS = ("scenario", "label", "seeds", "params", "grid", "protocols", "learners")
LEARNER_KEYS = ("name", "label", "params", "grid")
PROTOCOL_FIELDS = ("kind", "history_steps", "horizon", "stride", "window_mode")
PROTOCOL_KEYS = PROTOCOL_FIELDS + ("grid",)
#: set by the sweep: the model by the scenario, the feature window by the protocol
RESERVED_LEARNER_PARAMS = ("model", "window", "windows")
#: learner parameters that are the "k" of the paper's figures
K_PARAMS = {"pirl-knn": "n_neighbors", "pirl-gmm": "n_components"}
LEARNER_DISPLAY = {"tirl": "TIRL", "pirl-gmm": "PIRL-GMM", "pirl-dpgmm": "PIRL-DPGMM", "pirl-knn": "PIRL-kNN",
                   "cv": "CV", "ca": "CA", "ppo": "PPO"}


def sweep_learners() -> dict:
    """Learners a sweep runs, by name: `pirl_sim.learners.LEARNERS`, the kinematic baselines
    (`pirl_sim.evaluation.baselines.BASELINES`) and the learners of single kinds
    (`pirl_sim.experiments.registry.KIND_LEARNERS`: the agents' policies, the recovery kind's IRL)."""
    from pirl_sim.learners import LEARNERS

    from pirl_sim.experiments.registry import KIND_LEARNERS

    return {**LEARNERS, **BASELINES, **KIND_LEARNERS}


def canonical_json(obj) -> str:
    """Sorted keys, no spaces, no NaN: the same object always gives the same string (what keys hash)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)


def _jsonable(label: str, value):
    """TOML value -> JSON value (tuples as lists); dates, times and nan are rejected, naming the key (``label``
    and the path to the value inside it)."""
    if isinstance(value, float) and math.isnan(value):  # inf has uses (e.g. rationality = inf: exact optima)
        raise ValueError(f"{label}: nan is not allowed; give a number")
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    if isinstance(value, (list, tuple)):
        return [_jsonable(f"{label}[{i}]", v) for i, v in enumerate(value)]
    if isinstance(value, Mapping):
        return {str(k): _jsonable(f"{label}.{k}", v) for k, v in value.items()}
    raise ValueError(f"{label}: unsupported value {value!r} ({type(value).__name__})")


@contextmanager
def _named(prefix: str, errors=(ValueError,)):
    """Re-raise ``errors`` of the block as a ValueError ``prefix`` + its message (naming where it happened)."""
    try:
        yield
    except errors as exc:
        raise ValueError(f"{prefix}{exc}") from None


def _params(label: str, entry: Mapping) -> dict:
    """The table ``params`` of a config entry (default empty) as JSON data."""
    params = entry.get("params", {})
    if not isinstance(params, Mapping):
        raise ValueError(f"{label}.params must be a table, got {params!r}")
    return {str(k): _jsonable(f"{label}.params.{k}", v) for k, v in params.items()}


def _fmt(value) -> str:
    """A short label for a grid value."""
    if isinstance(value, float):
        return "inf" if value == math.inf else f"{value:g}"
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k}: {_fmt(v)}" for k, v in value.items()) + "}"
    return str(value)


def _seeds(label: str, value) -> tuple[int, ...]:
    if not isinstance(value, (list, tuple)):
        raise ValueError(f"{label} must be a list of integers, got {value!r}")
    if not value:
        raise ValueError(f"empty grid: {label} is an empty list")
    for s in value:
        if isinstance(s, bool) or not isinstance(s, int) or not 0 <= s < SEED_LIMIT:
            raise ValueError(f"{label} must hold integers in [0, 2**31), got {s!r}")
    if len(set(value)) != len(value):
        raise ValueError(f"{label} repeats a seed: {list(value)}")
    return tuple(value)


# ------------------------------------------------------------------------------------------ grid pieces
@dataclass(frozen=True)
class Choice:
    """One value of a grid axis and its label in tables and figures."""

    label: str
    value: Any


@dataclass(frozen=True)
class GridAxis:
    """A parameter and the values the grid takes for it (in order)."""

    name: str
    choices: tuple[Choice, ...]

    def __post_init__(self) -> None:
        if not self.choices:
            raise ValueError(f"empty grid: no value for {self.name!r}")

    @classmethod
    def parse(cls, label: str, name: str, value) -> "GridAxis":
        """A list of values (labelled by the values) or a table {variant label: value}."""
        if isinstance(value, Mapping):
            choices = tuple(Choice(str(k), _jsonable(f"{label}.{name}.{k}", v)) for k, v in value.items())
        elif isinstance(value, (list, tuple)):
            choices = tuple(Choice(_fmt(v), _jsonable(f"{label}.{name}[{i}]", v)) for i, v in enumerate(value))
        else:
            raise ValueError(f"{label}.{name} must be a list of values or a table of named values, got {value!r}")
        if not choices:
            raise ValueError(f"empty grid: {label}.{name} has no value")
        if len({c.label for c in choices}) != len(choices):
            raise ValueError(f"{label}.{name} repeats a value: {[c.label for c in choices]}")
        return cls(name, choices)


def _parse_grid(label: str, grid, fixed: Mapping) -> tuple[GridAxis, ...]:
    if grid is None:
        return ()
    if not isinstance(grid, Mapping):
        raise ValueError(f"{label} must be a table {{parameter = [values]}}, got {grid!r}")
    if both := [k for k in grid if k in fixed]:
        raise ValueError(f"{label}: {both} given both as fixed parameters and in the grid")
    return tuple(GridAxis.parse(label, str(k), v) for k, v in grid.items())


def _learner_defaults(name) -> dict:
    """The default parameters of the sweep learner ``name`` less those the sweep sets (`RESERVED_LEARNER_PARAMS`);
    ValueError naming the learners for an unknown one."""
    learners = sweep_learners()
    if name not in learners:
        raise ValueError(f"unknown learner {name!r}; choose one of {', '.join(sorted(learners))}")
    return {k: v for k, v in learners[name]().get_params().items() if k not in RESERVED_LEARNER_PARAMS}


def _points(axes: tuple[GridAxis, ...]):
    """Every combination of the axes' choices: list of ({name: value}, [(name, label)]) (no axes: one, empty)."""
    return [({a.name: c.value for a, c in zip(axes, combo)}, [(a.name, c.label) for a, c in zip(axes, combo)])
            for combo in itertools.product(*(a.choices for a in axes))]


@dataclass(frozen=True)
class LearnerGrid:
    """A learner and the values of its parameters (fixed ones and a grid)."""

    name: str
    label: str
    params: Mapping[str, Any]
    grid: tuple[GridAxis, ...] = ()

    def __post_init__(self) -> None:
        valid = tuple(_learner_defaults(self.name))
        for key in [*self.params, *(a.name for a in self.grid)]:
            if key in RESERVED_LEARNER_PARAMS:
                raise ValueError(f"learner {self.name!r}: {key!r} is set by the sweep (model: the scenario; window, "
                                 "windows: the protocol)")
            if key not in valid:
                raise ValueError(f"learner {self.name!r}: unknown parameter {key!r}; valid parameters: "
                                 f"{', '.join(valid)}")
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))

    @classmethod
    def parse(cls, label: str, entry) -> "LearnerGrid":
        entry = {"name": entry} if isinstance(entry, str) else entry
        check_keys(label, entry, LEARNER_KEYS)
        if "name" not in entry:
            raise ValueError(f"{label} needs a name (one of {', '.join(LEARNER_DISPLAY)})")
        name, params = entry["name"], _params(label, entry)
        display = entry.get("label", LEARNER_DISPLAY.get(name, str(name)))
        return cls(name, str(display), params, _parse_grid(f"{label}.grid", entry.get("grid"), params))


@dataclass(frozen=True)
class ProtocolGrid:
    """A protocol (`pirl_sim.evaluation.protocols.Protocol` fields, steps) and a grid over its fields."""

    fields: Mapping[str, Any]
    grid: tuple[GridAxis, ...] = ()

    def __post_init__(self) -> None:
        kind = self.fields.get("kind")
        if kind not in PROTOCOL_KINDS:
            raise ValueError(f"unknown protocol kind {kind!r}; choose one of {', '.join(PROTOCOL_KINDS)}")
        for a in self.grid:
            if a.name not in PROTOCOL_FIELDS[1:]:
                raise ValueError(f"protocol grid: unknown key {a.name!r}; valid keys: {', '.join(PROTOCOL_FIELDS[1:])}")
        object.__setattr__(self, "fields", MappingProxyType(dict(self.fields)))

    @classmethod
    def parse(cls, label: str, entry) -> "ProtocolGrid":
        entry = {"kind": entry} if isinstance(entry, str) else entry
        check_keys(label, entry, PROTOCOL_KEYS)
        fields = {k: _jsonable(f"{label}.{k}", v) for k, v in entry.items() if k != "grid"}
        return cls(fields, _parse_grid(f"{label}.grid", entry.get("grid"), fields))

    def points(self) -> list[dict]:
        """Complete Protocol fields for every grid point."""
        defaults = {"history_steps": None, "horizon": None, "stride": 1,
                    "window_mode": "sliding" if self.fields["kind"] == "rolling" else "first"}
        points = ({**defaults, **self.fields, **values} for values, _ in _points(self.grid))
        return [{k: f[k] for k in PROTOCOL_FIELDS} for f in points]


@dataclass(frozen=True)
class Experiment:
    """One block of the grid: a scenario (and a grid over its parameters) x protocols x learners x seeds."""

    scenario: str
    label: str
    params: Mapping[str, Any]
    grid: tuple[GridAxis, ...]
    protocols: tuple[ProtocolGrid, ...]
    learners: tuple[LearnerGrid, ...]
    seeds: tuple[int, ...]
    base_dir: str | None = None

    def __post_init__(self) -> None:
        spec = scenario_spec(self.scenario)  # unknown scenario: ValueError naming the registered ones
        for a in self.grid:
            if a.name not in spec.params:
                raise ValueError(f"scenario {self.scenario!r}: unknown parameter {a.name!r} in the grid; valid "
                                 f"parameters: {', '.join(spec.params)}")
        for what, values in (("protocol", self.protocols), ("learner", self.learners), ("seed", self.seeds)):
            if not values:
                raise ValueError(f"empty grid: experiment {self.label!r} has no {what}")
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))

    @classmethod
    def parse(cls, label: str, entry, default_seeds, base_dir: Path | None) -> "Experiment":
        check_keys(label, entry, EXPERIMENT_KEYS)
        if "scenario" not in entry:
            raise ValueError(f"{label} needs a scenario")
        scenario = scenario_spec(entry["scenario"]).name  # unknown: ValueError naming the registered ones
        params = _params(label, entry)
        grid, seeds = _parse_grid(f"{label}.grid", entry.get("grid"), params), entry.get("seeds", default_seeds)
        if seeds is None:
            raise ValueError(f"{label} has no seeds (give seeds here or at the top level)")
        protocols = entry.get("protocols", ["paper"] if scenario in PROTOCOL_FREE else [])
        learners = entry.get("learners", [])
        for key, v in (("protocols", protocols), ("learners", learners)):
            if not isinstance(v, list):
                raise ValueError(f"{label}.{key} must be a list, got {v!r}")
        return cls(scenario, str(entry.get("label", scenario)), params, grid,
                   tuple(ProtocolGrid.parse(f"{label}.protocols[{i}]", p) for i, p in enumerate(protocols)),
                   tuple(LearnerGrid.parse(f"{label}.learners[{i}]", lg) for i, lg in enumerate(learners)),
                   _seeds(f"{label}.seeds", seeds), None if base_dir is None else str(base_dir))


# ------------------------------------------------------------------------------------------ cells
@dataclass(frozen=True)
class Cell:
    """One grid point: everything a worker needs (``spec()``) and how it is labelled in tables.

    Attributes
    ----------
    scenario : str                       registered scenario name
    scenario_params : mapping            complete, normalised parameters
    data_fingerprint : str or None       hash of the files the scenario reads
    protocol : mapping                   `Protocol` fields (steps)
    learner : str                        `pirl_sim.learners.LEARNERS` name
    learner_params : mapping             complete parameters (without model, window, windows)
    seed : int                           data seed (and learner random_state unless given)
    experiment : str                     label of the experiment block
    scenario_label, protocol_label, learner_label : str
    k : int or None                      n_neighbors (kNN) or n_components (GMM)
    """

    scenario: str
    scenario_params: Mapping[str, Any]
    data_fingerprint: str | None
    protocol: Mapping[str, Any]
    learner: str
    learner_params: Mapping[str, Any]
    seed: int
    experiment: str
    scenario_label: str
    protocol_label: str
    learner_label: str
    k: int | None = None

    def spec(self) -> dict:
        """The cell's full configuration as plain JSON data: what a worker runs and what the key hashes."""
        return {"scenario": self.scenario, "scenario_params": json.loads(canonical_json(dict(self.scenario_params))),
                "data_fingerprint": self.data_fingerprint, "protocol": dict(self.protocol), "learner": self.learner,
                "learner_params": json.loads(canonical_json(dict(self.learner_params))), "seed": self.seed}

    def key(self, code_version: str) -> str:
        """sha256 of the full configuration and the code version (32 hex digits)."""
        blob = canonical_json({"cell": self.spec(), "code_version": code_version})
        return hashlib.sha256(blob.encode()).hexdigest()[:32]

    def labels(self) -> dict:
        return {"experiment": self.experiment, "scenario_label": self.scenario_label,
                "protocol_label": self.protocol_label, "learner_label": self.learner_label, "k": self.k}


def _learner_label(grid: LearnerGrid, params: dict, varied: list[tuple[str, str]]) -> tuple[str, int | None]:
    kname = K_PARAMS.get(grid.name)
    k = params.get(kname) if kname and params.get("aggregate") != "selected" else None  # a bank's choice: no k
    parts = ([] if k is None else [f"k={k}"]) + [f"{n}={lab}" for n, lab in varied if n != kname]
    return grid.label + (f" ({', '.join(parts)})" if parts else ""), (k if isinstance(k, int) else None)


def _check_learner(label: str, grid: LearnerGrid, params: dict, proto, shape) -> None:
    """Values we can check without data: k against the training samples, windows, enums (``log_bounds``: the
    learner's own `_check_common`)."""
    protocol_params = proto.learner_params()
    learner = sweep_learners()[grid.name](**params, **protocol_params)
    with _named(f"{label}: "):
        learner._check_common()
    for name, bic in (("n_neighbors", False), ("n_components", True), ("max_components", False)):
        v = params.get(name, 1)  # absent: nothing to check
        if not (is_positive_int(v) or (bic and v == "bic")):
            allowed = "a positive integer" + (' or "bic"' if bic else "")
            raise ValueError(f"{label}: {name} must be {allowed}, got {v!r}")
    kname = K_PARAMS.get(grid.name)
    k, window = params.get(kname) if kname else None, protocol_params["window"]
    if isinstance(k, int) and (shape.lengths or window is None or protocol_params.get("windows") == "first"):
        n = shape.n_samples(window, protocol_params.get("windows", "first"), params.get("stride", 1))
        what = "trajectories" if window is None else f"windows of {window} steps"
        bound = "" if shape.exact else "at most "
        if k > n:
            raise ValueError(f"{label}: k = {kname} = {k} is larger than the training set ({bound}{n} training "
                             f"{what} from {bound}{shape.n_train} trajectories)")
    rs = params.get("random_state")
    if rs is not None and (isinstance(rs, bool) or not isinstance(rs, int) or not 0 <= rs < SEED_LIMIT):
        raise ValueError(f"{label}: random_state must be an integer in [0, 2**31) or absent, got {rs!r}")
    if grid.name in ("pirl-gmm", "pirl-dpgmm"):
        _check_mixture(label, grid.name, params)
    if grid.name == "pirl-knn":
        from pirl_sim.learners.knn import AGGREGATES, AVERAGES, PRIORS, SEGMENT_STARTS, SELECTORS, TARGETS, WEIGHTINGS

        for key, choices in (("average", AVERAGES), ("prior", PRIORS), ("weighting", WEIGHTINGS), ("target", TARGETS),
                             ("aggregate", AGGREGATES), ("selector", SELECTORS), ("segment_start", SEGMENT_STARTS)):
            read = key != "selector" or params.get("aggregate") == "selected"  # a selector only serves "selected"
            if read and key in params and params[key] not in choices:
                raise ValueError(f"{label}: {key} must be one of {choices}, got {params[key]!r}")


def _check_mixture(label: str, name: str, params: dict) -> None:
    """The scikit-learn mixture's own parameter check (``covariance_type``, ``n_init``, ``max_iter``, ...), run
    on the parameters the learner passes to it, so that a bad value fails when the config is built."""
    from sklearn.mixture import BayesianGaussianMixture, GaussianMixture

    k = params.get("n_components", 2) if name == "pirl-gmm" else params.get("max_components", 1)
    common = {"n_components": k if isinstance(k, int) else 1, "covariance_type": params.get("covariance_type", "full"),
              "n_init": params.get("n_init", 1), "random_state": params.get("random_state")}
    mixture = GaussianMixture(**common) if name == "pirl-gmm" else BayesianGaussianMixture(
        **common, weight_concentration_prior=params.get("weight_concentration_prior"),
        max_iter=params.get("max_iter", 100))
    with _named(f"{label}: ", (TypeError, ValueError)):
        mixture._validate_params()
    if name == "pirl-dpgmm" and "max_iter" in params and not is_positive_int(params["max_iter"]):
        raise ValueError(f"{label}: max_iter must be a positive number of iterations of the mixture's fit, got "
                         f"{params['max_iter']!r}")  # scikit-learn allows 0; the learner does not
    if "min_cluster_size" in params and not is_positive_int(params["min_cluster_size"]):
        raise ValueError(f"{label}: min_cluster_size must be a positive integer, got {params['min_cluster_size']!r}")


def _expand(experiments: tuple[Experiment, ...]) -> tuple[Cell, ...]:
    cells: list[Cell] = []
    for e_idx, exp in enumerate(experiments):
        elabel = f"experiment {e_idx + 1} ({exp.label})"
        own: dict[str, Cell] = {}  # the same point twice in one experiment runs once
        spec = scenario_spec(exp.scenario)
        for lgrid in exp.learners:
            _check_runs_here(elabel, exp.scenario, lgrid.name)
        base = None if exp.base_dir is None else Path(exp.base_dir)
        for values, varied in _points(exp.grid):
            with _named(f"{elabel}: "):
                params = resolve_scenario_params(exp.scenario, {**exp.params, **values}, base)
            with _named(f"{elabel}: scenario {exp.scenario!r} cannot read its data: ", (OSError, ValueError, KeyError)):
                shape, fingerprint = spec.train_shape(params), spec.fingerprint(params)
            slabel = exp.label + (f" ({', '.join(f'{n}={lab}' for n, lab in varied)})" if varied else "")
            longest = max(shape.lengths, default=0)
            for fields in (f for pgrid in exp.protocols for f in pgrid.points()):
                with _named(f"{elabel}: protocol {dict(fields)}: ", (TypeError, ValueError)):
                    proto = Protocol(**fields)
                with _named(f"{elabel}: scenario {exp.scenario!r} ", (TypeError, ValueError)):
                    (spec.check_protocol or (lambda *_: None))(params, dict(fields))
                if shape.lengths and proto.steps_needed() > longest:
                    raise ValueError(f"{elabel}: the {proto.name} protocol needs trajectories of at least "
                                     f"{proto.steps_needed()} steps; the scenario's have at most {longest}")
                for lgrid in exp.learners:
                    defaults = _learner_defaults(lgrid.name)
                    for lvalues, lvaried in _points(lgrid.grid):
                        given = {**lgrid.params, **lvalues}
                        lparams = {**defaults, **given}
                        llabel, k = _learner_label(lgrid, lparams, lvaried)
                        if (lparams.get("likelihood") == "receding" and lparams.get("horizon") is None
                                and spec.driver_horizon is not None):
                            lparams["horizon"] = spec.driver_horizon(params)  # the drivers' own
                        seeded = "random_state" in defaults and "random_state" not in given  # the seed unless given
                        for seed in exp.seeds:
                            cell_params = _jsonable(llabel, {**lparams, "random_state": seed} if seeded else lparams)
                            _check_learner(f"{elabel}: {llabel} under the {proto.name} protocol", lgrid,
                                           _tuples(cell_params), proto, shape)
                            if spec.check_learner is not None:
                                with _named(f"{elabel}: {llabel}: scenario {exp.scenario!r} ", (TypeError, ValueError)):
                                    spec.check_learner(params, lgrid.name, cell_params)
                            cell = Cell(exp.scenario, params, fingerprint, fields, lgrid.name, cell_params, seed,
                                        exp.label, slabel, proto.name, llabel, k)
                            own.setdefault(canonical_json(cell.spec()), cell)
        cells += own.values()
    return tuple(cells)


def _check_runs_here(label: str, scenario: str, learner: str) -> None:
    """ValueError unless ``scenario`` runs ``learner``: its `ScenarioSpec.learners` when it names them, else any
    learner that is not another scenario's own (a class attribute ``scenarios``)."""
    spec, own = scenario_spec(scenario), getattr(sweep_learners()[learner], "scenarios", None)
    if spec.learners is not None and learner not in spec.learners:
        raise ValueError(f"{label}: scenario {scenario!r} runs the learners {list(spec.learners)} only, got "
                         f"{learner!r}")
    if spec.learners is None and own is not None and scenario not in own:
        raise ValueError(f"{label}: {learner!r} runs in the scenario(s) {list(own)} only, not in {scenario!r}")


def _tuples(params: dict) -> dict:
    """JSON lists back to the tuples learners expect (log_bounds)."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in params.items()}


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep: its experiments and the cells they expand to (checked when built).

    Attributes
    ----------
    name, description : str
    experiments : tuple of Experiment
    source : str          where the config came from (a path or "<default>")
    text : str            the TOML text (kept with the results)
    cells : tuple of Cell (computed)
    """

    name: str
    description: str
    experiments: tuple[Experiment, ...]
    source: str = "<dict>"
    text: str = ""
    cells: tuple[Cell, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.experiments:
            raise ValueError("empty grid: the sweep has no [[experiments]]")
        labels = [e.label for e in self.experiments]
        for i, lab in enumerate(labels):
            if lab in labels[:i]:
                raise ValueError(f"experiments {labels.index(lab) + 1} and {i + 1} are both labelled {lab!r}: give "
                                 "one a label")
        object.__setattr__(self, "cells", _expand(self.experiments))


def parse_config(data: Mapping[str, Any], *, base_dir=None, source: str = "<dict>", text: str = "") -> SweepConfig:
    """Validate a config given as a mapping (parsed TOML) into a `SweepConfig`.

    Parameters
    ----------
    data : mapping                see the module doc for the schema
    base_dir : path or None       directory that relative scenario paths are taken from
    source, text : str            recorded with the results

    Raises
    ------
    ValueError
        Naming the problem: unknown keys (with the valid ones), scenario, learner or protocol kind, an empty
        grid, a bad value, or a k larger than the training set.
    """
    check_keys("sweep config", data, TOP_KEYS)
    default_seeds = None if data.get("seeds") is None else _seeds("seeds", data["seeds"])
    exps = data.get("experiments", [])
    if not isinstance(exps, list):
        raise ValueError(f"experiments must be an array of tables ([[experiments]]), got {exps!r}")
    base = None if base_dir is None else Path(base_dir)
    experiments = tuple(Experiment.parse(f"experiments[{i}]", e, default_seeds, base) for i, e in enumerate(exps))
    name = data.get("name", Path(source).stem if source.endswith(".toml") else "sweep")
    return SweepConfig(str(name), str(data.get("description", "")), experiments, source, text)


def load_config(path) -> SweepConfig:
    """Read and validate a TOML sweep config; ``"default"`` is the embedded `default_config`."""
    if str(path) == "default":
        return default_config()
    path = Path(path)
    try:
        data, text = toml_text.load(path, "sweep config")
    except FileNotFoundError:
        raise ValueError(f"sweep config {str(path)!r} not found") from None
    return parse_config(data, base_dir=path.resolve().parent, source=str(path), text=text)


def preset_text(name: str) -> str:
    """The embedded sweep config ``pirl_sim/experiments/configs/<name>.toml`` (e.g. default, synthetic, passage) as text."""
    return resources.files("pirl_sim.experiments").joinpath("configs", f"{name}.toml").read_text(encoding="utf-8")


DEFAULT_CONFIG_TEXT = preset_text("default")


def default_config() -> SweepConfig:
    """The embedded default sweep (`pirl_sim/experiments/configs/default.toml`): the paper's experiments on the simulators."""
    return parse_config(toml_text.loads(DEFAULT_CONFIG_TEXT, "<default>"), source="<default>", text=DEFAULT_CONFIG_TEXT)
