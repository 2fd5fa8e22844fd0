"""The roundabout driver model of the paper: longitudinal motion along a reference path, three features.

State (s [m], v [m/s], a [m/s^2]) along a `ReferencePath`, control jerk [m/s^3] (`dynamics.longitudinal`).
Features (means over the N steps, as in the paper):

- ``speed_dev``: (v - v_des(s))^2, the squared deviation from a curvature-limited desired speed,
- ``acc_sq``:    a^2,
- ``jerk_sq``:   j^2 (the reference feature: reported weights are relative to it).

Desired speed. The paper's ``sqrt(a_des * kappa)`` has a slip (see shared/data/README.md): a lateral
acceleration limit gives ``sqrt(a_lat / |kappa|)``, capped by a speed limit where kappa is near 0. We use the
smooth cap

    v_des(kappa) = (v_c^-8 + v_max^-8)^(-1/8) = (q^2 + v_max^-8)^(-1/8),   v_c = sqrt(a_lat / |kappa|),
                                                                      q = kappa^2 / a_lat^2,

which is within 0.3 % of v_c wherever v_c < 0.6 v_max, equals v_max at kappa = 0, dips to
2^(-1/8) = 0.917 of the hard cap min(v_c, v_max) at the crossover, and is infinitely differentiable —
so the features have exact, continuous gradients and Hessians (the IRL needs the second derivatives).
Curvature along s is a cubic spline through the path's tabulated kappa (periodic on closed paths); beyond the
ends of an open path it is held at the end value (straight-line extension of the speed profile).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from .dynamics import LinearDynamics, longitudinal
from .features import Feature, FeatureSet, Residual, squared_control, squared_state
from .model import DriverModel
from .mpc import Bounds, SequentialMPC
from .paths import DEFAULT_A_LAT, DEFAULT_V_MAX, ReferencePath

__all__ = [
    "CompositePath",
    "smooth_desired_speed",
    "SpeedProfile",
    "roundabout_features",
    "PathDriverModel",
    "roundabout_model",
    "fit_longitudinal_states",
    "DEFAULT_BOUNDS",
]

#: Default bounds of the roundabout MPC: no reversing, comfortable acceleration and jerk.
DEFAULT_BOUNDS = Bounds(
    state={"v [m/s]": (0.0, 30.0), "a [m/s^2]": (-4.0, 3.0)},
    control={"j [m/s^3]": (-8.0, 8.0)},
)


def smooth_desired_speed(kappa: np.ndarray, a_lat: float = DEFAULT_A_LAT, v_max: float = DEFAULT_V_MAX):
    """v_des(kappa) and its first two derivatives in kappa (see module doc).

    Returns
    -------
    v, dv_dkappa, d2v_dkappa2 : arrays shaped like kappa [m/s, m^2/s, m^3/s]
    """
    k = np.asarray(kappa, dtype=float)
    a4 = a_lat**4
    F = (k**2 / a_lat**2) ** 2 + v_max**-8.0
    v = F ** (-1.0 / 8.0)
    F98 = F ** (-9.0 / 8.0)
    dv = -(k**3 / (2.0 * a4)) * F98
    d2v = -(3.0 * k**2 / (2.0 * a4)) * F98 + (9.0 / 4.0) * (k**6 / a4**2) * F ** (-17.0 / 8.0)
    return v, dv, d2v


@dataclass(frozen=True, eq=False)
class CompositePath:
    """Several reference paths laid end to end on one arc-length axis, separated by straight gaps.

    Recorded scenes have one path per route, but a learner works with one driver model. Putting path k at
    ``s`` in ``[offset_k, offset_k + length_k]`` lets one speed profile and one model serve every route: a
    trajectory on path k carries arc lengths shifted by ``offset_k``. Between paths lies a gap of ``gap``
    metres of zero curvature (the desired speed there is the speed limit), which is also what a prediction
    running past the end of its path sees (the straight-line extension of `ReferencePath`).

    Each gap is split at its middle: its first half belongs to the path before it (a track or prediction
    running past that path's end), its second half to the path after it (a track that starts before its
    path's first point, at a negative local arc length). Path k thus owns composite arc lengths
    ``[offset_k - gap/2, offset_k + length_k + gap/2)`` (the first path everything below, the last everything
    above), and a point there is placed on path k, extrapolated straight beyond its ends.

    Parameters
    ----------
    segments : tuple of ReferencePath (open paths)
    gap : float  [m], more than twice as long as any track or prediction runs beyond a path's ends
    """

    segments: tuple
    gap: float = 300.0
    spacing: float = 0.5

    def __post_init__(self) -> None:
        segs = tuple(self.segments)
        if not segs:
            raise ValueError("a CompositePath needs at least one ReferencePath")
        for i, p in enumerate(segs):
            if not isinstance(p, ReferencePath):
                raise TypeError(f"segment {i} is a {type(p).__name__}, expected a ReferencePath")
            if p.closed:
                raise ValueError(f"segment {i} is a closed path; only open paths can be laid end to end")
        if not np.isfinite(self.gap) or self.gap <= 0:
            raise ValueError(f"gap must be > 0 m, got {self.gap!r}")
        lengths = np.array([p.length for p in segs])
        offsets = np.concatenate([[0.0], np.cumsum(lengths + self.gap)[:-1]])
        s_parts, k_parts = [], []
        for p, off in zip(segs, offsets):
            s_parts.append(p.s + off)
            k_parts.append(p.kappa)
            gap_s = np.linspace(off + p.length, off + p.length + self.gap, 4)[1:]
            s_parts.append(gap_s)
            k_parts.append(np.zeros_like(gap_s))
        s_tab = np.concatenate(s_parts)
        keep = np.concatenate([[True], np.diff(s_tab) > 1e-9])
        object.__setattr__(self, "segments", segs)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "s", s_tab[keep])
        object.__setattr__(self, "kappa", np.concatenate(k_parts)[keep])

    closed = False

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def segment_of(self, s: np.ndarray) -> np.ndarray:
        """Index of the path that composite arc length s [m] belongs to: the path whose range, extended by
        half a gap at either end, holds s (see class doc)."""
        starts = self.offsets - 0.5 * self.gap  # where each path's share of the gap before it begins
        return np.clip(np.searchsorted(starts, np.asarray(s, dtype=float), side="right") - 1, 0, None)

    def local_range(self, segment: int) -> tuple[float, float]:
        """Local arc lengths [m] of path ``segment`` that `segment_of` maps back to it: (low, high), the
        path's own [0, length] extended by half a gap at either end (unbounded at the composite's ends)."""
        k = int(segment)
        if not 0 <= k < len(self.segments):
            raise IndexError(f"segment {k} out of range for {len(self.segments)} paths")
        low = -np.inf if k == 0 else -0.5 * self.gap
        high = np.inf if k == len(self.segments) - 1 else self.segments[k].length + 0.5 * self.gap
        return float(low), float(high)

    def to_cartesian(self, s, d, *, extrapolate: bool = True, segment=None) -> np.ndarray:
        """Point at composite arc length s [m] and lateral offset d [m], shape (..., 2).

        ``segment`` (int or int array broadcastable to s), when given, names the path to place each point
        on instead of `segment_of` (s): a point beyond that path's ends is extrapolated straight."""
        s = np.asarray(s, dtype=float)
        d = np.broadcast_to(np.asarray(d, dtype=float), s.shape)
        out = np.empty(s.shape + (2,))
        if segment is None:
            seg = self.segment_of(s)
        else:
            seg = np.broadcast_to(np.asarray(segment), s.shape)
            n_seg = len(self.segments)
            if not np.issubdtype(seg.dtype, np.integer) or (seg.size and not 0 <= seg.min() <= seg.max() < n_seg):
                raise ValueError(f"segment must be integer path indices in [0, {n_seg}), got {segment!r}")
        for k in np.unique(seg):
            sel = seg == k
            out[sel] = self.segments[k].to_cartesian(s[sel] - self.offsets[k], d[sel], extrapolate=True)
        return out


