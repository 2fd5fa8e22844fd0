"""Driving styles as a mixture over weights, and demonstrations drawn from them.

A `Population` is a mixture of named `Style` s; each style is a Gaussian over the normalised weights (reference
feature = 1), truncated to positive values by redrawing. Demonstrations are either noise-free optimal (the
paper's LQR data) or Boltzmann-rational: for quadratic features P(U) ∝ exp(-beta theta . f(U)) is exactly the
Gaussian N(-A^-1 b, A^-1) with A, b the quadratic form of beta theta . f (`pirl_sim.mpc.QuadraticCost`), so
demonstrations come from the true MaxEnt model and weight recovery is well posed. For features that are not
quadratic (the roundabout's desired speed depends on position) the Gaussian is the Laplace approximation at the
optimum, N(U*, H(U*)^-1), and an independence Metropolis-Hastings chain with that Gaussian as proposal corrects
it to the exact density (`sample_boltzmann_controls` reports the acceptance rate; it is 1 for quadratic costs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
import scipy.linalg

from .features import FeatureSet
from .irl import shift_to_pd
from .model import DriverModel
from .mpc import LQPredictor, SequentialMPC
from .trajectory import Trajectory
from .validation import is_positive_int

__all__ = ["Style", "Population", "optimal_controls", "sample_boltzmann_controls", "generate_demonstrations"]

_MAX_REDRAWS = 1000
#: largest style mixture weight, mean weight and std: beyond, sums and the drivers' costs overflow
STYLE_VALUE_MAX = 1e6


@dataclass(frozen=True)
class Style:
    """One driving style: a Gaussian over normalised weights, by feature name.

    Parameters
    ----------
    name : str
    weight : float
        Mixture weight (> 0; the population normalises them).
    mean : mapping {feature name: weight}
        Mean normalised weights; the reference feature must be 1 (or omitted).
    std : mapping {feature name: std}, optional
        Independent standard deviations (0 where omitted).
    cov : array (K, K), optional
        Full covariance in feature order instead of ``std`` (positive semi-definite).
    """

    name: str
    weight: float
    mean: Mapping[str, float]
    std: Mapping[str, float] = field(default_factory=dict)
    cov: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"style name must be a non-empty string, got {self.name!r}")
        if not np.isfinite(self.weight) or self.weight <= 0:
            raise ValueError(f"style {self.name!r}: weight must be > 0, got {self.weight!r}")
        if self.weight > STYLE_VALUE_MAX:
            raise ValueError(f"style {self.name!r}: weight must be in (0, {STYLE_VALUE_MAX:g}], got {self.weight!r}")
        if self.cov is not None and self.std:
            raise ValueError(f"style {self.name!r}: give std or cov, not both")
        for k, v in self.std.items():
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"style {self.name!r}: std of {k!r} must be >= 0, got {v!r}")
            if v > STYLE_VALUE_MAX:
                raise ValueError(f"style {self.name!r}: std of {k!r} must be in [0, {STYLE_VALUE_MAX:g}], got {v!r}")
        for k, v in self.mean.items():
            if isinstance(v, (int, float, np.number)) and not isinstance(v, bool) and abs(v) > STYLE_VALUE_MAX:
                raise ValueError(f"style {self.name!r}: mean of {k!r} must be in (0, {STYLE_VALUE_MAX:g}], got {v!r}")

    def moments(self, features: FeatureSet) -> tuple[np.ndarray, np.ndarray]:
        """Mean (K,) and covariance (K, K) in feature order, validated against the feature names."""
        names = list(features.names)
        for label, mapping in (("mean", self.mean), ("std", self.std)):
            unknown = sorted(set(mapping) - set(names))
            if unknown:
                raise ValueError(f"style {self.name!r}: unknown feature names in {label}: {unknown}; allowed: {names}")
        ref = features.reference
        mean = np.array([float(self.mean.get(n, 1.0 if n == ref else np.nan)) for n in names])
        if np.isnan(mean).any():
            missing = [n for n, m in zip(names, mean) if np.isnan(m)]
            raise ValueError(f"style {self.name!r}: mean misses features {missing}")
        if not np.isclose(mean[features.reference_index], 1.0):
            raise ValueError(
                f"style {self.name!r}: the reference feature {ref!r} has weight 1 in the normalisation, got "
                f"{mean[features.reference_index]}"
            )
        if np.any(mean <= 0):
            raise ValueError(f"style {self.name!r}: mean weights must be > 0, got {dict(zip(names, mean))}")
        if self.cov is not None:
            cov = np.asarray(self.cov, dtype=float)
            if cov.shape != (len(names), len(names)):
                raise ValueError(f"style {self.name!r}: cov must be {len(names)}x{len(names)}, got {cov.shape}")
            if not np.allclose(cov, cov.T):
                raise ValueError(f"style {self.name!r}: cov must be symmetric")
            eig = np.linalg.eigvalsh(cov)
            if eig.min() < -1e-12 * max(1.0, eig.max()):
                raise ValueError(f"style {self.name!r}: cov must be positive semi-definite, smallest eigenvalue {eig.min():.3g}")
        else:
            cov = np.diag([float(self.std.get(n, 0.0)) ** 2 for n in names])
        i = features.reference_index
        if cov[i, i] > 0:
            raise ValueError(f"style {self.name!r}: the reference feature {ref!r} is fixed at 1 and cannot vary")
        return mean, cov


@dataclass(frozen=True)
class Population:
    """A mixture of styles over the weights of a feature set.

    Parameters
    ----------
    features : FeatureSet
    styles : sequence of Style
    rationality : float or None
        None: demonstrations are exactly optimal (noise-free). A number beta > 0: Boltzmann-rational
        demonstrations with absolute weights beta * theta.
    """

    features: FeatureSet
    styles: tuple[Style, ...]
    rationality: float | None = None

    def __post_init__(self) -> None:
        styles = tuple(self.styles)
        if not styles:
            raise ValueError("a population needs at least one style")
        names = [s.name for s in styles]
        if len(set(names)) != len(names):
            raise ValueError(f"style names must be unique, got {names}")
        for s in styles:
            s.moments(self.features)  # validates names and covariance now, not at sampling time
        if self.rationality is not None and (not np.isfinite(self.rationality) or self.rationality <= 0):
            raise ValueError(f"rationality must be > 0 or None, got {self.rationality!r}")
        object.__setattr__(self, "styles", styles)

    @property
    def style_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.styles)

    def sample_weights(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Draw n normalised weight vectors (n, K) and their style indices (n,); draws kept positive."""
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        if not is_positive_int(n):
            raise ValueError(f"n must be a positive integer, got {n!r}")
        w = np.array([s.weight for s in self.styles], dtype=float)
        style = rng.choice(len(self.styles), size=int(n), p=w / w.sum())
        theta = np.empty((int(n), self.features.n_features))
        for j, s in enumerate(self.styles):
            idx = np.flatnonzero(style == j)
            mean, cov = s.moments(self.features)
            theta[idx] = _positive_gaussian(mean, cov, len(idx), rng, s.name)
        return theta, style


