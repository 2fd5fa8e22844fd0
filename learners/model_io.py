"""Saving and loading fitted learners in a versioned file that needs no pickle to read.

`save_learner` (``learner.save(path)``) and `load_learner` write and read format ``pirl_sim.learner`` version
`FORMAT_VERSION`: one NumPy ``.npz`` archive whose ``header`` entry is UTF-8 JSON (versions, the learner's class,
its constructor parameters, its `pirl_sim.model.DriverModel` and every fitted attribute) and whose other entries
are the numeric arrays the JSON refers to. `LEARNER_PARAMS` and `LEARNER_STATE` list, per format version, the
parameters and fitted attributes a file holds; a learner that does not match them cannot be saved, and a file of
an unknown version is refused with a ValueError naming the versions this code reads. Version 1 files are
converted on reading.

The full specification (JSON encoding, the model, versions) is in the documentation's "File formats" page.
"""

from __future__ import annotations

import dataclasses
import inspect
import io
import json
import math
import platform
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
from pirl_sim.io.atomic import atomic_write_bytes
from pirl_sim.irl import IRLResult, LogNormalPrior
from pirl_sim.model import DriverModel
from pirl_sim.mpc import Bounds
from pirl_sim.paths import ReferencePath
from pirl_sim.receding import RecedingResult

from .base import BaseLearner

__all__ = ["SavableLearner", "FORMAT", "FORMAT_VERSION", "SUPPORTED_VERSIONS", "LEARNER_PARAMS", "LEARNER_STATE", "save_learner",
           "load_learner", "read_header", "model_to_config", "model_from_config"]

FORMAT = "pirl_sim.learner"
FORMAT_VERSION = 2
SUPPORTED_VERSIONS = (1, 2)  #: 1 is converted on reading (module doc)
HEADER_KEY = "header"
HEADER_KEYS = ("learner", "params", "model", "state")  #: what a header must hold besides format and version

_COMMON = ("feature_transform", "horizon", "irl_hessian", "irl_max_iter", "likelihood", "log_bounds", "model",
           "step_stride", "stride", "window", "windows")
_MIXTURE = ("covariance_type", "min_cluster_size", "n_init", "random_state", "refine", "space", "max_components")
#: the constructor parameters of each learner in format version `FORMAT_VERSION`
LEARNER_PARAMS = {
    "TIRL": _COMMON,
    "PIRLGMM": _COMMON + _MIXTURE + ("n_components", "init"),
    "PIRLDPGMM": _COMMON + _MIXTURE + ("max_iter", "weight_concentration_prior", "weight_mixture"),
    "PIRLKNN": _COMMON + ("aggregate", "ahead_weights", "average", "lookup_ahead", "lookup_features", "lookup_history",
                          "n_candidates", "n_neighbors", "prior", "segment_start", "selector", "state_features",
                          "state_lags", "target", "target_steps", "temperature", "weighting"),
}
_FITTED = ("model_", "n_features_in_", "feature_names_in_", "irl_result_")
_MIXTURE_STATE = (("theta_", "labels_", "n_styles_", "components_", "style_weights_", "cluster_sizes_"),
                  ("control_rms_", "episode_steps_", "mixture_", "scaler_", "sample_labels_", "demo_theta_",
                   "demo_log_weights_", "demo_log_covariances_", "n_demos_with_prior_", "style_log_means_",
                   "style_log_covariances_", "xd_log_likelihood_", "n_refined_", "em_collapse_sizes_"))
#: the fitted attributes of each learner in format version `FORMAT_VERSION`: (always there, there for some options)
LEARNER_STATE = {
    "TIRL": (_FITTED + ("theta_", "beta_"), ()),
    "PIRLGMM": (_FITTED + _MIXTURE_STATE[0], _MIXTURE_STATE[1] + ("bic_", "classification_log_likelihood_")),
    "PIRLDPGMM": (_FITTED + _MIXTURE_STATE[0], _MIXTURE_STATE[1]),
    "PIRLKNN": (_FITTED + ("demo_theta_", "sample_theta_", "sample_owner_", "scaler_", "neighbors_", "state_idx_",
                           "n_weights_at_bound_", "n_scale_at_bound_", "lookup_z_", "key_scale_", "ahead_weight_"),
                ("prior_", "ahead_scores_", "ahead_validation_", "bank_", "selector_", "bank_errors_", "control_rms_",
                 "episode_steps_")),
}
#: residual kinds a model file describes
_RESIDUAL_KINDS = ("squared_state", "squared_control", "speed_deviation", "speed_target", "headway")

