"""The `Trajectory` type: one demonstration, validated on construction.

A trajectory of ``N`` steps holds ``N + 1`` states and ``N`` controls sampled every ``dt`` seconds:
``states[i + 1] = f(states[i], controls[i])``. Metadata carries what is known about the driver that made it
(ground-truth weights, style, track id, ...); it is never used by the maths.
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping, Sequence

import numpy as np

__all__ = ["Trajectory", "stack_trajectories"]


def _as_float_array(name: str, value: Any, ndim: int) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a numeric array, got {type(value).__name__}: {exc}") from None
    if arr.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} must be finite, found {arr[tuple(bad)]} at index {tuple(int(i) for i in bad)}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Trajectory:
    """A demonstration: states, the controls that produced them, and the sampling period.

    Parameters
    ----------
    states : array (N + 1, n_x)    states x_0 .. x_N, units as the dynamics model names them (e.g. [m, m/s])
    controls : array (N, n_u)      controls u_0 .. u_{N-1} (e.g. jerk [m/s^3])
    dt : float                     sampling period [s], > 0
    metadata : mapping, optional   free-form facts, e.g. ``{"theta": ..., "style": 1, "track_id": 7}``

    Raises
    ------
    ValueError, TypeError
        Wrong dimensions, non-finite or non-numeric values, fewer than one step, or not one more state than controls.
    """

    states: np.ndarray
    controls: np.ndarray
    dt: float
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        states = _as_float_array("states", self.states, 2)
        controls = _as_float_array("controls", self.controls, 2)
        if controls.shape[0] < 1:
            raise ValueError(f"a trajectory needs at least one step (one control), got controls of shape {controls.shape}")
        if states.shape[0] != controls.shape[0] + 1:
            raise ValueError(
                "expected one more state than controls: "
                f"{states.shape[0]} states != {controls.shape[0]} controls + 1"
            )
        if isinstance(self.dt, bool) or not isinstance(self.dt, (int, float, np.floating, np.integer)):
            raise TypeError(f"dt must be a number of seconds, got {self.dt!r}")
        if not np.isfinite(self.dt) or self.dt <= 0:
            raise ValueError(f"dt must be a finite positive number of seconds, got {self.dt!r}")
        object.__setattr__(self, "states", states)
        object.__setattr__(self, "controls", controls)
        object.__setattr__(self, "dt", float(self.dt))
        object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata)))

    @property
    def n_steps(self) -> int:
        """Number of steps N (controls)."""
        return self.controls.shape[0]

    @property
    def n_x(self) -> int:
        return self.states.shape[1]

    @property
    def n_u(self) -> int:
        return self.controls.shape[1]

    @property
    def duration(self) -> float:
        """N * dt [s]."""
        return self.n_steps * self.dt

    def window(self, start: int, stop: int | None = None) -> "Trajectory":
        """The sub-trajectory of steps ``start .. stop - 1`` (states ``start .. stop``).

        Negative indices count from the end as in Python slicing; the result keeps the metadata and adds
        ``window_start`` (absolute step index of its first state). A per-step ``step_mask`` entry (an array
        of one flag per step) is sliced with the steps.
        """
        n = self.n_steps
        stop = n if stop is None else stop
        start_i = start + n if start < 0 else start
        stop_i = stop + n if stop < 0 else stop
        if not (0 <= start_i < stop_i <= n):
            raise ValueError(
                f"window [{start}, {stop}) is not a non-empty range of steps of a trajectory with {n} steps"
            )
        meta = dict(self.metadata)
        meta["window_start"] = int(meta.get("window_start", 0)) + start_i
        if "step_mask" in meta:
            mask = np.asarray(meta["step_mask"])
            if mask.shape[:1] != (n,):
                raise ValueError(f"metadata step_mask has shape {mask.shape}, expected one flag per step ({n},)")
            meta["step_mask"] = mask[start_i:stop_i]
        return Trajectory(self.states[start_i : stop_i + 1], self.controls[start_i:stop_i], self.dt, meta)

    def history_window(self, start: int, stop: int | None = None) -> "Trajectory":
        """`window` as an online observer of its steps would know it: with an ``estimator`` in the metadata (a
        callable (trajectory, start, stop) -> Trajectory, e.g. `pirl_sim.scenarios.replay.HistoryEstimator` of
        recorded tracks, whose states a smoother fitted to the whole track) the window's states estimated again
        from its own observations; without one (exact simulated states), `window` itself."""
        estimator = self.metadata.get("estimator")
        return self.window(start, stop) if estimator is None else estimator(self, start, stop)

    def with_metadata(self, **updates: Any) -> "Trajectory":
        """A copy with metadata entries added or replaced."""
        meta = dict(self.metadata)
        meta.update(updates)
        return Trajectory(self.states, self.controls, self.dt, meta)


def stack_trajectories(trajectories: Sequence[Trajectory]) -> tuple[np.ndarray, np.ndarray, float]:
    """Stack equal-length trajectories into arrays.

    Returns
    -------
    states : array, shape (M, N + 1, n_x)
    controls : array, shape (M, N, n_u)
    dt : float [s]

    Raises
    ------
    TypeError
        An element is not a `Trajectory`.
    ValueError
        Empty input, or trajectories differ in length, state/control size or dt.
    """
    trajectories = list(trajectories)
    if not trajectories:
        raise ValueError("expected at least one trajectory, got none")
    for i, t in enumerate(trajectories):
        if not isinstance(t, Trajectory):
            raise TypeError(f"element {i} is a {type(t).__name__}, expected a pirl_sim.Trajectory")
    first = trajectories[0]
    for i, t in enumerate(trajectories):
        if t.states.shape != first.states.shape or t.controls.shape != first.controls.shape:
            raise ValueError(
                f"trajectory {i} has states {t.states.shape} and controls {t.controls.shape}, but trajectory 0 has "
                f"{first.states.shape} and {first.controls.shape}; group trajectories by length first"
            )
        if not math.isclose(t.dt, first.dt, rel_tol=1e-9):
            raise ValueError(f"trajectory {i} has dt={t.dt} s, trajectory 0 has dt={first.dt} s")
    states = np.stack([t.states for t in trajectories])
    controls = np.stack([t.controls for t in trajectories])
    return states, controls, first.dt