def _positive_gaussian(mean, cov, n, rng, name) -> np.ndarray:
    out = rng.multivariate_normal(mean, cov, size=n, method="eigh") if n else np.empty((0, len(mean)))
    for _ in range(_MAX_REDRAWS):
        bad = np.any(out <= 0, axis=1)
        if not bad.any():
            return out
        out[bad] = rng.multivariate_normal(mean, cov, size=int(bad.sum()), method="eigh")
    raise ValueError(f"style {name!r}: could not draw positive weights (mean {mean}); reduce its spread")


def optimal_controls(model: DriverModel, x0: np.ndarray, theta: np.ndarray, n_steps: int) -> np.ndarray:
    """Unconstrained optimum of theta . f from each start: (M, n_steps, n_u) (closed form when quadratic,
    Gauss-Newton to convergence otherwise)."""
    if model.features.quadratic:
        return LQPredictor(model.dynamics, model.features).controls(x0, theta, n_steps)
    return SequentialMPC(model.dynamics, model.features, None, n_iter=8).controls(x0, theta, n_steps)


def sample_boltzmann_controls(
    model: DriverModel,
    x0: np.ndarray,
    theta: np.ndarray,
    n_steps: int,
    rng: np.random.Generator,
    *,
    mh_steps: int = 30,
    return_acceptance: bool = False,
):
    """Samples from P(U) ∝ exp(-theta . f(U)): exact for quadratic features, Laplace + Metropolis otherwise.

    Parameters
    ----------
    x0 : array (M, n_x)
    theta : array (M, K) or (K,)   absolute weights (the scale is the rationality)
    n_steps : int
    rng : numpy.random.Generator
    mh_steps : int                 independence Metropolis-Hastings steps per chain (non-quadratic features)
    return_acceptance : bool       also return the mean acceptance rate (1.0 for quadratic features)

    Returns
    -------
    controls : array (M, n_steps, n_u) [, acceptance : float]
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    theta = model.features.weights(theta)
    if np.any(theta <= 0):
        raise ValueError(f"Boltzmann sampling needs positive weights, got {theta[theta <= 0][:3]}")
    M = x0.shape[0]
    theta = np.broadcast_to(theta, (M, model.features.n_features))
    n_u = model.dynamics.n_u
    if model.features.quadratic:
        cost = LQPredictor(model.dynamics, model.features).cost(n_steps)
        A, b = cost.terms(x0, theta)
        mean = -np.linalg.solve(A, b[..., None])[..., 0]
    else:
        mean = optimal_controls(model, x0, theta, n_steps).reshape(M, -1)
        X = model.dynamics.rollout(x0, mean.reshape(M, n_steps, n_u))
        der = model.features.derivatives(model.dynamics, X, mean.reshape(M, n_steps, n_u))
        A = np.einsum("mk,mkij->mij", theta, der.hess)
    d = mean.shape[1]
    # the proposal's precision: the Hessian at the optimum, shifted where it is not positive definite (the
    # Metropolis step corrects any mismatch with the exact density)
    L, A, _, _ = shift_to_pd(np.ascontiguousarray(A), 1e-9)
    Lt = np.swapaxes(L, -1, -2)

    def propose():
        z = rng.standard_normal((M, d))
        return mean + scipy.linalg.solve_triangular(Lt, z[..., None], lower=False)[..., 0], 0.5 * np.sum(z**2, axis=1)

    U, q = propose()
    if model.features.quadratic:
        out = U.reshape(M, n_steps, n_u)
        return (out, 1.0) if return_acceptance else out

    def energy(Uf):
        Uc = Uf.reshape(M, n_steps, n_u)
        return np.einsum("mk,mk->m", theta, model.features.values(model.dynamics.rollout(x0, Uc), Uc))

    e = energy(U)
    accepted = 0
    for _ in range(int(mh_steps)):
        U_new, q_new = propose()
        e_new = energy(U_new)
        # log acceptance: target exp(-e), proposal density exp(-q) (same normaliser for both)
        log_alpha = (-e_new + q_new) - (-e + q)
        take = np.log(rng.random(M)) < log_alpha
        U = np.where(take[:, None], U_new, U)
        e = np.where(take, e_new, e)
        q = np.where(take, q_new, q)
        accepted += int(take.sum())
    out = U.reshape(M, n_steps, n_u)
    rate = accepted / max(1, M * int(mh_steps))
    return (out, rate) if return_acceptance else out


def generate_demonstrations(
    model: DriverModel,
    population: Population,
    x0: np.ndarray,
    n_steps: int,
    rng: np.random.Generator,
    *,
    metadata: Sequence[Mapping] | None = None,
) -> list[Trajectory]:
    """Demonstrations from starts x0 (M, n_x) by drivers drawn from the population.

    Each trajectory's metadata holds ``theta`` (normalised true weights, feature order), ``theta_by_name``,
    ``style`` (index), ``style_name`` and ``rationality``.
    """
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    theta, style = population.sample_weights(x0.shape[0], rng)
    if population.rationality is None:
        U = optimal_controls(model, x0, theta, n_steps)
    else:
        U = sample_boltzmann_controls(model, x0, population.rationality * theta, n_steps, rng)
    X = model.dynamics.rollout(x0, U)
    out = []
    for m in range(x0.shape[0]):
        meta = {
            "theta": theta[m].copy(),
            "theta_by_name": model.features.as_dict(theta[m]),
            "style": int(style[m]),
            "style_name": population.styles[style[m]].name,
            "rationality": population.rationality,
        }
        if metadata is not None:
            meta.update(metadata[m])
        out.append(Trajectory(X[m], U[m], model.dynamics.dt, meta))
    return out