_DATACLASSES = {c.__name__: c for c in (IRLResult, RecedingResult, LogNormalPrior)}
_ESTIMATORS = {c.__name__: c for c in (StandardScaler, GaussianMixture, BayesianGaussianMixture, NearestNeighbors)}


class SavableLearner(BaseLearner):
    """A learner that writes itself to a model file: the base of every learner class this format holds."""

    def save(self, path) -> Path:
        """Write the fitted learner to a versioned ``.npz`` file that needs no pickle to read (`save_learner`);
        returns the path written."""
        return save_learner(self, path)

    @staticmethod
    def load(path) -> BaseLearner:
        """A learner written by `save` (of any learner class, `load_learner`); ValueError for a file this code
        cannot read."""
        return load_learner(path)


def _learner_classes() -> dict[str, type]:
    """{class name: class} of every learner class (the subclasses of `SavableLearner`, defined when
    `pirl_sim.learners` is imported)."""
    out, todo = {}, [SavableLearner]
    while todo:
        for sub in todo.pop().__subclasses__():
            out[sub.__name__] = sub
            todo.append(sub)
    return out


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
                    "kappa": self.array(path.kappa, f"{key}.kappa")}  # type: ignore[attr-defined]
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
            out["n_iter"] = int(model.n_iter)  # type: ignore[assignment]
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
            return ReferencePath(*(self.array(cfg[n])  # type: ignore[arg-type, misc]
                                   for n in ("s", "x", "y", "heading", "kappa")),
                                 closed=bool(cfg["closed"]))
        if cfg["kind"] == "composite":
            comp = CompositePath(tuple(self.path(p) for p in cfg["segments"]), gap=cfg["gap"], spacing=cfg["spacing"])
            kappa = self.array(cfg["kappa"])
            # a smoothed curvature table (the replay's profile path)
            if not np.array_equal(kappa, comp.kappa):  # type: ignore[attr-defined]
                if kappa.shape != comp.kappa.shape:  # type: ignore[attr-defined]
                    raise ValueError(f"{self.source}: a composite path's curvature table has {kappa.shape[0]} rows, "
                                     f"its segments give {comp.kappa.shape[0]}")  # type: ignore[attr-defined]
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

    if not isinstance(learner, BaseLearner):
        raise TypeError(f"expected a pirl_sim learner, got {type(learner).__name__}")
    name = type(learner).__name__
    if _learner_classes().get(name) is not type(learner):
        raise TypeError(f"cannot save a {name}: a {FORMAT} file holds the learners {sorted(LEARNER_PARAMS)}")
    check_is_fitted(learner)
    enc = _Encoder()
    params = learner.get_params(deep=False)
    state = {k: v for k, v in vars(learner).items() if k.endswith("_") and not k.startswith("_")}
    _check_schema(name, set(params), set(state))
    model = params.pop("model")
    header = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        **_versions(),
        "learner": name,
        "params": enc.value(params, "params"),
        "model": None if model is None else enc.model(model, "params.model"),
        "state": {k: enc.value(v, f"state.{k}") for k, v in state.items()},
    }
    text = json.dumps(header, indent=1, allow_nan=False)
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    buf = io.BytesIO()
    np.savez(buf, **{HEADER_KEY: np.frombuffer(text.encode("utf-8"), dtype=np.uint8)},  # type: ignore[arg-type]
             **enc.arrays)  # type: ignore[arg-type]
    return atomic_write_bytes(path, buf.getvalue())  # nothing but the finished file is ever left at or beside path


def _check_schema(name: str, params: set, state: set) -> None:
    """RuntimeError unless a learner's parameters and fitted attributes are those of `FORMAT_VERSION`: a change of
    them needs a new format version (module doc)."""
    required, optional = LEARNER_STATE[name]
    wrong = []
    if params != set(LEARNER_PARAMS[name]):
        wrong.append(f"parameters {sorted(params ^ set(LEARNER_PARAMS[name]))} differ")
    if not set(required) <= state <= set(required) | set(optional):
        wrong.append(f"fitted attributes {sorted((set(required) - state) | (state - set(required) - set(optional)))} "
                     "differ")
    if wrong:
        raise RuntimeError(f"{name}: {' and '.join(wrong)} from format version {FORMAT_VERSION}'s (LEARNER_PARAMS, "
                           f"LEARNER_STATE in {__name__}): a change of a learner's parameters or fitted state needs a "
                           "new FORMAT_VERSION and a converter from the last one")


