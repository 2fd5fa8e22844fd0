"""The desired-speed model's parameters fitted to recorded speeds: a robust fit of speeds against curvature.

The roundabout model's desired speed is v_des(kappa) = (kappa^4 / a_lat^4 + v_max^-8)^(-1/8)
(`pirl_sim.driving.smooth_desired_speed`): the lateral-acceleration limit a_lat [m/s^2] on curves, the speed
cap v_max [m/s] on straight road. `fit_desired_speed` fits both to recorded (curvature, speed) pairs of free
driving by least squares with a Cauchy loss on v - v_des(kappa) in the log-parameters: cars braking to yield or
accelerating away from a stop are far from their desired speed and would pull a squared loss down, the robust
loss lets them count little. Speeds below ``min_speed`` are left out (stops are not a choice of speed).

Pure array maths; the replay (`pirl_sim.experiments.recorded`) fits it on each split's training tracks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pirl_sim.driving import smooth_desired_speed
from pirl_sim.paths import DEFAULT_A_LAT, DEFAULT_V_MAX

__all__ = ["DesiredSpeedFit", "fit_desired_speed", "A_LAT_RANGE", "V_MAX_RANGE"]

A_LAT_RANGE = (0.2, 8.0)  #: [m/s^2] bounds of the fitted lateral-acceleration limit
V_MAX_RANGE = (2.0, 40.0)  #: [m/s] bounds of the fitted speed cap


@dataclass(frozen=True)
class DesiredSpeedFit:
    """Fitted desired-speed parameters.

    Attributes
    ----------
    a_lat : float [m/s^2]    lateral-acceleration limit
    v_max : float [m/s]      speed cap
    n_samples : int          (curvature, speed) pairs used
    scale : float [m/s]      robust scale of the residuals v - v_des (1.4826 x MAD)
    converged : bool         the optimiser's success flag
    at_bound : bool          a parameter ended at its bound (`A_LAT_RANGE`, `V_MAX_RANGE`)
    """

    a_lat: float
    v_max: float
    n_samples: int
    scale: float
    converged: bool
    at_bound: bool


def fit_desired_speed(kappa: np.ndarray, v: np.ndarray, *, min_speed: float = 1.0, f_scale: float = 1.0,
                      a_lat0: float = DEFAULT_A_LAT, v_max0: float = DEFAULT_V_MAX) -> DesiredSpeedFit:
    """Fit a_lat and v_max of v_des(kappa) to speeds (module doc).

    Parameters
    ----------
    kappa : array (n,) [1/m]   curvature at each sample (the one the desired speed sees)
    v : array (n,) [m/s]       speed at each sample
    min_speed : float [m/s]    samples below this speed are left out
    f_scale : float [m/s]      residual scale of the Cauchy loss
    a_lat0, v_max0 : float     start [m/s^2, m/s]

    Returns
    -------
    DesiredSpeedFit
    """
    from scipy.optimize import least_squares

    kappa = np.asarray(kappa, dtype=float).ravel()
    v = np.asarray(v, dtype=float).ravel()
    if kappa.shape != v.shape:
        raise ValueError(f"kappa and v need the same shape, got {kappa.shape} and {v.shape}")
    for name, value in (("min_speed", min_speed), ("f_scale", f_scale)):
        if not np.isfinite(value) or value < 0 or (name == "f_scale" and value == 0):
            raise ValueError(f"{name} must be a finite number {'> 0' if name == 'f_scale' else '>= 0'}, got {value!r}")
    use = np.isfinite(kappa) & np.isfinite(v) & (v >= min_speed)
    if use.sum() < 10:
        raise ValueError(f"need at least 10 samples at or above min_speed={min_speed} m/s, got {int(use.sum())}")
    k, vv = np.abs(kappa[use]), v[use]
    lo = np.log([A_LAT_RANGE[0], V_MAX_RANGE[0]])
    hi = np.log([A_LAT_RANGE[1], V_MAX_RANGE[1]])
    x0 = np.clip(np.log([a_lat0, v_max0]), lo + 1e-6, hi - 1e-6)

    def residual(x):
        return vv - smooth_desired_speed(k, np.exp(x[0]), np.exp(x[1]))[0]

    res = least_squares(residual, x0, bounds=(lo, hi), loss="cauchy", f_scale=f_scale, x_scale=1.0)
    a_lat, v_max = np.exp(res.x)
    r = residual(res.x)
    at_bound = bool(np.any(np.isclose(res.x, lo, atol=1e-4) | np.isclose(res.x, hi, atol=1e-4)))
    return DesiredSpeedFit(float(a_lat), float(v_max), int(use.sum()),
                           float(1.4826 * np.median(np.abs(r - np.median(r)))), bool(res.success), at_bound)
