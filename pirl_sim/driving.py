"""The roundabout driver model of the paper: longitudinal motion along a reference path, three features.

State (s [m], v [m/s], a [m/s^2]) along a `ReferencePath`, control jerk [m/s^3] (`dynamics.longitudinal`).
Features (means over the N steps, as in the paper): ``speed_dev`` = (v - v_des(s))^2, ``acc_sq`` = a^2 and
``jerk_sq`` = j^2 (the reference feature: reported weights are relative to it).

The desired speed is the lateral-acceleration limit ``sqrt(a_lat / |kappa|)`` capped smoothly by ``v_max``,
``v_des = (kappa^4 / a_lat^4 + v_max^-8)^(-1/8)`` (`smooth_desired_speed`), infinitely differentiable so that the
features have exact gradients and Hessians; curvature along s is a cubic spline through the path's tabulated
kappa (`SpeedProfile`). The model is explained in the documentation's "The cost model and its features" page.
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
    "physical_starts",
    "CompositePath",
    "smooth_desired_speed",
    "desired_speed_along",
    "SpeedProfile",
    "SpeedDeviationResidual",
    "roundabout_features",
    "SpeedTargetResidual",
    "HeadwayResidual",
    "FEATURE_SETS",
    "PathDriverModel",
    "roundabout_model",
    "fit_longitudinal_states",
    "estimate_longitudinal_states",
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


def desired_speed_along(k, dk, d2k, a_lat: float, v_max: float):
    """v_des [m/s] and its first two derivatives in arc length [1/s, 1/(m s)] from the curvature k [1/m] and its
    derivatives dk [1/m^2], d2k [1/m^3] along the path (arrays of one shape): `smooth_desired_speed` chained
    through kappa(s), with one fractional power (F^-9/8 = v / F, F^-17/8 = v / F^2), equal to it to rounding."""
    inv_a4 = 1.0 / a_lat**4
    k2 = k * k
    k3 = k2 * k
    F = k2 * k2 * inv_a4 + v_max**-8.0
    v = np.power(F, -0.125)
    F98 = v / F
    dv = -0.5 * inv_a4 * k3 * F98
    d2v = -1.5 * inv_a4 * k2 * F98 + 2.25 * inv_a4 * inv_a4 * (k3 * k3) * (F98 / F)
    return v, dv * dk, d2v * (dk * dk) + dv * d2k


@dataclass(frozen=True, eq=False)
class CompositePath:
    """Several reference paths laid end to end on one arc-length axis, separated by straight gaps.

    Path k lies at ``s`` in ``[offset_k, offset_k + length_k]``, so one speed profile and one model serve every
    route; each gap is split at its middle between the paths either side ("The cost model and its features" page).

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
        return float(self.s[-1])  # type: ignore[attr-defined]

    def segment_of(self, s: np.ndarray) -> np.ndarray:
        """Index of the path that composite arc length s [m] belongs to: the path whose range, extended by
        half a gap at either end, holds s (see class doc)."""
        # where each path's share of the gap before it begins
        starts = self.offsets - 0.5 * self.gap  # type: ignore[attr-defined]
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
            out[sel] = self.segments[k].to_cartesian(s[sel] - self.offsets[k], d[sel],  # type: ignore[attr-defined]
                                                     extrapolate=True)
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

    def _pieces(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The spline's cubic pieces at arc lengths s [m] (any shape), from one interval search.

        Returns the cubic's coefficients c0..c3 of each point's interval (highest power first) and the offset
        t [m] into it, so that kappa = ((c0 t + c1) t + c2) t + c3. Closed paths wrap s; open paths clip it
        to [0, length] (the caller zeroes the slopes beyond the ends)."""
        L = self.path.length
        q = np.mod(s, L) if self.path.closed else np.clip(s, 0.0, L)
        knots, coef = self._spline.x, self._spline.c
        i = np.clip(np.searchsorted(knots, q, side="right") - 1, 0, coef.shape[1] - 1)
        return coef[0, i], coef[1, i], coef[2, i], coef[3, i], q - knots[i]

    def curvature(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """kappa(s) [1/m], dkappa/ds [1/m^2], d2kappa/ds2 [1/m^3] at arc lengths s [m] (any shape; zero slope
        beyond the ends of an open path). The spline and its two derivatives from one interval search (the
        same piecewise cubic as ``scipy.interpolate.CubicSpline``, equal to rounding)."""
        s = np.asarray(s, dtype=float)
        c0, c1, c2, c3, t = self._pieces(s)
        k = ((c0 * t + c1) * t + c2) * t + c3
        dk = (3.0 * c0 * t + 2.0 * c1) * t + c2
        d2k = 6.0 * c0 * t + 2.0 * c1
        if not self.path.closed:
            outside = (s < 0.0) | (s > self.path.length)
            if outside.any():
                dk, d2k = np.where(outside, 0.0, dk), np.where(outside, 0.0, d2k)
        return k, dk, d2k

    def value(self, s: np.ndarray) -> np.ndarray:
        """v_des(s) [m/s] only, at arc lengths s [m] (any shape): what a cost evaluation needs."""
        c0, c1, c2, c3, t = self._pieces(np.asarray(s, dtype=float))
        k = ((c0 * t + c1) * t + c2) * t + c3
        k2 = k * k
        return np.power(k2 * k2 * (1.0 / self.a_lat**4) + self.v_max**-8.0, -0.125)

    def __call__(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """v_des(s) [m/s], dv_des/ds [1/s], d2v_des/ds2 [1/(m s)] at arc lengths s [m] (any shape).

        `desired_speed_along` of the curvature."""
        return desired_speed_along(*self.curvature(s), self.a_lat, self.v_max)


@dataclass(frozen=True, eq=False)
class SpeedDeviationResidual:
    """Residual ``v_k - v_des(s_k)`` of `speed_deviation_feature`, with its exact derivatives through the speed
    profile (a module-level callable, not a closure, so that models and fitted learners pickle).

    Parameters
    ----------
    profile : SpeedProfile
    """

    profile: SpeedProfile

    def __post_init__(self) -> None:
        if not callable(self.profile):  # a SpeedProfile, or another callable s -> (v_des, dv_des/ds, d2v_des/ds2)
            raise TypeError(f"profile must be a SpeedProfile (or a callable like it), got {type(self.profile).__name__}")

    def __call__(self, x: np.ndarray, u: np.ndarray) -> Residual:
        s, v = x[..., 0], x[..., 1]
        vd, dvd, d2vd = self.profile(s)
        jx = np.zeros(x.shape[:2] + (1, x.shape[-1]))
        jx[..., 0, 0] = -dvd
        jx[..., 0, 1] = 1.0
        hx = np.zeros(x.shape[:2] + (1, x.shape[-1], x.shape[-1]))
        hx[..., 0, 0, 0] = -d2vd
        return Residual((v - vd)[..., None], jx, np.zeros((1, 1, 1, u.shape[-1])), hx, x_support=(0, 1))

    def value(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The residual r (M, N, 1) [m/s] alone, without derivatives (`pirl_sim.features.FeatureSet.values`)."""
        value = getattr(self.profile, "value", None)
        vd = value(x[..., 0]) if value is not None else self.profile(x[..., 0])[0]
        return (x[..., 1] - vd)[..., None]


def speed_deviation_feature(profile: SpeedProfile, name: str = "speed_dev", reduction: str = "mean") -> Feature:
    """mean_k (v_k - v_des(s_k))^2 with exact derivatives through the speed profile."""
    return Feature(name, SpeedDeviationResidual(profile), reduction=reduction,  # type: ignore[arg-type]
                   quadratic=False)


@dataclass(frozen=True)
class SpeedTargetResidual:
    """Residual ``v_k - v_target`` for a constant target speed [m/s] (feature ``speed_hi``)."""

    v_target: float

    def __post_init__(self) -> None:
        if isinstance(self.v_target, bool) or not np.isfinite(self.v_target) or self.v_target <= 0:
            raise ValueError(f"v_target must be a finite speed > 0 m/s, got {self.v_target!r}")

    def __call__(self, x: np.ndarray, u: np.ndarray) -> Residual:
        jx = np.zeros((1, 1, 1, x.shape[-1]))
        jx[..., 0, 1] = 1.0
        return Residual((x[..., 1] - self.v_target)[..., None], jx, np.zeros((1, 1, 1, u.shape[-1])))


@dataclass(frozen=True)
class HeadwayResidual:
    """Residual of the ``headway`` feature: how far the gap to the vehicle ahead is below a safe gap,
    ``r = w softplus((d_0 + T v - g) / w)`` [m] (about 0 beyond the safe gap, linear below it, smooth in
    between); states of `pirl_sim.dynamics.following` (v at index 1, gap g at ``gap_index``: 3 for the vehicle
    ahead, 5 for the obstacle a car yields to).

    Parameters
    ----------
    standstill : float [m]   d_0, safe gap at standstill
    time_gap : float [s]     T, safe time gap
    softness : float [m]     w, width of the smooth corner
    gap_index : int          the state entry of the gap
    """

    standstill: float = 2.0
    time_gap: float = 1.0
    softness: float = 1.0
    gap_index: int = 3

    def __post_init__(self) -> None:
        for name in ("standstill", "time_gap", "softness"):
            v = getattr(self, name)
            if isinstance(v, bool) or not np.isfinite(v) or v < 0 or (name == "softness" and v == 0):
                raise ValueError(f"{name} must be a finite number {'> 0' if name == 'softness' else '>= 0'}, got {v!r}")
        if self.gap_index not in (3, 5):
            raise ValueError(f"gap_index must be 3 (the vehicle ahead) or 5 (the obstacle yielded to), got "
                             f"{self.gap_index!r}")

    def __call__(self, x: np.ndarray, u: np.ndarray) -> Residual:
        g = self.gap_index
        if x.shape[-1] < g + 2:
            raise ValueError(f"the headway feature needs states of pirl_sim.dynamics.following (s, v, a, g, v_L"
                             f"{', g_y, v_y' if g == 5 else ''}), got {x.shape[-1]} state entries")
        w = self.softness
        z = (self.standstill + self.time_gap * x[..., 1] - x[..., g]) / w
        r = w * np.logaddexp(0.0, z)
        sig = 0.5 * (1.0 + np.tanh(0.5 * z))  # d r / d z / w, overflow-free
        dz = np.zeros(x.shape[-1])
        dz[1], dz[g] = self.time_gap / w, -1.0 / w
        jx = (w * sig)[..., None, None] * dz  # (M, N, 1, n_x)
        # the second derivative w sig (1 - sig) dz dz^T = (1 - sig) / (w sig) jx^T jx (where sig underflows to 0,
        # both are 0): given as that scale, never as an (M, N, 1, n_x, n_x) array
        along = np.divide(1.0 - sig, w * sig, out=np.zeros_like(sig), where=sig > 0.0)
        return Residual(r[..., None], jx, np.zeros((1, 1, 1, u.shape[-1])), hess_scale=along[..., None],
                        x_support=(1, g))


#: target speed of the ``speed_hi`` feature [m/s] (72 km/h: above the speed of every roundabout)
SPEED_HI = 20.0
#: feature sets of `roundabout_features`
FEATURE_SETS = ("paper", "speed-level", "following", "interacting")


def roundabout_features(profile: SpeedProfile, kind: str = "paper") -> FeatureSet:
    """The paper's features (speed_dev, acc_sq, jerk_sq), means over the steps; reference: jerk_sq.

    ``kind="speed-level"`` adds two quadratic features that let each driver keep a speed level of their own
    relative to the map's desired speed: ``speed_sq`` = mean v^2 (pulls towards standing still) and
    ``speed_hi`` = mean (v - `SPEED_HI`)^2 (pulls up). With weights w (speed_dev), w_0, w_hi the preferred
    speed is (w v_des(s) + w_hi v_hi) / (w + w_0 + w_hi): a driver-specific blend that still follows the
    curvature through v_des.

    ``kind="following"`` adds to those ``headway`` (`HeadwayResidual`): the squared shortfall of the gap to the
    vehicle ahead below 2 m + 1 s x v; it needs the states of `pirl_sim.dynamics.following`.

    ``kind="interacting"`` is the paper's three, ``headway`` and ``yielding``: the cost of the simulated drivers
    who interact (`pirl_sim.scenarios.drivers`), with the states of `pirl_sim.dynamics.following` with two
    obstacles; ``yielding`` is ``headway``'s residual on the standing obstacle before a conflict point
    (`pirl_sim.scenarios.yielding`).
    """
    if kind not in FEATURE_SETS:
        raise ValueError(f"feature set must be one of {FEATURE_SETS}, got {kind!r}")
    feats = [
        speed_deviation_feature(profile),
        squared_state("acc_sq", [2], reduction="mean"),
        squared_control("jerk_sq", reduction="mean"),
    ]
    if kind in ("speed-level", "following"):
        feats += [squared_state("speed_sq", [1], reduction="mean"),
                  Feature("speed_hi", SpeedTargetResidual(SPEED_HI), reduction="mean", quadratic=True)]
    if kind in ("following", "interacting"):
        feats.append(Feature("headway", HeadwayResidual(), reduction="mean", quadratic=False))
    if kind == "interacting":
        feats.append(Feature("yielding", HeadwayResidual(gap_index=5), reduction="mean", quadratic=False))
    return FeatureSet(tuple(feats), reference="jerk_sq")


def physical_starts(x0: np.ndarray) -> np.ndarray:
    """Start states (s, v, a) (M, 3) made physical, as a copy: a start estimated from noisy data with v < 0 is a
    stopped car (v = 0), and a stopped car does not decelerate further (a >= 0)."""
    x0 = np.array(np.atleast_2d(x0), dtype=float)
    stopped = x0[:, 1] <= 0.0
    x0[stopped, 1] = 0.0
    x0[stopped, 2] = np.maximum(x0[stopped, 2], 0.0)
    return x0


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
        """As `DriverModel.predict_states`, from `physical_starts` (x0)."""
        return super().predict_states(physical_starts(x0), theta, horizon)

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """|kappa| [1/m] that the desired speed sees at arc lengths s [m] (any shape): the curvature of the
        ``speed_dev`` feature's `SpeedProfile` (e.g. to look drivers up by the road ahead,
        `pirl_sim.learners.PIRLKNN` ``lookup_ahead``).

        Raises
        ------
        ValueError
            A model without a ``speed_dev`` feature on a `SpeedProfile`.
        """
        for feature in self.features.features:
            profile = getattr(feature.residual, "profile", None)
            if feature.name == "speed_dev" and isinstance(profile, SpeedProfile):
                return np.abs(profile.curvature(np.asarray(s, dtype=float))[0])
        raise ValueError(f"this model has no speed_dev feature on a SpeedProfile (features {self.features.names}), "
                         "so no curvature ahead")

    def positions(self, states: np.ndarray, offset: np.ndarray | float = 0.0) -> np.ndarray:
        """Cartesian positions (..., 2) [m] of states (..., n_x) at lateral offset d [m] from the path."""
        s = np.asarray(states)[..., 0]
        return self.path.to_cartesian(s, np.broadcast_to(offset, s.shape), extrapolate=True)  # type: ignore[union-attr]


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
    return PathDriverModel(dyn, roundabout_features(SpeedProfile(path, a_lat, v_max)),  # type: ignore[arg-type]
                           bounds, path=path)


def fit_longitudinal_states(
    s_obs: np.ndarray, dynamics: LinearDynamics, *, jerk_weight: float = 1e-2
) -> tuple[np.ndarray, np.ndarray]:
    """States and controls that best explain observed path positions, by least squares through the dynamics.

    Solves ``min_{x0, U} sum_k (s_k(x0, U) - s_obs_k)^2 + jerk_weight * sum_k u_k^2``: `estimate_longitudinal_states`
    from positions only, with ``sigma_j = sigma_s / sqrt(jerk_weight)``.

    Parameters
    ----------
    s_obs : array (n,)   observed arc lengths [m] at the model's dt, n >= 2
    dynamics : LinearDynamics with the position as state 0
    jerk_weight : float  [m^2 / (m/s^3)^2], > 0

    Returns
    -------
    states : array (n, n_x), controls : array (n - 1, n_u)
    """
    s_obs = _observations("s_obs", s_obs)
    if not np.isfinite(jerk_weight) or jerk_weight <= 0:
        raise ValueError(f"jerk_weight must be > 0, got {jerk_weight!r}")
    return _fit_through_dynamics(dynamics, [(0, s_obs, 1.0)], float(jerk_weight))


#: Default noise model of :func:`estimate_longitudinal_states` (chosen by measurement, see there).
ESTIMATE_SIGMA_S = 0.1  # [m]
ESTIMATE_SIGMA_V = 0.001  # [m/s]
ESTIMATE_SIGMA_J = 3.0  # [m/s^3]
ESTIMATE_SIGMA_A = 0.01  # [m/s^2]


def estimate_longitudinal_states(
    s_obs: np.ndarray,
    dynamics: LinearDynamics,
    *,
    v_obs: np.ndarray | None = None,
    sigma_s: float = ESTIMATE_SIGMA_S,
    sigma_v: float = ESTIMATE_SIGMA_V,
    sigma_j: float = ESTIMATE_SIGMA_J,
    a_obs: np.ndarray | None = None,
    sigma_a: float = ESTIMATE_SIGMA_A,
    step_mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """States and controls (x0, U) through the dynamics that best explain observed positions and speeds: one least
    squares ("The cost model and its features" page, The state estimate); without ``v_obs``, `fit_longitudinal_states`.

    Parameters
    ----------
    s_obs, v_obs : array (n,)        observed arc lengths [m] at the model's dt (n >= 2); speeds [m/s] (optional)
    dynamics : LinearDynamics        position as state 0, speed as state 1 (e.g. `pirl_sim.dynamics.longitudinal`)
    sigma_s, sigma_v, sigma_j, sigma_a : float   noise of s and v, jerk prior, noise of a [m, m/s, m/s^3, m/s^2], > 0
    a_obs : array (n,), optional     observed accelerations [m/s^2], NaN where not observed
    step_mask : array (n - 1,) of bool, optional   steps across which the dynamics hold (default all)

    Returns
    -------
    states, controls : array (n, n_x), (n - 1, n_u)   [m, m/s, m/s^2], [m/s^3]; ValueError for bad inputs
    """
    s_obs = _observations("s_obs", s_obs)
    if v_obs is not None:
        v_obs = _observations("v_obs", v_obs)
        if v_obs.shape != s_obs.shape:
            raise ValueError(f"v_obs must have one speed per position: got {v_obs.shape[0]} speeds for "
                             f"{s_obs.shape[0]} positions")
        if dynamics.n_x < 2:
            raise ValueError(f"v_obs needs the speed as state 1, but the dynamics have {dynamics.n_x} state(s)")
    if a_obs is not None:
        a_obs = np.asarray(a_obs, dtype=float)
        if a_obs.shape != s_obs.shape:
            raise ValueError(f"a_obs must have one value (or NaN) per position: got shape {a_obs.shape} for "
                             f"{s_obs.shape[0]} positions")
        if np.isinf(a_obs).any():
            raise ValueError(f"a_obs contains infinite values (at index {int(np.argmax(np.isinf(a_obs)))}); "
                             "NaN marks an unobserved acceleration")
        if dynamics.n_x < 3:
            raise ValueError(f"a_obs needs the acceleration as state 2, but the dynamics have {dynamics.n_x} "
                             "state(s)")
    for name, value in (("sigma_s", sigma_s), ("sigma_v", sigma_v), ("sigma_j", sigma_j), ("sigma_a", sigma_a)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not np.isfinite(value) or value <= 0:
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    obs = [(0, s_obs, float(sigma_s) ** -2)]
    if v_obs is not None:
        obs.append((1, v_obs, float(sigma_v) ** -2))
    if a_obs is not None and np.isfinite(a_obs).any():
        obs.append((2, a_obs, float(sigma_a) ** -2))
    w_u = float(sigma_j) ** -2
    n = s_obs.size
    mask = np.ones(n - 1, dtype=bool) if step_mask is None else np.asarray(step_mask)
    if mask.shape != (n - 1,) or mask.dtype != bool:
        raise ValueError(f"step_mask must be a boolean array of shape ({n - 1},) (one per step), got "
                         f"{mask.dtype} {mask.shape}")
    if mask.all():
        return _fit_through_dynamics(dynamics, obs, w_u)
    states, _ = _fit_through_dynamics(dynamics, obs, w_u)  # for frames that no run can determine alone
    states = states.copy()
    controls = np.empty((n - 1, dynamics.n_u))
    padded = np.concatenate([[False], mask, [False]])
    starts = np.flatnonzero(~padded[:-1] & padded[1:])  # run i: steps starts[i] .. stops[i] - 1 all True,
    stops = np.flatnonzero(padded[:-1] & ~padded[1:])  # frames starts[i] .. stops[i]
    for a, b in zip(starts, stops):
        part = [(i, values[a:b + 1], w) for i, values, w in obs]
        n_obs = sum(int(np.isfinite(values).sum()) for _, values, _ in part)
        if n_obs < dynamics.n_x:  # x0 not determined by this run alone (e.g. one step, positions only)
            controls[a:b] = _carry(dynamics, states[a:b + 1])
            continue
        states[a:b + 1], controls[a:b] = _fit_through_dynamics(dynamics, part, w_u)
    broken = np.flatnonzero(~mask)
    controls[broken] = _carry(dynamics, np.stack([states[broken], states[broken + 1]], axis=1))
    return states, controls


def _carry(dynamics: LinearDynamics, pairs: np.ndarray) -> np.ndarray:
    """The controls (k, n_u) that carry the last state component (the acceleration) from x_k to x_{k+1};
    ``pairs`` (k, 2, n_x), or a run of states (k + 1, n_x)."""
    if pairs.ndim == 2:
        pairs = np.stack([pairs[:-1], pairs[1:]], axis=1)
    B_last = dynamics.B[-1]
    gap = pairs[:, 1, -1] - pairs[:, 0] @ dynamics.A[-1]
    return np.outer(gap, B_last) / float(B_last @ B_last)


def _observations(name: str, values) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1 or arr.size < 2:
        raise ValueError(f"{name} must be a 1-D array of at least 2 values, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        k = int(np.argmax(~np.isfinite(arr)))
        raise ValueError(f"{name} contains non-finite values ({float(arr[k])!r} at index {k})")
    return arr


def _fit_through_dynamics(dynamics: LinearDynamics, obs, w_u: float) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares for z = (x0, U): ``obs`` is a list of (state index, values (n,) with NaN where
    not observed, weight); ridge ``w_u`` on U."""
    n = obs[0][1].size - 1
    phi, gamma = dynamics.condensed(n)
    n_x, n_u = dynamics.n_x, dynamics.n_u
    lhs = np.zeros((n_x + n * n_u, n_x + n * n_u))
    rhs = np.zeros(n_x + n * n_u)
    for i, values, w in obs:  # state i at k = 0..n as a linear map of z = (x0, U)
        rows = np.zeros((n + 1, n_x + n * n_u))
        rows[0, :n_x] = np.eye(n_x)[i]
        rows[1:, :n_x] = phi[:, i, :]
        rows[1:, n_x:] = gamma[:, i, :, :].reshape(n, n * n_u)
        seen = np.isfinite(values)
        if not seen.all():
            rows, values = rows[seen], values[seen]
        if w == 1.0:  # the position-only fit exactly as it always was
            lhs += rows.T @ rows
            rhs += rows.T @ values
        else:
            lhs += w * (rows.T @ rows)
            rhs += w * (rows.T @ values)
    lhs[n_x:, n_x:] += w_u * np.eye(n * n_u)
    z = np.linalg.solve(lhs, rhs)
    x0, U = z[:n_x], z[n_x:].reshape(n, n_u)
    return dynamics.rollout(x0, U), U
