"""Summary statistics of the reports: confidence intervals over seeds."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ci95"]


def ci95(values) -> float:
    """Half-width of the 95 % confidence interval of the mean of ``values`` (Student t, n - 1 degrees of
    freedom; NaN values ignored); NaN for fewer than two values."""
    from scipy.stats import t as student

    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) < 2:
        return math.nan
    return float(student.ppf(0.975, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v)))
