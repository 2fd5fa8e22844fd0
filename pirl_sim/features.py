"""Named trajectory features and their exact derivatives with respect to the controls.

Every feature is a reduction (sum or mean over the N steps) of a squared residual,
``f(xi) = reduce_k ||r(x_k, u_{k-1})||^2`` for k = 1..N, where x_k is the state that control u_{k-1} produced
(x_0 is given, so it carries no cost). The residual supplies its Jacobians (and, when it is not affine, the
second derivatives), and `FeatureSet.derivatives` chains them through the condensed linear dynamics
``X = Phi x_0 + Gamma U`` into exact gradients and Hessians in the stacked controls U (length d = N * n_u).

A cost is ``C(xi) = theta . f(xi)`` with theta ordered as `FeatureSet.names`; weights may also be given as a
``{name: weight}`` mapping, checked against the names.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Callable, Literal, Mapping, NamedTuple, Sequence

import numpy as np

from .dynamics import LinearDynamics
from .trajectory import Trajectory, stack_trajectories

__all__ = [
    "Residual",
    "Feature",
    "FeatureSet",
    "FeatureDerivatives",
    "squared_state",
    "squared_control",
    "SquaredStateResidual",
    "SquaredControlResidual",
    "lqr_features",
]


class Residual(NamedTuple):
    """A residual and its derivatives at every stage.

    Attributes
    ----------
    r : array, shape (M, N, p)
    jac_x : array, shape (M or 1, N or 1, p, n_x)
    jac_u : array, shape (M or 1, N or 1, p, n_u)
    hess_x : array, shape (M, N, p, n_x, n_x), or None when the residual is affine in x (or gives `hess_scale`).
        Second derivatives of each residual component in the state (residuals are taken affine in u).
    hess_scale : array, shape (M, N, p), or None
        Instead of ``hess_x``: the second derivative is ``hess_scale * jac_x^T jac_x`` per component (along the
        gradient, as a smooth function of one affine combination of the states has), never stored as
        (M, N, p, n_x, n_x); the exact Hessian is then the Gauss-Newton one with the Jacobian scaled by
        ``sqrt(1 + r hess_scale)``.
    x_support : tuple of int, or None
        The state entries the residual can depend on (the only columns of ``jac_x`` that can be non-zero), when the
        residual states them; None: found from ``jac_x`` where needed.
    """

    r: np.ndarray
    jac_x: np.ndarray
    jac_u: np.ndarray
    hess_x: np.ndarray | None = None
    hess_scale: np.ndarray | None = None
    x_support: tuple[int, ...] | None = None

    @property
    def curved(self) -> bool:
        """Whether the residual has a second derivative in x (`hess_x` or `hess_scale`)."""
        return self.hess_x is not None or self.hess_scale is not None

    def second_x(self) -> np.ndarray | None:
        """The second derivatives (M, N, p, n_x, n_x) in x: `hess_x`, or built from `hess_scale`; None if affine."""
        if self.hess_x is not None or self.hess_scale is None:
            return self.hess_x
        jx = np.broadcast_to(self.jac_x, self.hess_scale.shape + self.jac_x.shape[-1:])
        return self.hess_scale[..., None, None] * (jx[..., :, None] * jx[..., None, :])


ResidualFn = Callable[[np.ndarray, np.ndarray], Residual]


@dataclass(frozen=True)
class Feature:
    """One named feature: reduce_k ||residual(x_k, u_{k-1})||^2.

    Parameters
    ----------
    name : str
    residual : callable ``(x (M, N, n_x), u (M, N, n_u)) -> Residual``
    reduction : {"sum", "mean"}
        Sum over the N stages, or their mean (the paper's roundabout features are means).
    quadratic : bool
        True when the residual is affine in (x, u): the feature is then exactly quadratic in U and its
        Hessian is the same for every trajectory of the same length.
    """

    name: str
    residual: ResidualFn
    reduction: Literal["sum", "mean"] = "sum"
    quadratic: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"feature name must be a non-empty string, got {self.name!r}")
        if self.reduction not in ("sum", "mean"):
            raise ValueError(f"reduction must be 'sum' or 'mean', got {self.reduction!r}")
        if not callable(self.residual):
            raise TypeError(f"residual of feature {self.name!r} must be callable")


class FeatureDerivatives(NamedTuple):
    """Features of M trajectories and their derivatives in the stacked controls (d = N * n_u).

    Attributes
    ----------
    values : array, shape (M, K)
    grad : array, shape (M, K, d)
    hess : array, shape (M, K, d, d), or (1, K, d, d) when shared by all M trajectories.
    """

    values: np.ndarray
    grad: np.ndarray
    hess: np.ndarray

    @property
    def shared_hessian(self) -> bool:
        return self.hess.shape[0] == 1 and self.grad.shape[0] != 1


@dataclass(frozen=True)
class FeatureSet:
    """An ordered set of named features with a reference feature that fixes the weights' scale.

    Parameters
    ----------
    features : sequence of Feature
    reference : str
        Name of the feature whose weight is 1 in the reported normalisation (a control-effort feature, whose
        Hessian is positive definite). Reported weights are ``theta / theta[reference]``.
    """

    features: tuple[Feature, ...]
    reference: str
    _hessian_cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        feats = tuple(self.features)
        if not feats:
            raise ValueError("a FeatureSet needs at least one feature")
        for f in feats:
            if not isinstance(f, Feature):
                raise TypeError(f"expected Feature objects, got {type(f).__name__}")
        names = [f.name for f in feats]
        if len(set(names)) != len(names):
            raise ValueError(f"feature names must be unique, got {names}")
        if self.reference not in names:
            raise ValueError(f"reference feature {self.reference!r} is not one of {names}")
        object.__setattr__(self, "features", feats)

    def __getstate__(self) -> dict:
        """Pickled without the Hessian cache: its keys hold ``id(dynamics)`` of this process, which another
        process could give to other dynamics."""
        state = dict(self.__dict__)
        state["_hessian_cache"] = {}
        return state

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.features)

    @property
    def n_features(self) -> int:
        return len(self.features)

    @property
    def reference_index(self) -> int:
        return self.names.index(self.reference)

    @property
    def quadratic(self) -> bool:
        return all(f.quadratic for f in self.features)

    # ------------------------------------------------------------------ weights
    def weights(self, theta: Mapping[str, float] | Sequence[float] | np.ndarray) -> np.ndarray:
        """Weights as an array ordered like `names`, shape (..., K); a mapping must name every feature."""
        if isinstance(theta, Mapping):
            unknown = sorted(set(theta) - set(self.names))
            missing = [n for n in self.names if n not in theta]
            if unknown or missing:
                raise ValueError(
                    f"weights must name exactly the features {list(self.names)}; unknown: {unknown}, missing: {missing}"
                )
            arr = np.array([float(theta[n]) for n in self.names])
        else:
            arr = np.asarray(theta, dtype=float)
        if arr.shape[-1:] != (self.n_features,):
            raise ValueError(f"weights must have {self.n_features} entries {list(self.names)}, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"weights must be finite, got {arr}")
        return arr

    def normalize(self, theta: np.ndarray) -> np.ndarray:
        """Divide by the reference feature's weight: the reported normalisation, shape (..., K)."""
        theta = self.weights(theta)
        ref = theta[..., self.reference_index : self.reference_index + 1]
        if np.any(ref <= 0):
            raise ValueError(f"the reference weight ({self.reference!r}) must be > 0 to normalise, got {ref.ravel()}")
        return theta / ref

    def as_dict(self, theta: np.ndarray) -> dict[str, float]:
        theta = self.weights(theta)
        if theta.ndim != 1:
            raise ValueError(f"as_dict takes one weight vector, got shape {theta.shape}")
        return {n: float(w) for n, w in zip(self.names, theta)}

    # ------------------------------------------------------------------ evaluation
    @staticmethod
    def _split(states: np.ndarray, controls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return states[:, 1:, :], controls

    def values(self, states: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """Feature values, shape (M, K), for states (M, N + 1, n_x) and controls (M, N, n_u)."""
        states, controls = _check_arrays(states, controls)
        x, u = self._split(states, controls)
        out = np.empty((states.shape[0], self.n_features))
        for k, feat in enumerate(self.features):
            # a residual may offer ``value(x, u) -> r`` without its derivatives (cheaper for cost evaluations)
            value = getattr(feat.residual, "value", None)
            r = value(x, u) if value is not None else feat.residual(x, u).r
            stage = np.sum(r**2, axis=-1)
            out[:, k] = stage.mean(axis=1) if feat.reduction == "mean" else stage.sum(axis=1)
        return out

    def trajectory_values(self, trajectories: Sequence[Trajectory]) -> np.ndarray:
        """Feature values of trajectories of any lengths, shape (M, K)."""
        trajectories = list(trajectories)
        if not trajectories:
            raise ValueError("expected at least one trajectory, got none")
        out = np.empty((len(trajectories), self.n_features))
        for idx, group in _group_by_length(trajectories).items():
            states, controls, _ = stack_trajectories([trajectories[i] for i in group])
            out[group] = self.values(states, controls)
        return out

    def derivatives(
        self, dynamics: LinearDynamics, states: np.ndarray, controls: np.ndarray, *, gauss_newton: bool = False
    ) -> FeatureDerivatives:
        """Exact values, gradients and Hessians of every feature in the stacked controls U.

        Parameters
        ----------
        dynamics : LinearDynamics
        states, controls : array (M, N + 1, n_x), (M, N, n_u)
        gauss_newton : bool       drop the residuals' second derivatives (``2 r . d2r``): positive semi-definite
                                  Gauss-Newton Hessians (for the MPC's sequential scheme)

        Returns
        -------
        derivatives : FeatureDerivatives   ``hess`` has a leading dimension of 1 when every feature is quadratic
        """
        states, controls = _check_arrays(states, controls)
        M, N, n_u = controls.shape
        K, d = self.n_features, N * n_u
        values = np.empty((M, K))
        grad = np.empty((M, K, d))
        hess = np.empty((1 if self.quadratic else M, K, d, d))
        for k, value, g, Hk in self._terms(dynamics, states, controls, gauss_newton):
            values[:, k], grad[:, k], hess[:, k] = value, g, Hk
        return FeatureDerivatives(values, grad, hess)

    def expansion(
        self,
        dynamics: LinearDynamics,
        states: np.ndarray,
        controls: np.ndarray,
        theta: np.ndarray,
        *,
        gauss_newton: bool = False,
    ) -> FeatureDerivatives:
        """Feature values and gradients, and the Hessian of the cost ``theta . f`` only, in the stacked controls.

        What a Newton step on the cost needs, without the per-feature Hessians of every trajectory.

        Parameters
        ----------
        dynamics : LinearDynamics
        states, controls : array (M, N + 1, n_x), (M, N, n_u)
        theta : array (M, K)            weights per trajectory
        gauss_newton : bool             the Gauss-Newton Hessian instead of the exact one (`derivatives`)

        Returns
        -------
        derivatives : FeatureDerivatives   ``values`` (M, K), ``grad`` (M, K, d), ``hess`` (M, d, d) of the cost
        """
        states, controls = _check_arrays(states, controls)
        M, N = controls.shape[:2]
        d = N * controls.shape[2]
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (M, self.n_features):
            raise ValueError(f"theta must have shape {(M, self.n_features)}, got {theta.shape}")
        values = np.empty((M, self.n_features))
        grad = np.empty((M, self.n_features, d))
        shared, own = [], []  # type: ignore[var-annotated]
        for k, value, g, Hk in self._terms(dynamics, states, controls, gauss_newton, factored=True):
            values[:, k], grad[:, k] = value, g
            (shared if Hk.shape[0] == 1 else own).append((k, Hk))
        if shared:  # constant Hessians: one pass over the output
            hess = np.einsum("mq,qij->mij", theta[:, [k for k, _ in shared]],  # type: ignore[index]
                             np.concatenate([H for _, H in shared]))
        else:
            hess = np.zeros((M, d, d))
        for k, Hk in own:
            Hk *= theta[:, k, None, None]
            hess += Hk
        return FeatureDerivatives(values, grad, hess)

    def _terms(
        self, dynamics: LinearDynamics, states: np.ndarray, controls: np.ndarray, gauss_newton: bool,
        factored: bool = False,
    ):
        """Per feature k: (k, values (M,), gradients (M, d), Hessians (1 or M, d, d)) in the stacked controls.

        ``factored``: Hessians of non-quadratic features as 2 J^T J + G^T (2 r . d2r) G from the residuals'
        Jacobians in U (`_factored_hessian`; the same matrices, about twice as fast as the stage-wise
        assembly, which the paper's reproductions keep so that their files stay byte-identical)."""
        M, N1, n_x = states.shape
        N, n_u = N1 - 1, controls.shape[2]
        if n_x != dynamics.n_x or n_u != dynamics.n_u:
            raise ValueError(
                f"trajectories have n_x={n_x}, n_u={n_u} but the dynamics have n_x={dynamics.n_x}, n_u={dynamics.n_u}"
            )
        _, gamma = dynamics.condensed(N)
        G = gamma.reshape(N, n_x, N * n_u)  # d x_k / d U for k = 1..N
        d = N * n_u
        x, u = self._split(states, controls)
        Gflat = G.reshape(N * n_x, d)
        for k, feat in enumerate(self.features):
            res = feat.residual(x, u)
            scale = 1.0 / N if feat.reduction == "mean" else 1.0
            r, Jx, Ju = res.r, res.jac_x, res.jac_u
            value = scale * np.sum(r**2, axis=(1, 2))
            # stage gradients 2 J^T r, chained through the dynamics
            JxT, JuT = np.swapaxes(Jx, -1, -2), np.swapaxes(Ju, -1, -2)
            gx = 2.0 * (JxT @ r[..., None])[..., 0]  # (M, N, n_x)
            gu = 2.0 * (JuT @ r[..., None])[..., 0]  # (M, N, n_u)
            g = scale * (gx.reshape(M, N * n_x) @ Gflat + gu.reshape(M, d))
            # stage Hessians 2 J^T J (+ 2 r . d2r for non-affine residuals); constant for quadratic features
            key = (k, N, id(dynamics))
            if feat.quadratic and key in self._hessian_cache:
                yield k, value, g, self._hessian_cache[key][0]
                continue
            if factored and not feat.quadratic:
                yield k, value, g, scale * _factored_hessian(G, Jx, Ju, r, None if gauss_newton else res)
                continue
            Hxx = 2.0 * (JxT @ Jx)
            Hxu = 2.0 * (JxT @ Ju)
            Huu = 2.0 * (JuT @ Ju)
            second = None if gauss_newton else res.second_x()
            if second is not None:
                Hxx = Hxx + 2.0 * np.einsum("mkp,mkpab->mkab", r, second)
            if feat.quadratic:
                Hxx, Hxu, Huu = Hxx[:1, :], Hxu[:1, :], Huu[:1, :]
            Hk = scale * _assemble_hessian(G, Hxx, Hxu, Huu, N, n_u)
            if feat.quadratic:
                Hk.setflags(write=False)
                self._hessian_cache[key] = (Hk, dynamics)  # keeps the dynamics alive: its id stays unique
            yield k, value, g, Hk

    def quadratic_terms(self, dynamics: LinearDynamics, x0: np.ndarray, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
        """Exact quadratic form of quadratic features around zero controls.

        ``f_k(U) = 1/2 U^T H_k U + b_k . U + c_k`` for trajectories starting at x0.

        Returns
        -------
        H : array, shape (K, d, d), shared by all starts.
        b : array, shape (M, K, d)
        """
        if not self.quadratic:
            nonq = [f.name for f in self.features if not f.quadratic]
            raise ValueError(f"quadratic_terms needs quadratic features; not quadratic: {nonq}")
        x0 = np.atleast_2d(np.asarray(x0, dtype=float))
        zeros = np.zeros((x0.shape[0], int(n_steps), dynamics.n_u))
        states = dynamics.rollout(x0, zeros)
        der = self.derivatives(dynamics, states, zeros)
        return der.hess[0], der.grad


def _check_arrays(states: np.ndarray, controls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    states = np.asarray(states, dtype=float)
    controls = np.asarray(controls, dtype=float)
    if states.ndim != 3 or controls.ndim != 3:
        raise ValueError(f"expected states (M, N+1, n_x) and controls (M, N, n_u), got {states.shape}, {controls.shape}")
    if states.shape[0] != controls.shape[0] or states.shape[1] != controls.shape[1] + 1:
        raise ValueError(
            f"expected one more state than controls per trajectory: states {states.shape}, controls {controls.shape}"
        )
    return states, controls


def _assemble_hessian(G, Hxx, Hxu, Huu, N, n_u) -> np.ndarray:
    """sum_k G_k^T Hxx_k G_k + G_k^T Hxu_k E_k + E_k^T Hux_k G_k + E_k^T Huu_k E_k, shape (M', d, d)."""
    Mp = max(Hxx.shape[0], Hxu.shape[0], Huu.shape[0])
    n_x = G.shape[1]
    d = N * n_u
    Hxx = np.broadcast_to(Hxx, (Mp, N, n_x, n_x))
    T = (Hxx @ G[None]).reshape(Mp, N * n_x, d)
    H = np.swapaxes(G.reshape(N * n_x, d), 0, 1)[None] @ T
    Hxu = np.broadcast_to(Hxu, (Mp, N, n_x, n_u))
    if np.any(Hxu):
        C = np.einsum("kad,mkac->mdkc", G, Hxu).reshape(Mp, d, d)  # column block k-1 <- G_k^T Hxu_k
        H = H + C + np.swapaxes(C, 1, 2)
    Huu = np.broadcast_to(Huu, (Mp, N, n_u, n_u))
    idx = np.arange(N)
    blocks = H.reshape(Mp, N, n_u, N, n_u)
    blocks[:, idx, :, idx, :] += np.moveaxis(Huu, 1, 0)
    return blocks.reshape(Mp, d, d)


def _factored_hessian(G, Jx, Ju, r, res=None) -> np.ndarray:
    """sum_k 2 J_k^T J_k + G_k^T (2 r_k . d2r_k) G_k with J_k = Jx_k G_k + Ju_k E_k, shape (M, d, d).

    G (N, n_x, d); Jx (M|1, N|1, p, n_x); Ju (M|1, N|1, p, n_u); r (M, N, p); res: the `Residual` whose second
    derivative enters, or None (Gauss-Newton). With its `Residual.hess_scale`, no control in the residual and
    1 + r hess_scale >= 0, the whole Hessian is one product, 2 (s J)^T (s J) with s = sqrt(1 + r hess_scale). A
    second-derivative term that is diagonal in the state costs one product per non-zero entry.
    """
    hess_scale = None if res is None else res.hess_scale
    M, N, p = r.shape
    n_x, d = G.shape[1], G.shape[2]
    n_u = d // N
    J = np.broadcast_to(Jx, (M, N, p, n_x)) @ G[None]  # (M, N, p, d)
    Ju = np.broadcast_to(Ju, (M, N, p, n_u))
    if hess_scale is not None and not np.any(Ju):
        s2 = 1.0 + r * hess_scale
        if np.all(s2 >= 0.0):
            Jf = (J * np.sqrt(s2)[..., None]).reshape(M, N * p, d)
            return 2.0 * (np.swapaxes(Jf, 1, 2) @ Jf)
    if np.any(Ju):
        J = J.reshape(M, N, p, N, n_u).copy()
        idx = np.arange(N)
        J[:, idx, :, idx, :] += np.moveaxis(Ju, 1, 0)
        J = J.reshape(M, N, p, d)
    Jf = J.reshape(M, N * p, d)
    H = 2.0 * (np.swapaxes(Jf, 1, 2) @ Jf)
    if res is None or not res.curved:
        return H
    W = 2.0 * np.einsum("mkp,mkpab->mkab", r, res.second_x())  # (M, N, n_x, n_x)
    diag = np.einsum("mkaa->mka", W)
    if not np.any(W - diag[..., None] * np.eye(n_x)):
        for a in np.flatnonzero(np.any(diag != 0, axis=(0, 1))):
            H += G[:, a, :].T @ (diag[:, :, a, None] * G[None, :, a, :])
        return H
    # only the states the second derivative touches (e.g. the speed and the gap of the headway residual)
    touched = np.any(W, axis=(0, 1))
    used = np.flatnonzero(touched.any(axis=0) | touched.any(axis=1))
    Gu = G[:, used, :]
    T = (W[:, :, used][:, :, :, used] @ Gu[None]).reshape(M, N * len(used), d)
    return H + Gu.reshape(N * len(used), d).T[None] @ T


def _group_by_length(trajectories: Sequence[Trajectory]) -> dict[int, np.ndarray]:
    lengths = np.array([t.n_steps for t in trajectories])
    return {int(n): np.flatnonzero(lengths == n) for n in np.unique(lengths)}


# ---------------------------------------------------------------------- ready-made features
@dataclass(frozen=True)
class SquaredStateResidual:
    """Residual ``x_k[index]`` of `squared_state` (all states if ``index`` is None).

    A module-level callable (not a closure) so that features, models and fitted learners pickle; its fields are
    its whole configuration (what `pirl_sim.learners.model_io` writes).

    Parameters
    ----------
    name : str
        The feature's name (named in the out-of-range error).
    index : tuple of int or None
        State entries that enter the residual.
    """

    name: str
    index: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        if self.index is not None:
            object.__setattr__(self, "index", tuple(int(i) for i in np.atleast_1d(np.asarray(self.index, dtype=int))))

    def __call__(self, x: np.ndarray, u: np.ndarray) -> Residual:
        n_x = x.shape[-1]
        sel = np.arange(n_x) if self.index is None else np.asarray(self.index, dtype=int)
        if np.any((sel < 0) | (sel >= n_x)):
            raise ValueError(f"feature {self.name!r}: state index {list(sel)} out of range for n_x={n_x}")
        jac_x, jac_u = _selector_jacobians(tuple(int(i) for i in sel), n_x, u.shape[-1])
        return Residual(x[..., sel], jac_x, jac_u)

    def value(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The residual alone (M, N, p), without its Jacobians."""
        return self(x, u).r


@dataclass(frozen=True)
class SquaredControlResidual:
    """Residual ``u_{k-1}`` of `squared_control` (a module-level callable, see `SquaredStateResidual`)."""

    def __call__(self, x: np.ndarray, u: np.ndarray) -> Residual:
        n_u = u.shape[-1]
        jac_u, jac_x = _selector_jacobians(tuple(range(n_u)), n_u, x.shape[-1])
        return Residual(u, jac_x, jac_u)

    def value(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The residual alone (M, N, n_u)."""
        return u


@functools.lru_cache(maxsize=64)
def _selector_jacobians(sel: tuple[int, ...], n_in: int, n_other: int) -> tuple[np.ndarray, np.ndarray]:
    """Read-only Jacobians (1, 1, p, n_in) of selecting entries ``sel`` of an n_in-vector, and zeros
    (1, 1, p, n_other) for the other argument (made once: residuals are evaluated many times per MPC call)."""
    jac = np.eye(n_in)[list(sel)][None, None]
    zeros = np.zeros((1, 1, len(sel), n_other))
    jac.setflags(write=False)
    zeros.setflags(write=False)
    return jac, zeros


def squared_state(name: str, index: Sequence[int] | None = None, *, reduction: str = "sum") -> Feature:
    """reduce_k ||x_k[index]||^2 (all states if index is None)."""
    return Feature(name, SquaredStateResidual(name, None if index is None else tuple(index)),
                   reduction=reduction, quadratic=True)  # type: ignore[arg-type]


def squared_control(name: str, *, reduction: str = "sum") -> Feature:
    """reduce_k ||u_{k-1}||^2."""
    return Feature(name, SquaredControlResidual(), reduction=reduction, quadratic=True)  # type: ignore[arg-type]


def lqr_features() -> FeatureSet:
    """The paper's synthetic LQR cost ``q sum ||x_k||^2 + r sum u_k^2`` as features (state_sq, control_sq).

    Normalised weights are (q / r, 1): the paper's theta = q / r is the first entry.
    """
    return FeatureSet((squared_state("state_sq"), squared_control("control_sq")), reference="control_sq")
