"""Hypothesis strategies for pirl_sim's types, for property tests (needs the ``hypothesis`` test extra)."""

from __future__ import annotations

import numpy as np

from .dynamics import LinearDynamics
from .trajectory import Trajectory

__all__ = ["trajectories"]


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
