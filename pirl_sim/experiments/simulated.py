"""The generated (synthetic, passage) and simulated (SUMO, highway-env) experiment kinds: parameters -> data."""

from __future__ import annotations

import importlib
import math
from functools import partial
from operator import itemgetter
from pathlib import Path

from pirl_sim.extras import install_hint
from pirl_sim.population import Style

from pirl_sim.scenarios.passage import PassageConfig
from pirl_sim.scenarios.synthetic import SyntheticConfig

from .spec import Param, ScenarioData, ScenarioSpec, TrainShape, dataclass_params, split_indices

__all__ = ["SPECS", "generated_config"]


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
_MIX = Param("mix", None, "mixture weights by style name (0 drops a style); default: the styles' own")
_SYNTHETIC_PARAMS = {
    **dataclass_params(SyntheticConfig, kinds={"styles": "styles", "rationality": "rationality"},
                       defaults={"styles": None, "rationality": math.inf}),
    "mix": _MIX,
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
    **dataclass_params(PassageConfig, kinds={"styles": "styles", "rationality": "rationality"},
                       defaults={"styles": None}),
    "mix": _MIX,
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
        raise ValueError(f"scenario {name!r} needs {exc.name}, which is not installed: {install_hint(name)}") from None


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


def _build_simulated(name: str, params: dict, seed: int, simulation_dir: Path) -> ScenarioData:
    run = getattr(_simulator(name), f"load_{name}_run")(simulation_dir)
    demos = run.demonstrations(selection=params["selection"], min_steps=params["min_steps"])
    if len(demos) < 2:
        raise ValueError(f"scenario {name!r}: only {len(demos)} demonstrations with selection "
                         f"{params['selection']!r} and min_steps {params['min_steps']} (more vehicles?)")
    train, test = split_indices(len(demos), params["test_fraction"], seed)
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


#: the synthetic, passage, SUMO and highway-env kinds
SPECS: tuple[ScenarioSpec, ...] = (
    ScenarioSpec(
        "synthetic", "the paper's 1-D point mass regulated by LQR, theta = q/r from two kernels",
        _SYNTHETIC_PARAMS, partial(_check_generated, "synthetic"), partial(_build_generated, "synthetic"),
        _shape_fixed,
    ),
    ScenarioSpec(
        "passage", "roundabout passage, drivers of the paper's three user-study styles",
        _PASSAGE_PARAMS, partial(_check_generated, "passage"), partial(_build_generated, "passage"), _shape_fixed,
    ),
    *(ScenarioSpec(
        name, summary, _SIMULATED_PARAMS, partial(_check_simulated, name), partial(_build_simulated, name),
        _shape_simulated, simulation=_simulation_params, simulate=partial(_simulate, name),
        driver_horizon=itemgetter("horizon"),  # the drivers' own
    ) for name, summary in (
        ("sumo", "SUMO roundabout (libsumo), PIRL drivers of known weights re-planning every 0.1 s among SUMO's own"),
        ("highway", "highway-env roundabout, PIRL drivers of known weights re-planning every 0.1 s among IDM "
                    "vehicles"))),
)
