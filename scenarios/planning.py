"""Who drives, when and where: a population plan drawn before a simulation starts (simulator-neutral).

:func:`plan_population` draws, from ``numpy.random.SeedSequence(seed)``, the departure times, which
vehicles are background traffic, each PIRL driver's style and normalised weights and every vehicle's route
— the one plan of every simulator: the SUMO scenario (:func:`pirl_sim.scenarios.sumo.scenario.plan_vehicles`)
and the highway-env scenario both call it, so for the same population, route catalogue and seed they get the
same plan. It takes plain arguments instead of a simulator's config.

Random streams (:func:`random_streams`): ``SeedSequence(seed).spawn(3)`` gives the population draws
(stream 0), the drivers' control noise (stream 1) and the simulator's own behaviour
(stream 2: background drivers' parameters, initial placement).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from pirl_sim.validation import number

from .population_config import FEATURE_NAMES, PopulationConfig
from .recording import BACKGROUND_STYLE, BACKGROUND_STYLE_NAME

__all__ = ["PLAN_COLUMNS", "theta_columns", "check_seed", "random_streams", "route_id", "check_routes",
           "check_route_weights", "plan_population"]

#: columns of a plan, one row per vehicle in departure order (then ``theta_headway``, ``theta_yielding`` for drivers
#: who interact)
PLAN_COLUMNS: tuple[str, ...] = ("vehicle_id", "depart", "route_id", "is_pirl", "style", "style_name",
                                 *(f"theta_{f}" for f in FEATURE_NAMES))


def theta_columns(plan: pd.DataFrame) -> list[str]:
    """A plan's weight columns in feature order (``theta_<feature>``)."""
    return [c for c in plan.columns if str(c).startswith("theta_")]


def check_seed(seed) -> int:
    """``seed`` as an int, or ``ValueError`` unless it is an integer in [0, 2**31)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**31:
        raise ValueError(f"seed must be an integer in [0, 2**31), got {seed!r}")
    return int(seed)


def random_streams(seed: int) -> tuple[np.random.Generator, np.random.Generator, np.random.Generator]:
    """(population draws, control noise, simulator behaviour): independent generators from ``seed``."""
    a, b, c = np.random.SeedSequence(check_seed(seed)).spawn(3)
    return np.random.default_rng(a), np.random.default_rng(b), np.random.default_rng(c)


def route_id(entry_arm: int, exit_arm: int) -> str:
    """Id of the roundabout route entering from arm ``entry_arm`` and leaving by arm ``exit_arm``: every
    simulator's name for it (``"arm{entry_arm}_to_arm{exit_arm}"``)."""
    return f"arm{entry_arm}_to_arm{exit_arm}"


def check_routes(label: str, chosen, catalogue: Sequence[str]) -> tuple[str, ...] | None:
    """``chosen`` route ids as a tuple (None stays None: every route), or ``ValueError`` naming the ones
    that are not in ``catalogue``."""
    if chosen is None:
        return None
    if isinstance(chosen, str) or not len(chosen):
        raise ValueError(f"{label} must be a non-empty list of route ids, got {chosen!r}")
    unknown = [r for r in chosen if r not in catalogue]
    if unknown:
        raise ValueError(f"{label}: unknown route(s) {unknown}; routes: {', '.join(catalogue)}")
    return tuple(chosen)


def check_route_weights(weights, catalogue: Sequence[str]) -> dict[str, float] | None:
    """``weights`` (route id -> relative frequency, >= 0, some > 0) as a dict sorted by route id (None stays None:
    every route equally often), or ``ValueError`` naming a route not in ``catalogue`` or a bad weight."""
    if weights is None:
        return None
    if not isinstance(weights, Mapping) or not weights:
        raise ValueError(f"route_weights must be a non-empty mapping route id -> weight, got {weights!r}")
    unknown = sorted(set(weights) - set(catalogue))
    if unknown:
        raise ValueError(f"route_weights: unknown route(s) {unknown}; routes: {', '.join(catalogue)}")
    out = {r: number(f"route_weights[{r!r}]", w, low=0.0) for r, w in sorted(weights.items())}
    if not sum(out.values()) > 0:
        raise ValueError(f"route_weights must give some route a weight > 0, got {weights!r}")
    return out


def plan_population(population: PopulationConfig, route_ids: Sequence[str], seed: int, *,
                    pirl_routes: Sequence[str] | None = None,
                    background_routes: Sequence[str] | None = None,
                    route_weights: Mapping[str, float] | None = None) -> pd.DataFrame:
    """Every vehicle of a run, drawn from ``seed`` before anything runs.

    Parameters
    ----------
    population : PopulationConfig
    route_ids : sequence of str        the route catalogue in its canonical order (draws index into it)
    seed : int                         in [0, 2**31)
    pirl_routes, background_routes : sequence of str, optional   routes PIRL / background vehicles draw from; None: all
    route_weights : mapping route id -> float, optional   relative frequencies of the routes (normalised over the
                                       routes each kind of vehicle draws from; a route not named has weight 0);
                                       None: every route equally often

    Returns
    -------
    plan : pandas.DataFrame            `PLAN_COLUMNS`, one row per vehicle in departure order (``style`` -1 and NaN
                                       weights for background); ValueError for a bad seed or unknown routes
    """
    if not isinstance(population, PopulationConfig):
        raise TypeError(f"population must be a PopulationConfig, got {type(population).__name__}")
    catalogue = list(route_ids)
    if not catalogue:
        raise ValueError("route_ids must name at least one route")
    pirl_list = list(check_routes("pirl_routes", pirl_routes, catalogue) or catalogue)
    bg_list = list(check_routes("background_routes", background_routes, catalogue) or catalogue)
    rng, _, _ = random_streams(seed)
    n = population.n_vehicles
    depart = population.depart_times(rng)
    is_pirl = np.ones(n, dtype=bool)
    is_pirl[rng.choice(n, size=population.n_background, replace=False)] = False
    n_pirl = int(is_pirl.sum())
    features = population.feature_names
    theta = np.full((n, len(features)), np.nan)
    style = np.full(n, BACKGROUND_STYLE, dtype=np.int64)
    if n_pirl:
        theta[is_pirl], style[is_pirl] = population.sample_weights(n_pirl, rng)
    route = np.empty(n, dtype=object)
    if route_weights is None:
        route[is_pirl] = [pirl_list[i] for i in rng.integers(len(pirl_list), size=n_pirl)]
        route[~is_pirl] = [bg_list[i] for i in rng.integers(len(bg_list), size=n - n_pirl)]
    else:
        for label, mask, routes in (("pirl_routes", is_pirl, pirl_list), ("background_routes", ~is_pirl, bg_list)):
            w = np.array([float(route_weights.get(r, 0.0)) for r in routes])
            if mask.any() and not w.sum() > 0:
                raise ValueError(f"route_weights give every route of {label} weight 0: {', '.join(routes)}")
            if mask.any():
                route[mask] = [routes[i] for i in rng.choice(len(routes), size=int(mask.sum()), p=w / w.sum())]
    width = max(3, len(str(n - 1)))
    names = population.style_names
    return pd.DataFrame({
        "vehicle_id": [f"veh{k:0{width}d}" for k in range(n)],
        "depart": depart,
        "route_id": route.astype(str),
        "is_pirl": is_pirl,
        "style": style,
        "style_name": [names[s] if s >= 0 else BACKGROUND_STYLE_NAME for s in style],
        **{f"theta_{f}": theta[:, i] for i, f in enumerate(features)},
    }, columns=[*PLAN_COLUMNS, *(f"theta_{f}" for f in features[len(FEATURE_NAMES):])])