def _versions() -> dict[str, str]:
    import sklearn

    return {"pirl_sim_version": _package_version(), "numpy_version": np.__version__,
            "scikit_learn_version": sklearn.__version__, "python_version": platform.python_version()}


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
        try:
            arrays = {k: data[k] for k in data.files if k != HEADER_KEY}
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
            raise ValueError(f"{source}: an array of the file cannot be read ({exc})") from None
    classes = _learner_classes()
    name = header["learner"]
    if name not in classes:
        raise ValueError(f"{source}: unknown learner {name!r}; this pirl_sim reads {sorted(classes)}")
    dec = _Decoder(arrays, source)
    try:
        params = dec.value(header["params"])
        model = None if header["model"] is None else dec.model(header["model"])
        state = {k: dec.value(v) for k, v in header["state"].items()}
    except Exception as exc:  # a damaged header: say which file, and which packages wrote it
        raise ValueError(f"{source}: the header cannot be decoded ({_explain(exc, source)}){_written_with(header)}"
                         ) from None
    if not isinstance(params, dict) or not all(isinstance(k, str) for k in params):
        raise ValueError(f"{source}: 'params' is not a mapping of parameter names to values")
    version = header["format_version"]
    if version == 1:
        params, state = _convert_v1(name, params, state, source)
    known = set(LEARNER_PARAMS[name]) - {"model"}
    if set(params) != known:
        raise ValueError(f"{source}: the {name}'s parameters {sorted(set(params) ^ known)} are not those of format "
                         f"version {version} (missing or unknown); the file is damaged or was edited")
    required, optional = LEARNER_STATE[name]
    missing = [k for k in required if k not in state]
    unknown = [k for k in state if k not in required and k not in optional]
    if missing or unknown:
        raise ValueError(f"{source}: the fitted state of the {name} " + " and ".join(
            ([f"lacks {missing}"] if missing else []) + ([f"has unknown attributes {unknown}"] if unknown else []))
            + f" (format version {version}); the file is damaged or was edited")
    learner = classes[name](model=model, **params)
    try:
        learner._check_params(state["model_"])
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{source}: invalid parameters of the {name}: {exc}") from None
    for k, v in state.items():
        setattr(learner, k, v)
    _check_fitted(learner, source)
    return learner


def _explain(exc: Exception, source: str) -> str:
    text = str(exc)
    if text.startswith(f"{source}: "):
        text = text[len(source) + 2:]
    return f"{type(exc).__name__}: {text}"


def _written_with(header: dict) -> str:
    """'; written with ...' when the file's numpy or scikit-learn differs from this one's."""
    import sklearn

    theirs = {"numpy": header.get("numpy_version"), "scikit-learn": header.get("scikit_learn_version")}
    ours = {"numpy": np.__version__, "scikit-learn": sklearn.__version__}
    diff = [f"{k} {theirs[k]} (here {ours[k]})" for k in theirs if theirs[k] is not None and theirs[k] != ours[k]]
    return f"; written with {', '.join(diff)}" if diff else ""


def _convert_v1(name: str, params: dict, state: dict, source: str) -> tuple[dict, dict]:
    """A version-1 learner's parameters and fitted state as version 2 has them (module doc)."""
    cls = _learner_classes()[name]
    defaults = {k: p.default for k, p in inspect.signature(cls.__init__).parameters.items()  # type: ignore[misc]
                if k not in ("self", "model") and p.default is not inspect.Parameter.empty}
    unknown = sorted(set(params) - set(defaults))
    if unknown:
        raise ValueError(f"{source}: this format version 1 file holds a {name} with parameter(s) {unknown}, which "
                         f"the {name} of pirl_sim {_package_version()} (format version {FORMAT_VERSION}) does not "
                         "have; read it with the pirl_sim that wrote it, or refit the learner with this one")
    if name == "PIRLDPGMM" and params.get("space") == "weights" and "weight_mixture" not in params:
        params = {**params, "weight_mixture": "mml"}  # the only weight-space mixture before the choice existed
    params = {**defaults, **params}
    state = dict(state)
    try:
        if name == "PIRLKNN":
            state.setdefault("state_idx_", tuple(int(i) for i in params["state_features"]))
            if "lookup_z_" not in state:  # fitted before the road's weight: the index's points are the look-up's
                Z = np.array(state["neighbors_"]._fit_X)
                state["lookup_z_"] = Z
                state.setdefault("key_scale_", np.ones(Z.shape[1]))
                state.setdefault("ahead_weight_", 1.0)
        if name in ("PIRLGMM", "PIRLDPGMM"):
            if "style_weights_" not in state and "mixture_" in state:
                w = state["mixture_"].weights_[state["components_"]]
                state["style_weights_"] = w / w.sum()
            if "episode_steps_" not in state and not (params["window"] is not None and params["windows"] == "first"):
                state["episode_steps_"] = None  # histories are not the first steps of episodes
            if "control_rms_" not in state and params["likelihood"] == "trajectory":
                state["control_rms_"] = math.nan  # floors the receding likelihood's noise only: unused
    except (KeyError, AttributeError, IndexError, TypeError, ValueError) as exc:
        raise ValueError(f"{source}: this format version 1 file's {name} cannot be converted to version "
                         f"{FORMAT_VERSION} ({type(exc).__name__}: {exc}); refit the learner") from None
    return params, state