@dataclass(frozen=True, eq=False)
class SpeedProfile:
    """The desired speed along a path, v_des(s), with exact first and second derivatives in s.

    Parameters
    ----------
    path : ReferencePath or CompositePath
    a_lat : float   comfortable lateral acceleration [m/s^2] (the paper's 1.8)
    v_max : float   speed limit [m/s]
    """

    path: ReferencePath
    a_lat: float = DEFAULT_A_LAT
    v_max: float = DEFAULT_V_MAX
    _spline: CubicSpline = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.path, (ReferencePath, CompositePath)):
            raise TypeError(f"path must be a ReferencePath or CompositePath, got {type(self.path).__name__}")
        for name in ("a_lat", "v_max"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be > 0, got {v!r}")
        s, kappa = self.path.s, self.path.kappa
        if self.path.closed:
            kappa = kappa.copy()
            kappa[-1] = kappa[0]
            spline = CubicSpline(s, kappa, bc_type="periodic")
        else:
            spline = CubicSpline(s, kappa, bc_type="not-a-knot")
        object.__setattr__(self, "_spline", spline)

    def curvature(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """kappa(s), dkappa/ds, d2kappa/ds2 (zero slope beyond the ends of an open path)."""
        s = np.asarray(s, dtype=float)
        L = self.path.length
        if self.path.closed:
            q = np.mod(s, L)
            return self._spline(q), self._spline(q, 1), self._spline(q, 2)
        q = np.clip(s, 0.0, L)
        inside = (s >= 0.0) & (s <= L)
        return self._spline(q), np.where(inside, self._spline(q, 1), 0.0), np.where(inside, self._spline(q, 2), 0.0)

    def __call__(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """v_des(s), dv_des/ds, d2v_des/ds2."""
        k, dk, d2k = self.curvature(s)
        v, dv, d2v = smooth_desired_speed(k, self.a_lat, self.v_max)
        return v, dv * dk, d2v * dk**2 + dv * d2k


def speed_deviation_feature(profile: SpeedProfile, name: str = "speed_dev", reduction: str = "mean") -> Feature:
    """mean_k (v_k - v_des(s_k))^2 with exact derivatives through the speed profile."""

    def residual(x: np.ndarray, u: np.ndarray) -> Residual:
        s, v = x[..., 0], x[..., 1]
        vd, dvd, d2vd = profile(s)
        jx = np.zeros(x.shape[:2] + (1, x.shape[-1]))
        jx[..., 0, 0] = -dvd
        jx[..., 0, 1] = 1.0
        hx = np.zeros(x.shape[:2] + (1, x.shape[-1], x.shape[-1]))
        hx[..., 0, 0, 0] = -d2vd
        return Residual((v - vd)[..., None], jx, np.zeros((1, 1, 1, u.shape[-1])), hx)

    return Feature(name, residual, reduction=reduction, quadratic=False)


def roundabout_features(profile: SpeedProfile) -> FeatureSet:
    """The paper's features (speed_dev, acc_sq, jerk_sq), means over the steps; reference: jerk_sq."""
    return FeatureSet(
        (
            speed_deviation_feature(profile),
            squared_state("acc_sq", [2], reduction="mean"),
            squared_control("jerk_sq", reduction="mean"),
        ),
        reference="jerk_sq",
    )


@dataclass(frozen=True)
class PathDriverModel(DriverModel):
    """A `DriverModel` along a reference path: predictions by `SequentialMPC`, positions in Cartesian metres.

    Parameters
    ----------
    path : ReferencePath
    n_iter : int   Gauss-Newton iterations of the MPC
    """

    path: ReferencePath | CompositePath | None = None
    n_iter: int = 10

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.path, (ReferencePath, CompositePath)):
            raise TypeError(f"path must be a ReferencePath or CompositePath, got {type(self.path).__name__}")

    def predictor(self):
        if "seq" not in self._predictors:
            self._predictors["seq"] = SequentialMPC(self.dynamics, self.features, self.bounds, n_iter=self.n_iter)
        return self._predictors["seq"]

    def predict_states(self, x0: np.ndarray, theta: np.ndarray, horizon: int) -> np.ndarray:
        """As `DriverModel.predict_states`, after making start states physical: a start estimated from noisy
        data with v < 0 is a stopped car (v = 0), and a stopped car does not decelerate further (a >= 0)."""
        x0 = np.array(np.atleast_2d(x0), dtype=float)
        stopped = x0[:, 1] <= 0.0
        x0[stopped, 1] = 0.0
        x0[stopped, 2] = np.maximum(x0[stopped, 2], 0.0)
        return super().predict_states(x0, theta, horizon)

    def positions(self, states: np.ndarray, offset: np.ndarray | float = 0.0) -> np.ndarray:
        """Cartesian positions (..., 2) [m] of states (..., n_x) at lateral offset d [m] from the path."""
        s = np.asarray(states)[..., 0]
        return self.path.to_cartesian(s, np.broadcast_to(offset, s.shape), extrapolate=True)


def roundabout_model(
    path: ReferencePath | CompositePath,
    *,
    dt: float = 0.2,
    a_lat: float = DEFAULT_A_LAT,
    v_max: float = DEFAULT_V_MAX,
    bounds: Bounds | None = DEFAULT_BOUNDS,
) -> PathDriverModel:
    """The paper's roundabout model on a path: longitudinal dynamics at ``dt``, the three features, bounds."""
    dyn: LinearDynamics = longitudinal(dt)
    return PathDriverModel(dyn, roundabout_features(SpeedProfile(path, a_lat, v_max)), bounds, path=path)


def fit_longitudinal_states(
    s_obs: np.ndarray, dynamics: LinearDynamics, *, jerk_weight: float = 1e-2
) -> tuple[np.ndarray, np.ndarray]:
    """States and controls that best explain observed path positions, by least squares through the dynamics.

    Solves ``min_{x0, U} sum_k (s_k(x0, U) - s_obs_k)^2 + jerk_weight * sum_k u_k^2`` (ridge on the
    controls only), so speed and acceleration come out consistent with the dynamics instead of from noisy
    finite differences — the start state of a prediction should be the last state of this fit.

    Parameters
    ----------
    s_obs : array (n,)   observed arc lengths [m] at the model's dt, n >= 2
    dynamics : LinearDynamics with the position as state 0
    jerk_weight : float  [m^2 / (m/s^3)^2], > 0

    Returns
    -------
    states : array (n, n_x), controls : array (n - 1, n_u)
    """
    s_obs = np.asarray(s_obs, dtype=float)
    if s_obs.ndim != 1 or s_obs.size < 2:
        raise ValueError(f"s_obs must be a 1-D array of at least 2 positions, got shape {s_obs.shape}")
    if not np.all(np.isfinite(s_obs)):
        raise ValueError("s_obs contains non-finite values")
    if not np.isfinite(jerk_weight) or jerk_weight <= 0:
        raise ValueError(f"jerk_weight must be > 0, got {jerk_weight!r}")
    n = s_obs.size - 1
    phi, gamma = dynamics.condensed(n)
    n_x, n_u = dynamics.n_x, dynamics.n_u
    # s_k = e0 . x_k for k = 0..n as a linear map of z = (x0, U)
    rows = np.zeros((n + 1, n_x + n * n_u))
    rows[0, :n_x] = np.eye(n_x)[0]
    rows[1:, :n_x] = phi[:, 0, :]
    rows[1:, n_x:] = gamma[:, 0, :, :].reshape(n, n * n_u)
    reg = np.zeros(n_x + n * n_u)
    reg[n_x:] = jerk_weight
    z = np.linalg.solve(rows.T @ rows + np.diag(reg), rows.T @ s_obs)
    x0, U = z[:n_x], z[n_x:].reshape(n, n_u)
    return dynamics.rollout(x0, U), U
