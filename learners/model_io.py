"""Saving and loading fitted learners in a versioned file that needs no pickle to read.

File format ``pirl_sim.learner``, version 1
-------------------------------------------
One NumPy ``.npz`` archive (a zip of ``.npy`` arrays; read it with ``numpy.load(path, allow_pickle=False)``):

- ``header``: a uint8 array holding UTF-8 JSON, the whole description of the learner::

      {"format": "pirl_sim.learner", "format_version": 1, "pirl_sim_version": "...",
       "learner": "PIRLGMM",                      # class name, one of pirl_sim.learners.LEARNERS
       "params": {...},                           # the constructor's arguments (get_params), model excluded
       "model": {...},                            # the DriverModel: dynamics, features, bounds, path
       "state": {...}}                            # every fitted attribute (name ends in "_")

- every other entry is a numeric array that the JSON refers to by its entry name, ``{"__array__": "<name>"}``
  (names are the attribute paths, e.g. ``state.theta_``, ``state.mixture_.means_``).

JSON values carry their type where JSON alone would lose it: ``{"__tuple__": [...]}``,
``{"__dict__": [[key, value], ...]}``, ``{"__float__": "nan" | "inf" | "-inf"}``,
``{"__str_array__": [...]}`` (arrays of strings), ``{"__dataclass__": "IRLResult", "fields": {...}}``
(results and priors of `pirl_sim.irl` and `pirl_sim.receding`), ``{"__estimator__": "GaussianMixture",
"params": {...}, "state": {...}}`` (scikit-learn's StandardScaler, GaussianMixture, BayesianGaussianMixture,
NearestNeighbors; a NearestNeighbors index is rebuilt from its training points, ``_fit_X``) and
``{"__model__": {...}}``. Only the classes named here are ever built when a file is read.

The model: ``dynamics`` (``A`` (n_x, n_x), ``B`` (n_x, n_u), ``dt`` [s], state and control names,
``position_index``), ``features`` (``reference`` and, per feature, ``name``, ``reduction``, ``quadratic`` and
its ``residual``: ``squared_state`` with ``index``, ``squared_control``, ``speed_deviation`` with its speed
profile: ``path``, ``a_lat`` [m/s^2], ``v_max`` [m/s], ``speed_target`` with ``v_target`` [m/s], or ``headway``
with ``standstill`` [m], ``time_gap`` [s], ``softness`` [m]), ``bounds`` (``state``/``control``: name -> [low,
high]) and, for a `pirl_sim.driving.PathDriverModel`, ``path`` and ``n_iter``. A path is a ``reference`` table
(``s``, ``x``, ``y``, ``heading`` [rad], ``kappa`` [1/m], ``closed``) or a ``composite`` of reference paths
(``segments``, ``gap`` [m], ``spacing`` [m], and its curvature table ``kappa``, which a replay may have
smoothed). Features defined elsewhere (other residual callables) pickle but cannot be written here: saving
such a learner is a TypeError naming the feature.

A file whose ``format_version`` is not in `SUPPORTED_VERSIONS` is refused with a ValueError naming both.
Loaded learners predict exactly what the saved ones did (tested).
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.mixture import BayesianGaussianMixture, GaussianMixture
from sklearn.neighbors import NearestNeighbors
from sklearn.preprocessing import StandardScaler

from pirl_sim.driving import (
    CompositePath,
    HeadwayResidual,
    PathDriverModel,
    SpeedDeviationResidual,
    SpeedProfile,
    SpeedTargetResidual,
)
from pirl_sim.dynamics import LinearDynamics
from pirl_sim.features import Feature, FeatureSet, SquaredControlResidual, SquaredStateResidual
from pirl_sim.irl import IRLResult, LogNormalPrior
from pirl_sim.model import DriverModel
from pirl_sim.mpc import Bounds
from pirl_sim.paths import ReferencePath
from pirl_sim.receding import RecedingResult

__all__ = ["FORMAT", "FORMAT_VERSION", "SUPPORTED_VERSIONS", "save_learner", "load_learner", "read_header",
           "model_to_config", "model_from_config"]

FORMAT = "pirl_sim.learner"
FORMAT_VERSION = 1
SUPPORTED_VERSIONS = (1,)
HEADER_KEY = "header"
#: residual kinds a model file describes
_RESIDUAL_KINDS = ("squared_state", "squared_control", "speed_deviation", "speed_target", "headway")

_DATACLASSES = {c.__name__: c for c in (IRLResult, RecedingResult, LogNormalPrior)}
_ESTIMATORS = {c.__name__: c for c in (StandardScaler, GaussianMixture, BayesianGaussianMixture, NearestNeighbors)}


def _learner_classes() -> dict[str, type]:
    from . import LEARNERS

    return {cls.__name__: cls for cls in LEARNERS.values()}


# ---------------------------------------------------------------------------------------------- encoding
class _Encoder:
    """Turns a value into JSON, moving numeric arrays into ``arrays`` under their attribute path."""

    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}

    def array(self, arr: np.ndarray, key: str) -> dict:
        arr = np.asarray(arr)
        if arr.dtype.kind in "biuf":
            if key in self.arrays:
                raise ValueError(f"two arrays would be stored as {key!r}")  # pragma: no cover - paths are unique
            self.arrays[key] = arr
            return {"__array__": key}
        if arr.dtype.kind in "OU" and all(isinstance(x, str) for x in arr.ravel()):
            return {"__str_array__": arr.tolist(), "shape": list(arr.shape)}
        raise TypeError(f"{key}: cannot store an array of dtype {arr.dtype} (numbers and strings only)")

    def value(self, v: Any, key: str) -> Any:
        if v is None or isinstance(v, (bool, str)):
            return v
        if isinstance(v, np.bool_):
            return bool(v)
        if isinstance(v, (int, np.integer)):
            return int(v)
        if isinstance(v, (float, np.floating)):
            v = float(v)
            return v if math.isfinite(v) else {"__float__": repr(v)}
        if isinstance(v, np.ndarray):
            return self.array(v, key)
        if isinstance(v, tuple):
            return {"__tuple__": [self.value(x, f"{key}.{i}") for i, x in enumerate(v)]}
        if isinstance(v, list):
            return [self.value(x, f"{key}.{i}") for i, x in enumerate(v)]
        if isinstance(v, dict):
            return {"__dict__": [[self.value(k, f"{key}.key{i}"), self.value(x, f"{key}.{k}")]
                                 for i, (k, x) in enumerate(v.items())]}
        if isinstance(v, DriverModel):
            return {"__model__": self.model(v, key)}
        name = type(v).__name__
        if dataclasses.is_dataclass(v) and _DATACLASSES.get(name) is type(v):
            return {"__dataclass__": name, "fields": {f.name: self.value(getattr(v, f.name), f"{key}.{f.name}")
                                                      for f in dataclasses.fields(v) if f.init}}
        if _ESTIMATORS.get(name) is type(v):
            params = self.value(v.get_params(deep=False), f"{key}.params")
            if isinstance(v, NearestNeighbors):
                state = {"_fit_X": self.array(v._fit_X, f"{key}._fit_X")}
            else:
                state = {a: self.value(x, f"{key}.{a}") for a, x in vars(v).items()
                         if a.endswith("_") and not a.startswith("_")}
            return {"__estimator__": name, "params": params, "state": state}
        raise TypeError(f"{key}: cannot store a {name} in a {FORMAT} file "
                        f"(numbers, strings, arrays, tuples, lists, dicts, {sorted(_DATACLASSES)}, "
                        f"{sorted(_ESTIMATORS)} and DriverModel only)")

    # ------------------------------------------------------------------ models
    def path(self, path, key: str) -> dict:
        if type(path) is ReferencePath:
            return {"kind": "reference", "closed": bool(path.closed),
                    **{n: self.array(getattr(path, n), f"{key}.{n}") for n in ("s", "x", "y", "heading", "kappa")}}
        if type(path) is CompositePath:
            return {"kind": "composite", "gap": float(path.gap), "spacing": float(path.spacing),
                    "segments": [self.path(p, f"{key}.segments.{i}") for i, p in enumerate(path.segments)],
                    "kappa": self.array(path.kappa, f"{key}.kappa")}
        raise TypeError(f"{key}: cannot store a path of type {type(path).__name__} (ReferencePath or CompositePath)")

    def residual(self, feature: Feature, key: str) -> dict:
        r = feature.residual
        if type(r) is SquaredStateResidual:
            return {"kind": "squared_state", "index": None if r.index is None else list(r.index)}
        if type(r) is SquaredControlResidual:
            return {"kind": "squared_control"}
        if type(r) is SpeedDeviationResidual:
            p = r.profile
            return {"kind": "speed_deviation", "a_lat": float(p.a_lat), "v_max": float(p.v_max),
                    "path": self.path(p.path, f"{key}.profile.path")}
        if type(r) is SpeedTargetResidual:
            return {"kind": "speed_target", "v_target": float(r.v_target)}
        if type(r) is HeadwayResidual:
            return {"kind": "headway", "standstill": float(r.standstill), "time_gap": float(r.time_gap),
                    "softness": float(r.softness)}
        raise TypeError(f"feature {feature.name!r} has a residual of type {type(r).__name__}, which a {FORMAT} file "
                        f"cannot describe ({', '.join(_RESIDUAL_KINDS)} only); pickle the learner instead")

    def model(self, model: DriverModel, key: str) -> dict:
        if type(model) not in (DriverModel, PathDriverModel):
            raise TypeError(f"{key}: cannot store a model of type {type(model).__name__} "
                            "(DriverModel or PathDriverModel)")
        dyn = model.dynamics
        out = {
            "class": type(model).__name__,
            "dynamics": {"A": self.array(dyn.A, f"{key}.A"), "B": self.array(dyn.B, f"{key}.B"), "dt": dyn.dt,
                         "state_names": list(dyn.state_names), "control_names": list(dyn.control_names),
                         "position_index": [int(i) for i in dyn.position_index]},
            "features": {"reference": model.features.reference,
                         "features": [{"name": f.name, "reduction": f.reduction, "quadratic": bool(f.quadratic),
                                       "residual": self.residual(f, f"{key}.features.{f.name}")}
                                      for f in model.features.features]},
            "bounds": None if model.bounds is None else {
                kind: {n: [float(lo), float(hi)] for n, (lo, hi) in getattr(model.bounds, kind).items()}
                for kind in ("state", "control")},
        }
        if isinstance(model, PathDriverModel):
            out["path"] = self.path(model.path, f"{key}.path")
            out["n_iter"] = int(model.n_iter)
        return out


# ---------------------------------------------------------------------------------------------- decoding
class _Decoder:
    def __init__(self, arrays, source: str) -> None:
        self.arrays = arrays
        self.source = source

    def array(self, ref: dict) -> np.ndarray:
        key = ref["__array__"]
        if key not in self.arrays:
            raise ValueError(f"{self.source}: the header refers to array {key!r}, which the file does not hold")
        return np.array(self.arrays[key])

    def value(self, v: Any) -> Any:
        if isinstance(v, list):
            return [self.value(x) for x in v]
        if not isinstance(v, dict):
            return v
        if "__array__" in v:
            return self.array(v)
        if "__str_array__" in v:
            return np.array(v["__str_array__"], dtype=object).reshape(v["shape"])
        if "__float__" in v:
            return float(v["__float__"])
        if "__tuple__" in v:
            return tuple(self.value(x) for x in v["__tuple__"])
        if "__dict__" in v:
            return {self.value(k): self.value(x) for k, x in v["__dict__"]}
        if "__model__" in v:
            return self.model(v["__model__"])
        if "__dataclass__" in v:
            cls = self._known(_DATACLASSES, v["__dataclass__"], "result type")
            return cls(**{k: self.value(x) for k, x in v["fields"].items()})
        if "__estimator__" in v:
            cls = self._known(_ESTIMATORS, v["__estimator__"], "estimator")
            est = cls(**self.value(v["params"]))
            state = {k: self.value(x) for k, x in v["state"].items()}
            if cls is NearestNeighbors:
                return est.fit(state["_fit_X"])
            for k, x in state.items():
                setattr(est, k, x)
            return est
        raise ValueError(f"{self.source}: unknown tagged value with keys {sorted(v)}")

    def _known(self, table: dict, name: str, what: str):
        if name not in table:
            raise ValueError(f"{self.source}: unknown {what} {name!r}; this pirl_sim reads {sorted(table)}")
        return table[name]

    def path(self, cfg: dict):
        if cfg["kind"] == "reference":
            return ReferencePath(*(self.array(cfg[n]) for n in ("s", "x", "y", "heading", "kappa")),
                                 closed=bool(cfg["closed"]))
        if cfg["kind"] == "composite":
            comp = CompositePath(tuple(self.path(p) for p in cfg["segments"]), gap=cfg["gap"], spacing=cfg["spacing"])
            kappa = self.array(cfg["kappa"])
            if not np.array_equal(kappa, comp.kappa):  # a smoothed curvature table (the replay's profile path)
                if kappa.shape != comp.kappa.shape:
                    raise ValueError(f"{self.source}: a composite path's curvature table has {kappa.shape[0]} rows, "
                                     f"its segments give {comp.kappa.shape[0]}")
                object.__setattr__(comp, "kappa", kappa)
            return comp
        raise ValueError(f"{self.source}: unknown path kind {cfg['kind']!r} (reference, composite)")

    def residual(self, name: str, cfg: dict):
        kind = cfg["kind"]
        if kind == "squared_state":
            return SquaredStateResidual(name, None if cfg["index"] is None else tuple(cfg["index"]))
        if kind == "squared_control":
            return SquaredControlResidual()
        if kind == "speed_deviation":
            return SpeedDeviationResidual(SpeedProfile(self.path(cfg["path"]), cfg["a_lat"], cfg["v_max"]))
        if kind == "speed_target":
            return SpeedTargetResidual(cfg["v_target"])
        if kind == "headway":
            return HeadwayResidual(cfg["standstill"], cfg["time_gap"], cfg["softness"])
        raise ValueError(f"{self.source}: feature {name!r} has unknown residual kind {kind!r} "
                         f"({', '.join(_RESIDUAL_KINDS)})")

    def model(self, cfg: dict) -> DriverModel:
        d = cfg["dynamics"]
        dyn = LinearDynamics(self.array(d["A"]), self.array(d["B"]), d["dt"], tuple(d["state_names"]),
                             tuple(d["control_names"]), tuple(d["position_index"]))
        fs = cfg["features"]
        features = FeatureSet(tuple(Feature(f["name"], self.residual(f["name"], f["residual"]),
                                            reduction=f["reduction"], quadratic=f["quadratic"])
                                    for f in fs["features"]), reference=fs["reference"])
        b = cfg["bounds"]
        bounds = None if b is None else Bounds(state={n: tuple(v) for n, v in b["state"].items()},
                                               control={n: tuple(v) for n, v in b["control"].items()})
        if cfg["class"] == "PathDriverModel":
            return PathDriverModel(dyn, features, bounds, path=self.path(cfg["path"]), n_iter=cfg["n_iter"])
        if cfg["class"] == "DriverModel":
            return DriverModel(dyn, features, bounds)
        raise ValueError(f"{self.source}: unknown model class {cfg['class']!r} (DriverModel, PathDriverModel)")


# ---------------------------------------------------------------------------------------------- public
def model_to_config(model: DriverModel) -> tuple[dict, dict[str, np.ndarray]]:
    """A model as (JSON-ready description, its arrays by name): the ``model`` part of the file format."""
    enc = _Encoder()
    return enc.model(model, "model"), enc.arrays


def model_from_config(config: dict, arrays: dict[str, np.ndarray], source: str = "model") -> DriverModel:
    """The inverse of `model_to_config`."""
    return _Decoder(arrays, source).model(config)


def save_learner(learner, path: str | Path) -> Path:
    """Write a fitted learner to ``path`` (format in the module doc; ``.npz`` is appended if missing).

    Raises
    ------
    sklearn.exceptions.NotFittedError
        The learner was not fitted.
    TypeError
        A parameter or a feature the format cannot describe (e.g. a ``random_state`` Generator, a custom
        feature residual); the message names it.
    """
    from sklearn.utils.validation import check_is_fitted

    from .base import BaseLearner

    if not isinstance(learner, BaseLearner):
        raise TypeError(f"expected a pirl_sim learner, got {type(learner).__name__}")
    check_is_fitted(learner)
    enc = _Encoder()
    params = learner.get_params(deep=False)
    model = params.pop("model")
    header = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "pirl_sim_version": _package_version(),
        "learner": type(learner).__name__,
        "params": enc.value(params, "params"),
        "model": None if model is None else enc.model(model, "params.model"),
        "state": {k: enc.value(v, f"state.{k}") for k, v in vars(learner).items()
                  if k.endswith("_") and not k.startswith("_")},
    }
    text = json.dumps(header, indent=1, allow_nan=False)
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez(buf, **{HEADER_KEY: np.frombuffer(text.encode("utf-8"), dtype=np.uint8)}, **enc.arrays)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(buf.getvalue())
    tmp.replace(path)
    return path


def read_header(path: str | Path) -> dict:
    """The JSON header of a learner file, after checking its format and version (see `load_learner`)."""
    with _open(path) as data:
        return _header(data, str(path))


def load_learner(path: str | Path):
    """Read a learner written by `save_learner`; it predicts exactly what the saved one did.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not a pirl_sim learner file, or one of a format version this code does not read (the message names the
        file's version and `SUPPORTED_VERSIONS`).
    """
    source = str(path)
    with _open(path) as data:
        header = _header(data, source)
        arrays = {k: data[k] for k in data.files if k != HEADER_KEY}
    classes = _learner_classes()
    name = header.get("learner")
    if name not in classes:
        raise ValueError(f"{source}: unknown learner {name!r}; this pirl_sim reads {sorted(classes)}")
    dec = _Decoder(arrays, source)
    params = dec.value(header["params"])
    params["model"] = None if header["model"] is None else dec.model(header["model"])
    learner = classes[name](**params)
    for k, v in header["state"].items():
        setattr(learner, k, dec.value(v))
    return learner


def _open(path):
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no learner file {path}")
    try:
        return np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, ValueError, OSError) as exc:
        raise ValueError(f"{path}: not a {FORMAT} file (not a NumPy .npz archive: {exc})") from None


def _header(data, source: str) -> dict:
    if HEADER_KEY not in data.files:
        raise ValueError(f"{source}: not a {FORMAT} file (no {HEADER_KEY!r} entry)")
    try:
        header = json.loads(bytes(data[HEADER_KEY]).decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{source}: the {HEADER_KEY!r} entry is not UTF-8 JSON ({exc})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        found = header.get("format") if isinstance(header, dict) else type(header).__name__
        raise ValueError(f"{source}: not a {FORMAT} file (format {found!r})")
    version = header.get("format_version")
    if version not in SUPPORTED_VERSIONS:
        raise ValueError(f"{source}: {FORMAT} format version {version!r} is not supported; this pirl_sim "
                         f"({_package_version()}) reads version(s) {', '.join(map(str, SUPPORTED_VERSIONS))}")
    return header


def _package_version() -> str:
    try:
        from importlib.metadata import version

        return version("pirl_sim")
    except Exception:  # pragma: no cover - not installed
        return "unknown"