def _open(path):
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no learner file {path}")
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: not a {FORMAT} file (the file is empty)")
    try:
        data = np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise ValueError(f"{path}: not a {FORMAT} file (not a NumPy .npz archive: {exc})") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise ValueError(f"{path}: not a {FORMAT} file (a single NumPy array, not an .npz archive)")
    return data


def _header(data, source: str) -> dict:
    if HEADER_KEY not in data.files:
        raise ValueError(f"{source}: not a {FORMAT} file (no {HEADER_KEY!r} entry)")
    try:
        header = json.loads(bytes(data[HEADER_KEY]).decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{source}: the {HEADER_KEY!r} entry is not UTF-8 JSON ({exc})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        found = header.get("format") if isinstance(header, dict) else type(header).__name__
        raise ValueError(f"{source}: not a {FORMAT} file (format {found!r})")
    version = header.get("format_version")
    if version not in SUPPORTED_VERSIONS:
        newer = isinstance(version, int) and not isinstance(version, bool) and version > FORMAT_VERSION
        raise ValueError(
            f"{source}: {FORMAT} format version {version!r} is not supported"
            + (f" (written by pirl_sim {header.get('pirl_sim_version', 'unknown')})" if newer else "")
            + f"; this pirl_sim ({_package_version()}) writes version {FORMAT_VERSION} and reads version(s) "
            + ", ".join(map(str, SUPPORTED_VERSIONS))
            + (": upgrade pirl_sim to the version that wrote the file, or refit the learner with this one" if newer
               else ": refit the learner with this pirl_sim"))
    missing = [k for k in HEADER_KEYS if k not in header]
    if missing:
        raise ValueError(f"{source}: the header of this {FORMAT} file lacks {', '.join(map(repr, missing))} "
                         f"(it needs {', '.join(HEADER_KEYS)}); the file is damaged or was edited")
    kinds = {"learner": (str,), "params": (dict,), "model": (dict, type(None)), "state": (dict,)}
    wrong = [k for k, types in kinds.items() if not isinstance(header[k], types)]
    if wrong:
        raise ValueError(f"{source}: the header's {', '.join(map(repr, wrong))} "
                         f"{'is' if len(wrong) == 1 else 'are'} not of the right kind (learner: a name, params and "
                         "state: mappings, model: a mapping or null); the file is damaged or was edited")
    return header


def _check_fitted(learner, source: str) -> None:
    """ValueError naming ``source`` unless the fitted arrays of a learner read from it fit together: shapes, finite
    and positive weights, indices in range (what a damaged or edited file breaks, later, as an IndexError or a
    LinAlgError deep inside a prediction)."""

    def fail(what: str):
        raise ValueError(f"{source}: {what}; the file is damaged or was edited")

    def array(name, value, shape, *, integer=False, positive=False, nonnegative=False, finite=True, high=None):
        a = np.asarray(value)
        if a.dtype.kind not in ("iu" if integer else "biuf"):
            fail(f"{name} holds {a.dtype} values, expected {'integers' if integer else 'numbers'}")
        if a.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, a.shape)):
            dims = ["any" if n is None else str(n) for n in shape]
            want = "(" + ", ".join(dims) + ("," if len(shape) == 1 else "") + ")"
            fail(f"{name} has shape {a.shape}, expected {want}")
        if finite and a.size and not np.all(np.isfinite(a)):
            fail(f"{name} holds values that are not finite")
        if positive and a.size and not np.all(a > 0):
            fail(f"{name} holds values <= 0 (weights are positive)")
        if (nonnegative or integer) and a.size and not np.all(a >= 0):
            fail(f"{name} holds negative values")
        if high is not None and a.size and not np.all(a < high):
            fail(f"{name} holds values >= {high} (indices into {high} entries)")
        return a

    def count(name, value, low=0):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            fail(f"{name} is {value!r}, expected an integer >= {low}")
        return int(value)

    model = learner.model_
    if not isinstance(model, DriverModel):
        fail(f"model_ is a {type(model).__name__}, not a DriverModel")
    K, n_x = model.features.n_features, model.dynamics.n_x
    names = [str(n) for n in np.ravel(learner.feature_names_in_)]
    if learner.n_features_in_ != K or names != list(model.features.names):
        fail(f"n_features_in_ / feature_names_in_ ({learner.n_features_in_}, {names}) "
             f"differ from the model's {K} features {list(model.features.names)}")
    res = learner.irl_result_
    if not isinstance(res, (IRLResult, RecedingResult)):
        fail(f"irl_result_ is a {type(res).__name__}, not an IRLResult or RecedingResult")
    G = array("irl_result_.theta", res.theta, (None, K), positive=True).shape[0]
    array("irl_result_.normalized", res.normalized, (G, K), positive=True)
    name = type(learner).__name__
    if name == "TIRL":
        array("theta_", learner.theta_, (K,), positive=True)
        array("beta_", learner.beta_, ())
    elif name in ("PIRLGMM", "PIRLDPGMM"):
        J = count("n_styles_", learner.n_styles_, 1)
        array("theta_", learner.theta_, (J, K), positive=True)
        array("style_weights_", learner.style_weights_, (J,), nonnegative=True)
        array("labels_", learner.labels_, (None,), integer=True, high=J)
        array("cluster_sizes_", learner.cluster_sizes_, (J,), integer=True)
        comps = array("components_", learner.components_, (J,), integer=True)
        if learner.space == "features":
            mix, scaler = getattr(learner, "mixture_", None), getattr(learner, "scaler_", None)
            if mix is None or scaler is None:
                fail("a feature-space mixture without its mixture_ or scaler_")
            C = count("mixture_.n_components", getattr(mix, "n_components", None), 1)
            array("components_", comps, (J,), integer=True, high=C)
            w = array("mixture_.weights_", mix.weights_, (C,), nonnegative=True)  # type: ignore[union-attr]
            if not w.sum() > 0:
                fail("mixture_.weights_ are all zero; a mixture's weights sum to 1")
            array("mixture_.means_", mix.means_, (C, K))  # type: ignore[union-attr]
            shapes = {"full": (C, K, K), "tied": (K, K), "diag": (C, K), "spherical": (C,)}
            if mix.covariance_type not in shapes:  # type: ignore[union-attr]
                fail(f"mixture_.covariance_type is {mix.covariance_type!r}")  # type: ignore[union-attr]
            chol = array("mixture_.precisions_cholesky_", mix.precisions_cholesky_,  # type: ignore[union-attr]
                         shapes[mix.covariance_type])  # type: ignore[union-attr]
            kind = mix.covariance_type  # type: ignore[union-attr]
            diag = np.diagonal(chol, axis1=-2, axis2=-1) if kind in ("full", "tied") else chol  # diag, spherical
            if not (np.asarray(diag) > 0).all():
                fail("mixture_.precisions_cholesky_ has a diagonal entry <= 0; a Cholesky factor of a precision "
                     "matrix has a positive diagonal")
            array("scaler_.mean_", scaler.mean_, (K,))  # type: ignore[union-attr]
            array("scaler_.scale_", scaler.scale_, (K,), positive=True)  # type: ignore[union-attr]
        else:
            array("style_log_means_", learner.style_log_means_, (J, K - 1))
            array("style_log_covariances_", learner.style_log_covariances_, (J, K - 1, K - 1))
    elif name == "PIRLKNN":
        D = array("demo_theta_", learner.demo_theta_, (None, K), positive=True).shape[0]
        S = array("sample_theta_", learner.sample_theta_, (None, K), positive=True).shape[0]
        array("sample_owner_", learner.sample_owner_, (S,), integer=True, high=D)
        Z = learner.neighbors_._fit_X
        d = array("neighbors_ (its look-up points)", Z, (S, None)).shape[1]
        array("lookup_z_", learner.lookup_z_, (S, d))
        array("key_scale_", learner.key_scale_, (d,), nonnegative=True)
        array("scaler_.mean_", learner.scaler_.mean_, (d,))
        array("scaler_.scale_", learner.scaler_.scale_, (d,), positive=True)
        array("state_idx_", np.asarray(learner.state_idx_, dtype=int), (None,), integer=True, high=n_x)
        if learner.n_neighbors > S:
            fail(f"n_neighbors={learner.n_neighbors} exceeds the {S} look-up samples")
        if hasattr(learner, "bank_"):
            array("bank_", learner.bank_, (None,), integer=True, high=D)


def _package_version() -> str:
    try:
        from importlib.metadata import version

        return version("pirl_sim")
    except Exception:  # pragma: no cover - not installed
        return "unknown"
