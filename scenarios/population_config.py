"""Driver populations for simulated scenarios: who drives, with which cost weights, and how many.

A :class:`PopulationConfig` says what a scenario's traffic is made of, independently of the simulator: named
``styles`` (Gaussians over the normalised weights of ``speed_dev`` and ``acc_sq``, ``jerk_sq`` = 1, with mixture
weights; and of ``headway`` and ``yielding`` for drivers who interact, :data:`INTERACTION_FEATURES`), ``background_share`` (vehicles driven by the simulator's own model), ``n_vehicles`` and their
departures (``depart_interval`` [s] or ``depart_rate`` [veh/h], ``arrivals``) and ``control_noise`` [m/s^3].
Everything is validated when the config is built (``ValueError`` naming the entry); :func:`load_population`
reads a TOML file and rejects unknown keys. :data:`DEFAULT_POPULATION` (:data:`DEFAULT_POPULATION_TOML`) is the
paper's three user-study styles in equal shares plus 20 % background traffic.

The TOML format, with an example, is in the documentation's "SUMO roundabouts" page (populations).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pirl_sim.features import Feature, FeatureSet, squared_control, squared_state
from pirl_sim.population import STYLE_VALUE_MAX, Population, Style
from pirl_sim.io import toml_text
from pirl_sim.validation import check_keys, number

from .passage import THREE_STYLES

__all__ = [
    "FEATURE_NAMES",
    "FREE_FEATURES",
    "INTERACTION_FEATURES",
    "REFERENCE_FEATURE",
    "PRESET_STYLES",
    "FrozenMapping",
    "Arrivals",
    "StyleConfig",
    "PopulationConfig",
    "DEFAULT_POPULATION",
    "DEFAULT_POPULATION_TOML",
    "INTERACTING_POPULATION",
    "INTERACTING_POPULATION_TOML",
    "load_population",
    "population_from_dict",
    "population_from_toml",
    "MAX_VEHICLES",
    "MAX_CONTROL_NOISE",
]

MAX_VEHICLES = 100_000  #: largest n_vehicles (~4.6 simulated days at the default 4 s between departures)
#: [m/s^3] largest control_noise: the driver model's jerk bound; noisier jerks throw vehicles off their paths
MAX_CONTROL_NOISE = 8.0

#: the roundabout driver model's features, in its order (:func:`pirl_sim.driving.roundabout_features`)
FEATURE_NAMES: tuple[str, ...] = ("speed_dev", "acc_sq", "jerk_sq")
#: the reference feature: its normalised weight is 1 for every driver
REFERENCE_FEATURE = "jerk_sq"
#: the features whose weights a style chooses
FREE_FEATURES: tuple[str, ...] = ("speed_dev", "acc_sq")
#: the features of drivers who interact (``kind="interacting"`` of `pirl_sim.driving.roundabout_features`): a style
#: that weighs them also chooses their weights; every style of a population weighs them, or none does
INTERACTION_FEATURES: tuple[str, ...] = ("headway", "yielding")


class FrozenMapping(Mapping):
    """A read-only, picklable mapping (configs travel to worker processes; ``MappingProxyType`` does not
    pickle)."""

    __slots__ = ("_data",)

    def __init__(self, data=()):
        object.__setattr__(self, "_data", dict(data))

    def __getitem__(self, key):
        return self._data[key]

    def __iter__(self):
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)  # type: ignore[attr-defined]

    def __setattr__(self, name, value):
        raise AttributeError("FrozenMapping is read-only")

    def __reduce__(self):
        return (FrozenMapping, (self._data,))

    def __hash__(self) -> int:
        return hash(tuple(self._data.items()))  # type: ignore[attr-defined]

    def __repr__(self) -> str:
        return repr(self._data)  # type: ignore[attr-defined]


class Arrivals(str, enum.Enum):
    """How departure times are spaced."""

    REGULAR = "regular"  #: exactly ``depart_interval`` apart
    POISSON = "poisson"  #: exponential gaps with mean ``depart_interval``


# ----------------------------------------------------------------------------------------------
# validation helpers
# ----------------------------------------------------------------------------------------------

def _feature_mapping(label: str, mapping: Any, *, allow_reference: bool) -> dict[str, float]:
    """A {free feature name: number} dict, with unknown names rejected."""
    if not isinstance(mapping, Mapping):
        raise ValueError(f"{label} must be a mapping of feature name -> number, got {mapping!r}")
    allowed = FREE_FEATURES + INTERACTION_FEATURES + ((REFERENCE_FEATURE,) if allow_reference else ())
    unknown = [k for k in mapping if k not in allowed]
    if unknown:
        raise ValueError(f"{label}: unknown feature name(s) {', '.join(map(repr, unknown))}; allowed: "
                         f"{', '.join(allowed)}")
    return {str(k): number(f"{label}[{k!r}]", v) for k, v in mapping.items()}


# ----------------------------------------------------------------------------------------------
# styles
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class StyleConfig:
    """One driving style: a Gaussian over the normalised weights of ``speed_dev`` and ``acc_sq``, and of ``headway``
    and ``yielding`` for drivers who interact (draws kept positive by redrawing,
    `pirl_sim.population.Population.sample_weights`).

    Attributes
    ----------
    name : str                    unique within a population, non-empty
    weight : float                mixture weight, > 0 (normalised over the styles)
    mean : mapping {feature name: float}   mean normalised weights of both free features and, for a driver who
        interacts, of ``headway`` and ``yielding``, > 0 (``jerk_sq``: 1)
    std : mapping {feature name: float}    independent standard deviations, >= 0 (0 where omitted); not with ``cov``
    cov : mapping {feature name: {feature name: float}} or None   full covariance over the free features,
        symmetric positive definite (a degenerate spread goes through ``std``); not with ``std``
    """

    name: str
    weight: float = 1.0
    mean: Mapping[str, float] = field(default_factory=dict)
    std: Mapping[str, float] = field(default_factory=dict)
    cov: Mapping[str, Mapping[str, float]] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"style name must be a non-empty string, got {self.name!r}")
        label = f"style {self.name!r}"
        weight = number(f"{label}: weight", self.weight)
        if weight <= 0:
            raise ValueError(f"{label}: weight must be > 0, got {weight!r}")
        if weight > STYLE_VALUE_MAX:
            raise ValueError(f"{label}: weight must be in (0, {STYLE_VALUE_MAX:g}], got {weight!r}")
        mean = _feature_mapping(f"{label}: mean", self.mean, allow_reference=True)
        missing = [n for n in FREE_FEATURES if n not in mean]
        if missing:
            raise ValueError(f"{label}: mean misses feature(s) {', '.join(map(repr, missing))}; give all of "
                             f"{', '.join(FREE_FEATURES)}")
        if REFERENCE_FEATURE in mean:
            if mean[REFERENCE_FEATURE] != 1.0:
                raise ValueError(f"{label}: the reference feature {REFERENCE_FEATURE!r} is fixed at 1, got "
                                 f"{mean[REFERENCE_FEATURE]!r}")
            del mean[REFERENCE_FEATURE]
        for n, v in mean.items():
            if v <= 0:
                raise ValueError(f"{label}: mean[{n!r}] must be > 0 (weights are positive), got {v!r}")
            if v > STYLE_VALUE_MAX:
                raise ValueError(f"{label}: mean[{n!r}] must be in (0, {STYLE_VALUE_MAX:g}], got {v!r}")
        given = [n for n in INTERACTION_FEATURES if n in mean]
        if given and len(given) < len(INTERACTION_FEATURES):
            raise ValueError(f"{label}: a driver who interacts weighs {' and '.join(INTERACTION_FEATURES)}; the mean "
                             f"gives only {', '.join(given)}")
        free = self._free(mean)
        std = _feature_mapping(f"{label}: std", self.std, allow_reference=False)
        stray = [n for n in std if n not in free]
        if stray:
            raise ValueError(f"{label}: std of {', '.join(map(repr, stray))}, which the mean does not weigh; give "
                             f"its mean too")
        for n, v in std.items():
            if v < 0:
                raise ValueError(f"{label}: std[{n!r}] must be >= 0, got {v!r}")
            if v > STYLE_VALUE_MAX:
                raise ValueError(f"{label}: std[{n!r}] must be in [0, {STYLE_VALUE_MAX:g}], got {v!r}")
        cov = None
        if self.cov is not None:
            if std:
                raise ValueError(f"{label}: give std or cov, not both")
            cov = self._checked_cov(label, free)
        object.__setattr__(self, "weight", weight)
        object.__setattr__(self, "mean", FrozenMapping({n: mean[n] for n in free}))
        object.__setattr__(self, "std", FrozenMapping({n: std[n] for n in free if n in std}))
        object.__setattr__(self, "cov", None if cov is None else FrozenMapping(
            {a: FrozenMapping({b: float(cov[i, j]) for j, b in enumerate(free)})
             for i, a in enumerate(free)}))

    @staticmethod
    def _free(mean: Mapping[str, float]) -> tuple[str, ...]:
        return FREE_FEATURES + tuple(n for n in INTERACTION_FEATURES if n in mean)

    @property
    def free_features(self) -> tuple[str, ...]:
        """The features whose weights this style chooses: `FREE_FEATURES`, and `INTERACTION_FEATURES` when its mean
        weighs them."""
        return self._free(self.mean)

    @property
    def feature_names(self) -> tuple[str, ...]:
        """Every feature of this style's drivers, in the model's order (`FEATURE_NAMES`, then the interaction
        features it weighs)."""
        return FEATURE_NAMES + self.free_features[len(FREE_FEATURES):]

    def _checked_cov(self, label: str, free: tuple[str, ...]) -> np.ndarray:
        if not isinstance(self.cov, Mapping):
            raise ValueError(f"{label}: cov must be a mapping feature -> (feature -> number), got {self.cov!r}")
        rows = _feature_mapping_of_mappings(f"{label}: cov", self.cov, free)
        k = len(free)
        mat = np.full((k, k), np.nan)
        for i, a in enumerate(free):
            for j, b in enumerate(free):
                if b in rows.get(a, {}):
                    mat[i, j] = rows[a][b]
        # one triangle is enough; a given pair must agree with its mirror
        for i in range(k):
            for j in range(k):
                if np.isnan(mat[i, j]):
                    mat[i, j] = mat[j, i]
                elif not np.isnan(mat[j, i]) and not math.isclose(mat[i, j], mat[j, i], rel_tol=1e-9,
                                                                  abs_tol=1e-15):
                    raise ValueError(f"{label}: cov is not symmetric: cov[{free[i]!r}]"
                                     f"[{free[j]!r}] = {mat[i, j]} but cov[{free[j]!r}]"
                                     f"[{free[i]!r}] = {mat[j, i]}")
        if np.isnan(mat).any():
            i, j = np.argwhere(np.isnan(mat))[0]
            raise ValueError(f"{label}: cov misses the entry for ({free[i]!r}, {free[j]!r})")
        eig = np.linalg.eigvalsh(mat)
        if eig.min() <= 1e-12 * max(1.0, float(np.abs(eig).max())):
            raise ValueError(f"{label}: cov must be positive definite, its smallest eigenvalue is "
                             f"{eig.min():.3g} (eigenvalues {np.round(eig, 6).tolist()}); use std with zeros "
                             "for a weight that does not vary")
        return mat

    def covariance(self) -> np.ndarray:
        """Covariance (F, F) over `free_features`, in that order."""
        free = self.free_features
        if self.cov is not None:
            return np.array([[self.cov[a][b] for b in free] for a in free])
        return np.diag([self.std.get(n, 0.0) ** 2 for n in free])

    def to_style(self) -> Style:
        """The :class:`pirl_sim.population.Style` (covariance over all of `feature_names`, reference fixed)."""
        names = self.feature_names
        k = len(names)
        free = [names.index(n) for n in self.free_features]
        cov = np.zeros((k, k))
        cov[np.ix_(free, free)] = self.covariance()
        return Style(self.name, self.weight, {**self.mean, REFERENCE_FEATURE: 1.0}, cov=cov)

    def to_dict(self) -> dict[str, Any]:
        """Plain (TOML/JSON-ready) form."""
        out: dict[str, Any] = {"name": self.name, "weight": self.weight, "mean": dict(self.mean)}
        if self.cov is not None:
            out["cov"] = {a: dict(r) for a, r in self.cov.items()}
        elif self.std:
            out["std"] = dict(self.std)
        return out

    @classmethod
    def from_style(cls, style: Style) -> StyleConfig:
        """From a :class:`pirl_sim.population.Style` with ``std`` over the named features."""
        if style.cov is not None:
            cov = np.asarray(style.cov, dtype=float)
            frees = cls._free(style.mean)
            names = FEATURE_NAMES + frees[len(FREE_FEATURES):]
            free = [names.index(n) for n in frees]
            sub = cov[np.ix_(free, free)]
            return cls(style.name, style.weight, dict(style.mean),
                       cov={a: {b: float(sub[i, j]) for j, b in enumerate(frees)} for i, a in enumerate(frees)})
        return cls(style.name, style.weight, dict(style.mean), dict(style.std))


def _feature_mapping_of_mappings(label: str, mapping: Mapping, free: tuple[str, ...]) -> dict[str, dict[str, float]]:
    unknown = [k for k in mapping if k not in free]
    if unknown:
        raise ValueError(f"{label}: unknown feature name(s) {', '.join(map(repr, unknown))}; allowed: "
                         f"{', '.join(free)}")
    return {str(a): _feature_mapping(f"{label}[{a!r}]", row, allow_reference=False) for a, row in mapping.items()}


#: the paper's user-study styles (`scenarios.passage.THREE_STYLES`), by name
PRESET_STYLES: Mapping[str, StyleConfig] = FrozenMapping(
    {s.name: StyleConfig.from_style(s) for s in THREE_STYLES})


# ----------------------------------------------------------------------------------------------
# the population
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PopulationConfig:
    """What a simulated scenario's traffic is made of (validated on construction; "SUMO roundabouts" page).

    Attributes
    ----------
    styles : tuple of StyleConfig      at least one, unique names
    background_share : float           share in [0, 1] of vehicles driven by the simulator's own model
                                       (``round(background_share * n_vehicles)`` of them)
    n_vehicles : int                   vehicles in the scenario, 1 <= n_vehicles <= `MAX_VEHICLES`
    depart_interval : float            mean time between consecutive departures [s], > 0
    arrivals : Arrivals or str         ``"regular"`` (exactly ``depart_interval`` apart) or ``"poisson"``
    control_noise : float              std of Gaussian noise on each applied jerk [m/s^3], <= `MAX_CONTROL_NOISE`
    """

    styles: tuple[StyleConfig, ...] = field(default_factory=lambda: tuple(PRESET_STYLES.values()))
    background_share: float = 0.2
    n_vehicles: int = 80
    depart_interval: float = 4.0
    arrivals: Arrivals = Arrivals.REGULAR
    control_noise: float = 0.0

    def __post_init__(self) -> None:
        styles = self.styles
        if isinstance(styles, (StyleConfig, str, Mapping)) or not hasattr(styles, "__iter__"):
            raise ValueError(f"styles must be a sequence of StyleConfig, got {styles!r}")
        styles = tuple(styles)
        if not styles:
            raise ValueError("a population needs at least one style")
        for s in styles:
            if not isinstance(s, StyleConfig):
                raise ValueError(f"styles must be StyleConfig instances, got {s!r}")
        names = [s.name for s in styles]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"style names must be unique, repeated: {repeated}")
        if len({s.feature_names for s in styles}) > 1:
            weigh = [s.name for s in styles if s.feature_names != FEATURE_NAMES]
            raise ValueError(f"every style weighs {', '.join(INTERACTION_FEATURES)} or none does: the style(s) "
                             f"{weigh} weigh it, the others not")
        share = number("background_share", self.background_share)
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"background_share must be in [0, 1], got {share!r}")
        n = self.n_vehicles
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
            raise ValueError(f"n_vehicles must be an integer, got {n!r}")
        if n < 1:
            raise ValueError(f"n_vehicles must be >= 1, got {n!r}")
        if n > MAX_VEHICLES:
            raise ValueError(f"n_vehicles must be >= 1 and <= {MAX_VEHICLES}, got {n!r}")
        interval = number("depart_interval", self.depart_interval)
        if interval <= 0:
            raise ValueError(f"depart_interval must be > 0 s, got {interval!r}")
        try:
            arrivals = Arrivals(self.arrivals)
        except ValueError:
            raise ValueError(f"arrivals must be one of {[a.value for a in Arrivals]}, got {self.arrivals!r}") from None
        noise = number("control_noise", self.control_noise)
        if not 0 <= noise <= MAX_CONTROL_NOISE:
            raise ValueError(f"control_noise must be >= 0 and <= {MAX_CONTROL_NOISE:g} m/s^3 (the drivers' jerk "
                             f"bound), got {noise!r}")
        object.__setattr__(self, "styles", styles)
        object.__setattr__(self, "background_share", share)
        object.__setattr__(self, "n_vehicles", int(n))
        object.__setattr__(self, "depart_interval", interval)
        object.__setattr__(self, "arrivals", arrivals)
        object.__setattr__(self, "control_noise", noise)

    # -- derived ----------------------------------------------------------------------------------

    @property
    def style_names(self) -> tuple[str, ...]:
        """Style names in order (a style's index is its position here)."""
        return tuple(s.name for s in self.styles)

    @property
    def feature_names(self) -> tuple[str, ...]:
        """The drivers' features: `FEATURE_NAMES`, and `INTERACTION_FEATURES` when the styles weigh them."""
        return self.styles[0].feature_names

    @property
    def interacting(self) -> bool:
        """Whether the drivers weigh the interaction features (``kind="interacting"`` of
        `pirl_sim.driving.roundabout_features`)."""
        return self.feature_names != FEATURE_NAMES

    @property
    def n_background(self) -> int:
        """Vehicles driven by the simulator's own model: ``round(background_share * n_vehicles)``."""
        return int(round(self.background_share * self.n_vehicles))

    @property
    def n_pirl(self) -> int:
        """Vehicles driven by sampled PIRL drivers."""
        return self.n_vehicles - self.n_background

    @property
    def depart_rate(self) -> float:
        """Mean departures per hour [veh/h]."""
        return 3600.0 / self.depart_interval

    def population(self, features: FeatureSet) -> Population:
        """The :class:`pirl_sim.population.Population` over ``features`` (names checked against them)."""
        if tuple(features.names) != self.feature_names or features.reference != REFERENCE_FEATURE:
            raise ValueError(f"features must be {self.feature_names} with reference {REFERENCE_FEATURE!r} (the "
                             f"roundabout model), got {tuple(features.names)} with {features.reference!r}")
        return Population(features, tuple(s.to_style() for s in self.styles), None)

    def sample_weights(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Draw n drivers: normalised weights (n, K) over `feature_names` and style indices (n,).

        :meth:`pirl_sim.population.Population.sample_weights` of :meth:`population` (styles by mixture
        weight, then each style's Gaussian, draws kept positive).
        """
        return self.population(_naming_features(self.interacting)).sample_weights(n, rng)

    def depart_times(self, rng: np.random.Generator) -> np.ndarray:
        """Departure times [s], shape (n_vehicles,), non-decreasing, the first at 0.

        Parameters
        ----------
        rng : numpy.random.Generator
            Used for Poisson arrivals only (not touched for regular ones).
        """
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        n = self.n_vehicles
        if self.arrivals is Arrivals.REGULAR:
            return self.depart_interval * np.arange(n, dtype=float)
        gaps = rng.exponential(self.depart_interval, size=n - 1)
        return np.concatenate(([0.0], np.cumsum(gaps)))

    def to_dict(self) -> dict[str, Any]:
        """Plain (TOML/JSON-ready) form that :func:`population_from_dict` reads back."""
        return {
            "n_vehicles": self.n_vehicles,
            "depart_interval": self.depart_interval,
            "arrivals": self.arrivals.value,
            "background_share": self.background_share,
            "control_noise": self.control_noise,
            "styles": [s.to_dict() for s in self.styles],
        }


def _naming_features(interacting: bool = False) -> FeatureSet:
    """The roundabout model's feature names and reference, for drawing weights without a path.

    ``speed_dev`` needs a reference path to be evaluated; drawing weights only needs the names, so its
    residual here refuses to be evaluated.
    """

    def no_path(x, u):
        raise RuntimeError("speed_dev needs a reference path: use pirl_sim.driving.roundabout_features")

    feats: tuple[Feature, ...] = (Feature("speed_dev", no_path, reduction="mean", quadratic=False),
                                  squared_state("acc_sq", [2], reduction="mean"),
                                  squared_control("jerk_sq", reduction="mean"))
    if interacting:
        feats += tuple(Feature(n, no_path, reduction="mean", quadratic=False) for n in INTERACTION_FEATURES)
    return FeatureSet(feats, reference=REFERENCE_FEATURE)


# ----------------------------------------------------------------------------------------------
# TOML
# ----------------------------------------------------------------------------------------------

_TOP_KEYS = ("styles", "background_share", "n_vehicles", "depart_interval", "depart_rate", "arrivals",
             "control_noise")
_STYLE_KEYS = ("name", "preset", "weight", "mean", "std", "cov")


def population_from_dict(data: Mapping[str, Any], *, source: str = "population") -> PopulationConfig:
    """Build a `PopulationConfig` from plain data (the parsed TOML; ValueError for unknown keys or preset names,
    listing the known ones, and everything `PopulationConfig` and `StyleConfig` reject).

    Parameters
    ----------
    data : mapping     keys as the attributes of `PopulationConfig`, or ``depart_rate`` [veh/h] instead of
                       ``depart_interval``; ``styles`` a list of tables (``name``, ``weight``, ``mean``, ``std`` or
                       ``cov``, or ``preset = "<name>"`` of `PRESET_STYLES`); omitted keys take the defaults
    source : str       named in error messages (e.g. the file)
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"{source}: expected a table of settings, got {type(data).__name__}")
    check_keys(source, data, _TOP_KEYS)
    kwargs: dict[str, Any] = {k: data[k] for k in ("background_share", "n_vehicles", "depart_interval",
                                                   "arrivals", "control_noise") if k in data}
    if "depart_rate" in data:
        if "depart_interval" in data:
            raise ValueError(f"{source}: give depart_interval [s] or depart_rate [veh/h], not both")
        rate = number(f"{source}: depart_rate", data["depart_rate"])
        if rate <= 0:
            raise ValueError(f"{source}: depart_rate must be > 0 veh/h, got {rate!r}")
        kwargs["depart_interval"] = 3600.0 / rate
    if "styles" in data:
        raw = data["styles"]
        if isinstance(raw, (str, Mapping)) or not isinstance(raw, (list, tuple)):
            raise ValueError(f"{source}: styles must be a list of tables ([[styles]]), got {raw!r}")
        kwargs["styles"] = tuple(_style_from_dict(s, f"{source}: styles[{i}]") for i, s in enumerate(raw))
    try:
        return PopulationConfig(**kwargs)
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None


def _style_from_dict(data: Any, label: str) -> StyleConfig:
    if not isinstance(data, Mapping):
        raise ValueError(f"{label}: a style must be a table, got {data!r}")
    check_keys(label, data, _STYLE_KEYS)
    if "preset" in data:
        name = data["preset"]
        if not isinstance(name, str) or name not in PRESET_STYLES:
            raise ValueError(f"{label}: unknown style name {name!r} for preset; known styles: "
                             f"{', '.join(map(repr, PRESET_STYLES))}")
        extra = [k for k in ("mean", "std", "cov") if k in data]
        if extra:
            raise ValueError(f"{label}: a preset style fixes mean and spread; remove {', '.join(extra)} or "
                             "define the style in full without preset")
        base = PRESET_STYLES[name]
        args = (data.get("name", base.name), data.get("weight", base.weight), base.mean, base.std, base.cov)
    else:
        if "name" not in data:
            raise ValueError(f"{label}: a style needs a name (or a preset = one of "
                             f"{', '.join(map(repr, PRESET_STYLES))})")
        if "mean" not in data:
            raise ValueError(f"{label}: style {data['name']!r} needs a mean over {', '.join(FREE_FEATURES)}")
        args = (data["name"], data.get("weight", 1.0), data["mean"], data.get("std", {}), data.get("cov"))
    try:
        return StyleConfig(*args)
    except ValueError as exc:
        raise ValueError(f"{label}: {exc}") from None


def population_from_toml(text: str, *, source: str = "<toml>") -> PopulationConfig:
    """Parse TOML text into a :class:`PopulationConfig` (see :func:`population_from_dict`)."""
    return population_from_dict(toml_text.loads(text, source), source=source)


def load_population(path) -> PopulationConfig:
    """Read a population TOML file (see the module docstring for an example).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        As :func:`population_from_dict`, the message starting with the file name.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"population config not found: {path}")
    return population_from_toml(read_toml_text(path, "population config"), source=str(path))


def read_toml_text(path: Path, what: str) -> str:
    """The text of a TOML file (`pirl_sim.io.toml_text.read_text`)."""
    return toml_text.read_text(path, what)


#: the embedded default: the paper's three user-study styles in equal shares, 20 % background traffic
DEFAULT_POPULATION_TOML = """\
# pirl_sim default population: the paper's three user-study styles, 20 % background traffic.
# Weights are normalised (jerk_sq = 1); mean and std over the named features speed_dev and acc_sq.
n_vehicles = 80
depart_interval = 4.0      # [s] between departures (or depart_rate [veh/h])
arrivals = "regular"       # "regular" or "poisson"
background_share = 0.2     # driven by the simulator's own car-following model, weights unknown
control_noise = 0.0        # [m/s^3] std of Gaussian noise on each applied jerk

[[styles]]
name = "tracks desired speed"
weight = 1.0
mean = { speed_dev = 3.0, acc_sq = 0.3 }
std = { speed_dev = 0.3, acc_sq = 0.03 }

[[styles]]
name = "minimises acceleration"
weight = 1.0
mean = { speed_dev = 0.1, acc_sq = 3.0 }
std = { speed_dev = 0.01, acc_sq = 0.3 }

[[styles]]
name = "no preference"
weight = 1.0
mean = { speed_dev = 0.3, acc_sq = 0.3 }
std = { speed_dev = 0.03, acc_sq = 0.03 }
"""

DEFAULT_POPULATION: PopulationConfig = population_from_toml(DEFAULT_POPULATION_TOML, source="default population")

#: an example of drivers who interact: two styles that differ tenfold in their headway and yielding weights
INTERACTING_POPULATION_TOML = """\
# pirl_sim example population of drivers who interact: the gap to the vehicle ahead (headway) and to the point
# they yield at (yielding) are in their own cost. 20 % background traffic.
n_vehicles = 80
depart_interval = 4.0
background_share = 0.2

[[styles]]
name = "close follower"
mean = { speed_dev = 3.0, acc_sq = 0.3, headway = 3.0, yielding = 3.0 }
std = { speed_dev = 0.3, acc_sq = 0.03, headway = 0.3, yielding = 0.3 }

[[styles]]
name = "keeps its distance"
mean = { speed_dev = 0.3, acc_sq = 0.3, headway = 30.0, yielding = 30.0 }
std = { speed_dev = 0.03, acc_sq = 0.03, headway = 3.0, yielding = 3.0 }
"""

INTERACTING_POPULATION: PopulationConfig = population_from_toml(INTERACTING_POPULATION_TOML,
                                                                source="interacting population")
