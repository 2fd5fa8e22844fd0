"""Test helpers: Hypothesis strategies for pirl_sim's types (property tests; need the ``hypothesis`` test extra)
and :func:`assert_recovered`, which asserts that fitted weights come back within stated tolerances."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dynamics import LinearDynamics
from .trajectory import Trajectory

__all__ = ["trajectories", "assert_recovered", "recovery_misses", "RecoveryMiss"]


def trajectories(dynamics: LinearDynamics, *, min_steps: int = 1, max_steps: int = 30, scale: float = 10.0):
    """Strategy: dynamically consistent `Trajectory` objects of ``dynamics`` (random start and controls)."""
    from hypothesis import strategies as st
    from hypothesis.extra.numpy import arrays

    finite = st.floats(-scale, scale, allow_nan=False, allow_infinity=False)

    @st.composite
    def build(draw):
        n = draw(st.integers(min_steps, max_steps))
        x0 = draw(arrays(float, dynamics.n_x, elements=finite))
        U = draw(arrays(float, (n, dynamics.n_u), elements=finite))
        return Trajectory(dynamics.rollout(x0, U), U, dynamics.dt)

    return build()


# ---------------------------------------------------------------------------------------------- recovery
@dataclass(frozen=True)
class RecoveryMiss:
    """One figure of a :class:`~pirl_sim.recovery.RecoveryReport` outside its tolerance."""

    feature: str
    style: str
    statistic: str
    bound: str
    value: float
    low: float
    high: float
    limit: float
    n: int

    def __str__(self) -> str:
        which = "" if self.bound == "estimate" else f" ({self.bound} end of its interval)"
        return (f"{self.feature}, style {self.style!r} (n={self.n}): {self.statistic} |log error| "
                f"{self.value:.4g}{which}, interval [{self.low:.4g}, {self.high:.4g}], tolerance {self.limit:g}")


def recovery_misses(report, tolerances, *, statistic: str = "median", bound: str = "estimate",
                    styles="all") -> list[RecoveryMiss]:
    """The figures of ``report`` outside ``tolerances`` (see :func:`assert_recovered`); empty when all are in."""
    import math
    from collections.abc import Mapping

    from .recovery import STATISTICS, RecoveryReport

    if not isinstance(report, RecoveryReport):
        raise TypeError(f"report must be a pirl_sim.recovery.RecoveryReport, got {type(report).__name__}")
    if not isinstance(tolerances, Mapping) or not tolerances:
        raise TypeError("tolerances must be a non-empty mapping {feature: limit} or {statistic: {feature: limit}}")
    if all(isinstance(v, Mapping) for v in tolerances.values()):
        table = {s: dict(v) for s, v in tolerances.items()}
    elif not any(isinstance(v, Mapping) for v in tolerances.values()):
        table = {statistic: dict(tolerances)}
    else:
        raise TypeError("tolerances must be all {feature: limit} or all {statistic: {feature: limit}}, not mixed")
    bounds = ("estimate", "high")
    if bound not in bounds:
        raise ValueError(f"bound must be one of {bounds} (the statistic, or the upper end of its interval), "
                         f"got {bound!r}")
    if styles == "all":
        groups = ["all"]
    elif styles == "each":
        groups = ["all", *report.style_names]
    else:
        if isinstance(styles, str):
            raise ValueError(f"styles must be 'all', 'each' or a list of style names, got {styles!r}")
        groups = list(styles)
        unknown = [s for s in groups if s != "all" and s not in report.style_names]
        if unknown or not groups:
            raise ValueError(f"styles {unknown or groups!r}: the report's styles are {report.style_names}")
    summary = report.summary()
    misses = []
    for stat, limits in table.items():
        if stat not in STATISTICS:
            raise ValueError(f"statistic must be one of {STATISTICS}, got {stat!r}")
        if "*" in limits:
            limits = {**{f: limits["*"] for f in report.features}, **{f: v for f, v in limits.items() if f != "*"}}
        for feature, limit in limits.items():
            if feature not in report.features:
                raise ValueError(f"tolerance for unknown feature {feature!r}; the report's features are "
                                 f"{report.features} ('*': every one)")
            if isinstance(limit, bool) or not isinstance(limit, (int, float)) or not (math.isfinite(limit)
                                                                                   and limit >= 0):
                raise ValueError(f"the tolerance of {feature!r} ({stat}) must be a number >= 0 of |log error|, "
                                 f"got {limit!r}")
            for group in groups:
                row = summary[(summary["feature"] == feature) & (summary["style"] == group)].iloc[0]
                value = float(row[stat] if bound == "estimate" else row[f"{stat}_high"])
                if not value <= limit:  # NaN (e.g. an interval of one track) is a miss
                    misses.append(RecoveryMiss(feature, group, stat, bound, value, float(row[f"{stat}_low"]),
                                               float(row[f"{stat}_high"]), float(limit), int(row["n"])))
    return misses


def assert_recovered(report, tolerances, *, statistic: str = "median", bound: str = "estimate",
                     styles="all") -> None:
    """Assert that a `~pirl_sim.recovery.RecoveryReport` recovers the weights within tolerances: AssertionError listing
    every (feature, style, statistic) out of tolerance with its value, interval and limit.

    Parameters
    ----------
    report : RecoveryReport
    tolerances : mapping        ``{feature: limit}`` for ``statistic``, or ``{statistic: {feature: limit}}`` (limits
                                >= 0 on "median", "p90", "mean" of |log(theta_hat / theta)|; feature ``"*"``: all)
    statistic : str             the statistic of a flat ``{feature: limit}``
    bound : {"estimate", "high"}   compare the statistic, or the upper end of its confidence interval (a test)
    styles : "all", "each" or list of str   over all tracks; all and each style; or these groups (bad arguments:
                                TypeError, ValueError)
    """
    misses = recovery_misses(report, tolerances, statistic=statistic, bound=bound, styles=styles)
    if misses:
        head = (f"weights not recovered within tolerance ({report!r}); "
                f"{len(misses)} figure(s) out of tolerance:")
        raise AssertionError("\n".join([head, *(f"  - {m}" for m in misses)]))
