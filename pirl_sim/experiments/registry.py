"""The experiment kinds the engine can run, by name: every `ScenarioSpec` of the experiments package."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from . import agents, horizon_scan, policy_recovery, recorded, recovery, simulated, weight_space
from .spec import ScenarioSpec, convert_param

__all__ = ["SCENARIOS", "KIND_LEARNERS", "PROTOCOL_FREE", "register_scenario", "scenario_spec", "resolve_scenario_params"]

SCENARIOS: dict[str, ScenarioSpec] = {s.name: s for s in (*simulated.SPECS, *recorded.SPECS, agents.SPEC, recovery.SPEC,
                                                           horizon_scan.SPEC, policy_recovery.SPEC, weight_space.SPEC)}
#: learners that only some kinds run (their classes name the kinds in ``scenarios``): the agents' policies and
#: the recovery kind's per-track IRL
KIND_LEARNERS: dict[str, type] = {**agents.POLICIES, **recovery.LEARNERS, **policy_recovery.LEARNERS, **horizon_scan.LEARNERS}
#: kinds that score whole runs or episodes, not predictions under a protocol: a config may leave out protocols
PROTOCOL_FREE: frozenset[str] = frozenset({"agents", "recovery", "policy-recovery"})


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


def resolve_scenario_params(name: str, given: Mapping[str, Any], base_dir: Path | None = None) -> dict:
    """Validate the parameters of scenario ``name`` and complete them with its defaults.

    Parameters
    ----------
    name : str                   a registered scenario
    given : mapping              parameters from a config (TOML values)
    base_dir : Path or None      directory that relative paths are taken from

    Returns
    -------
    params : dict                normalised, JSON-serialisable: what a cell key hashes and ``build`` receives;
                                 ValueError for an unknown scenario or parameter (listing the valid ones) or value
    """
    spec = scenario_spec(name)
    if unknown := [k for k in given if k not in spec.params]:
        raise ValueError(f"scenario {name!r}: unknown parameter(s) {', '.join(map(repr, unknown))}; valid "
                         f"parameters: {', '.join(spec.params)}")
    full = {key: convert_param(p.kind, f"scenario {name!r} parameter {key!r}", given.get(key, p.default), base_dir,
                          p.choices) for key, p in spec.params.items()}
    try:
        return spec.check(full)
    except (TypeError, ValueError) as exc:  # TypeError: the scenario config's own type checks
        msg = str(exc)
        raise ValueError(msg if msg.startswith(f"scenario {name!r}") else f"scenario {name!r}: {msg}") from None


