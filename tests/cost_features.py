"""Cost features that several core test modules differentiate (tests/core/test_features.py, tests/core/test_irl.py).
Test modules ``from cost_features import ...`` (tests/conftest.py puts tests/ on sys.path)."""

import numpy as np

from pirl_sim.features import Feature, FeatureSet, Residual, squared_control, squared_state


def nonquadratic_features():
    """A feature with a residual that is not affine in the state: (v - sin(s))^2, plus a^2 and j^2 (means)."""

    def resid(x, u):
        s, v = x[..., 0], x[..., 1]
        r = (v - np.sin(s))[..., None]
        jx = np.zeros(x.shape[:2] + (1, 3))
        jx[..., 0, 0] = -np.cos(s)
        jx[..., 0, 1] = 1.0
        hx = np.zeros(x.shape[:2] + (1, 3, 3))
        hx[..., 0, 0, 0] = np.sin(s)
        return Residual(r, jx, np.zeros((1, 1, 1, 1)), hx)

    return FeatureSet(
        (
            Feature("speed_dev", resid, reduction="mean", quadratic=False),
            squared_state("acc", [2], reduction="mean"),
            squared_control("jerk", reduction="mean"),
        ),
        reference="jerk",
    )
