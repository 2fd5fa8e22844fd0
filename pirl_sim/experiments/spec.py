"""The scenario registry of sweeps: a name -> how to build train/test data from a validated parameter dict.

Each entry is a `ScenarioSpec`: the valid parameters (`Param`: kind, default, meaning), a ``check`` that turns
a config's parameters into a complete, JSON-serialisable dict, a ``build`` that draws the data for one seed, a
``train_shape`` that tells the sweep how many training trajectories of which lengths there will be and, for
scenarios that read files, a ``fingerprint`` of their content. Simulated scenarios (``sumo``, ``highway``) also
give ``simulation`` and ``simulate``, so that each run is recorded once and shared by the cells that use it.

The fields, how to add a scenario and the simulated scenarios' parameters are explained in the documentation's
"Architecture" page (how the engine knows experiment kinds) and "Sweeps" page.
"""

from __future__ import annotations

import dataclasses
import typing

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from pirl_sim.validation import number


__all__ = ["Param", "ScenarioData", "ScenarioSpec", "TrainShape", "PARAM_KINDS", "convert_param", "split_indices", "dataclass_params"]

PARAM_KINDS = ("int", "float", "range", "rationality", "mix", "styles", "path", "bool", "choice", "table")


@dataclass(frozen=True)
class Param:
    """One scenario parameter (the kinds: "Sweeps" page, The config).

    Attributes
    ----------
    kind : {"int", "float", "range", "rationality", "mix", "styles", "path", "bool", "choice", "table"}
    default : JSON value or None   None for ``path`` means required
    doc : str                      meaning and unit
    choices : tuple of str         the allowed values of a ``choice``
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
    """A registered scenario (module doc; the architecture page explains each field and gives its signature).

    Attributes
    ----------
    name, summary, params : str, str, mapping {name: Param}
    check : callable(dict) -> dict            complete parameters -> normalised JSON-serialisable ones; ValueError
    build, train_shape : callable   (dict, int) -> ScenarioData, or None (``run_cells`` reads its data); -> TrainShape
    fingerprint, simulation : callable or None   hash of the data files a scenario reads; a simulation's parameters
    simulate, driver_horizon : callable or None   records one run of ``simulation(params)``; the MPC horizon [steps]
    run_cells : callable(specs), or None      the scenario's own cell runner; None: `pirl_sim.engine.worker.run_cells`
    task_group : callable(dict), or None      which cells run as one task; None: `pirl_sim.engine.worker.knn_group`
    check_protocol : callable(dict, dict), or None   ValueError for a protocol the scenario cannot run
    check_learner : callable(dict, str, dict), or None   ValueError for a learner (name, parameters) it cannot run
    learners, code : tuple of str (or None)   the only learners this scenario runs; modules hashed into its keys only
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
    check_learner: Callable[[dict, str, dict], None] | None = None
    learners: tuple[str, ...] | None = None
    code: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if (self.simulation is None) != (self.simulate is None):
            raise ValueError(f"scenario {self.name!r}: give both simulation and simulate, or neither")


# ------------------------------------------------------------------------------------------ conversion
def convert_param(kind: str, label: str, value, base_dir: Path | None, choices: tuple[str, ...] = ()):
    """A TOML value of a parameter as its normalised JSON value."""
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{label} must be an integer, got {value!r}")
        return int(value)
    if kind == "float":
        v = number(label, value, finite=False)
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
        lo, hi = (number(label, v, finite=False) for v in value)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"{label} must be [low, high] with finite low <= high, got {value!r}")
        return [lo, hi]
    if kind == "rationality":
        if value is None:
            return None
        v = number(label, value, finite=False)
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
            w = number(f"{label}[{name!r}]", w, finite=False)
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
        out = []  # type: ignore[assignment]
        for i, s in enumerate(value):
            if isinstance(s, str):
                out.append(s)  # type: ignore[attr-defined]
                continue
            if not isinstance(s, Mapping):
                raise ValueError(f"{label}[{i}] must be a preset name or a table {{name, weight, mean, std}}")
            valid = ("name", "weight", "mean", "std")
            unknown = [k for k in s if k not in valid]
            if unknown:
                raise ValueError(f"{label}[{i}]: unknown key(s) {unknown}; valid keys: {', '.join(valid)}")
            if "name" not in s or "mean" not in s:
                raise ValueError(f"{label}[{i}] needs at least a name and a mean")
            entry = {"name": str(s["name"]), "weight": number(f"{label}[{i}].weight", s.get("weight", 1.0), finite=False)}
            for part in ("mean", "std"):
                table = s.get(part, {})
                if not isinstance(table, Mapping):
                    raise ValueError(f"{label}[{i}].{part} must be a table {{feature name = value}}")
                entry[part] = {str(k): number(f"{label}[{i}].{part}[{k!r}]", v, finite=False) for k, v in table.items()}
            out.append(entry)  # type: ignore[attr-defined]
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



def split_indices(n: int, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) indices of n demonstrations: the seed's random order, its first test_fraction test."""
    order = np.random.default_rng(seed).permutation(n)
    n_test = max(1, int(round(test_fraction * n)))
    return order[n_test:], order[:n_test]


def dataclass_params(cls, *, kinds: Mapping[str, str] = MappingProxyType({}),
                     defaults: Mapping[str, Any] = MappingProxyType({}), skip: tuple[str, ...] = ("seed",)
                     ) -> dict[str, Param]:
    """One `Param` per field of the config dataclass ``cls`` (in field order, less ``skip``).

    The kind follows the field's type (``int``, ``float``, a pair of floats: ``range``) unless ``kinds`` names
    it, the default is the field's own (a tuple as a list) unless ``defaults`` gives the sweep's, and the doc
    is the field's ``metadata["doc"]``: a scenario's parameters are declared once, on its config.
    """
    hints = typing.get_type_hints(cls)
    out = {}
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        kind = kinds.get(f.name) or {int: "int", float: "float", tuple[float, float]: "range"}.get(hints[f.name])
        if kind is None:
            raise TypeError(f"{cls.__name__}.{f.name}: no parameter kind for type {hints[f.name]}: name it in kinds")
        if "doc" not in f.metadata:
            raise TypeError(f"{cls.__name__}.{f.name} has no metadata['doc']")
        default = defaults[f.name] if f.name in defaults else f.default
        out[f.name] = Param(kind, list(default) if isinstance(default, tuple) else default, f.metadata["doc"])
    return out
