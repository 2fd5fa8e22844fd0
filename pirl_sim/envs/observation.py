"""highway-env's ``Kinematics`` observation without pandas, and with the observed vehicles kept.

:class:`RoundaboutKinematics` is highway-env's :class:`~highway_env.envs.common.observation.KinematicObservation`
(same options, same rows, same values to float32 rounding) with its rows computed as numpy arrays
(:func:`kinematics_rows`; the features of :data:`DIRECT_FEATURES` directly, others through
``Vehicle.to_dict``) and with :attr:`RoundaboutKinematics.rows`, the vehicles of rows 1..V-1 of the last
observation after shuffling, so that the env's ``info`` can name the neighbour of each row.

The observation is explained in the documentation's "The gymnasium environment" page (spaces).
"""

from __future__ import annotations

import numpy as np
from highway_env.envs.common.observation import KinematicObservation
from highway_env.vehicle.kinematics import Vehicle

__all__ = ["RoundaboutKinematics", "StyleKinematics", "DIRECT_FEATURES", "kinematics_rows", "shuffle_rows",
           "with_style_columns"]

#: features computed from (x, y, speed, heading) alone, without ``Vehicle.to_dict``
DIRECT_FEATURES = ("presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h")
_RELATIVE = ("x", "y", "vx", "vy")  # relative to the observer unless absolute (as Vehicle.to_dict)


def kinematics_rows(states: np.ndarray, features, *, absolute: bool = False, features_range=None,
                    normalize: bool = True, clip: bool = True, vehicles_count: int | None = None) -> np.ndarray:
    """highway-env's ``Kinematics`` rows from plain vehicle states.

    Parameters
    ----------
    states : array (n, 4)         ``x``, ``y`` [m], ``speed`` [m/s], ``heading`` [rad]; the observer is row 0
    features : sequence of str    names in `DIRECT_FEATURES`
    absolute : bool               False: ``x``, ``y``, ``vx``, ``vy`` of rows 1.. relative to the observer
    features_range : mapping name -> [low, high], optional   mapped to [-1, 1] when ``normalize`` (``utils.lmap``)
    normalize, clip : bool        map ``features_range`` to [-1, 1]; clip to [-1, 1]
    vehicles_count : int, optional   rows of the result; missing rows are zeros (default: n)

    Returns
    -------
    rows : numpy.ndarray (vehicles_count, len(features)), float64
    """
    states = np.asarray(states, dtype=float).reshape(-1, 4)
    unknown = [f for f in features if f not in DIRECT_FEATURES]
    if unknown:
        raise ValueError(f"features {unknown} need highway-env's Vehicle.to_dict; plain states give "
                         f"{', '.join(DIRECT_FEATURES)}")
    n = len(states)
    heading = states[:, 3]
    cos_h, sin_h = np.cos(heading), np.sin(heading)
    cols = {"presence": np.ones(n), "x": states[:, 0], "y": states[:, 1], "vx": states[:, 2] * cos_h,
            "vy": states[:, 2] * sin_h, "heading": heading, "cos_h": cos_h, "sin_h": sin_h}
    if not absolute:
        for f in _RELATIVE:
            cols[f] = np.concatenate([cols[f][:1], cols[f][1:] - cols[f][0]])
    values = np.column_stack([cols[f] for f in features]) if n else np.zeros((0, len(features)))
    return _finished(values, features, features_range if normalize else None, clip,
                     n if vehicles_count is None else vehicles_count)


def shuffle_rows(obs: np.ndarray, rows: list, rng: np.random.Generator) -> list:
    """Shuffle rows 1.. of ``obs`` in place with the draw highway-env makes for it (``rng.shuffle`` of V-1
    items) and return ``rows`` (the vehicles of those rows) in the same new order."""
    perm = np.arange(len(obs) - 1)
    rng.shuffle(perm)
    obs[1:] = obs[1:][perm]
    return [rows[i] for i in perm]


def with_style_columns(obs: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """``obs`` (V, F) with the style columns (V - 1, W) of rows 1.. appended (the ego's row: zeros), float32."""
    ego = np.zeros((1, columns.shape[1]))
    return np.concatenate([obs, np.concatenate([ego, columns])], axis=1).astype(np.float32)


def style_space(space, width: int):
    """A ``Box`` of shape (V, F) widened by ``width`` columns in [-1, 1] (the style columns)."""
    from gymnasium import spaces

    v = space.shape[0]
    low = np.concatenate([np.broadcast_to(space.low, space.shape), -np.ones((v, width))], axis=1)
    high = np.concatenate([np.broadcast_to(space.high, space.shape), np.ones((v, width))], axis=1)
    return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)


def _finished(values: np.ndarray, features, features_range, clip: bool, vehicles_count: int) -> np.ndarray:
    """Rows normalised over ``features_range`` (None: as they are) and padded with zero rows."""
    if features_range:
        for j, f in enumerate(features):
            if f in features_range:
                lo, hi = features_range[f]
                values[:, j] = -1 + (values[:, j] - lo) * 2 / (hi - lo)  # highway_env.utils.lmap
                if clip:
                    values[:, j] = np.clip(values[:, j], -1, 1)
    out = np.zeros((vehicles_count, len(features)))
    out[:len(values)] = values[:vehicles_count]
    return out


class RoundaboutKinematics(KinematicObservation):
    """highway-env's ``Kinematics`` observation, pandas-free, remembering its rows (see the module docstring).

    Attributes
    ----------
    rows : list
        The vehicles (or road objects) of rows 1..V-1 of the last observation, None for empty rows.
    """

    rows: list

    def __init__(self, env, **kwargs) -> None:
        super().__init__(env, **kwargs)
        self.rows = [None] * (self.vehicles_count - 1)

    def _close(self) -> list:
        close = self.env.road.close_objects_to(
            self.observer_vehicle, self.env.PERCEPTION_DISTANCE, count=self.vehicles_count - 1,
            see_behind=self.see_behind, sort=self.order == "sorted", vehicles_only=not self.include_obstacles)
        return list(close[-self.vehicles_count + 1:]) if self.vehicles_count > 1 else []

    def observe(self) -> np.ndarray:
        """(V, F) float32 rows: the observer, then its nearest vehicles (see highway-env's ``Kinematics``)."""
        if not self.env.road:
            return np.zeros(self.space().shape, dtype=self.space().dtype)
        if self.normalize and not self.features_range:  # highway-env's default ranges (set on first use)
            self.normalize_obs({})
        close = self._close()
        objects = [self.observer_vehicle] + close
        options = {"features_range": self.features_range, "normalize": self.normalize, "clip": self.clip,
                   "vehicles_count": self.vehicles_count}
        if all(f in DIRECT_FEATURES for f in self.features) and all(isinstance(o, Vehicle) for o in objects):
            states = np.array([[o.position[0], o.position[1], o.speed, o.heading] for o in objects], dtype=float)
            obs = kinematics_rows(states, self.features, absolute=self.absolute, **options)
        else:  # through Vehicle.to_dict, as highway-env
            ego = self.observer_vehicle
            dicts = [ego.to_dict()] + [o.to_dict(None if self.absolute else ego,
                                                 observe_intentions=self.observe_intentions) for o in close]
            values = np.array([[d[f] for f in self.features] for d in dicts], dtype=float)
            obs = _finished(values, self.features, self.features_range if self.normalize else None, self.clip,
                            self.vehicles_count)
        rows = close + [None] * (self.vehicles_count - 1 - len(close))
        if self.order == "shuffled":
            rows = shuffle_rows(obs, rows, self.env.np_random)
        self.rows = rows
        return obs.astype(self.space().dtype)


class StyleKinematics(RoundaboutKinematics):
    """:class:`RoundaboutKinematics` with the env's style columns appended to every row
    (:mod:`pirl_sim.envs.styles`; the env's ``_style`` observer gives them for rows 1..)."""

    def space(self):
        return style_space(super().space(), self.env._style_width)

    def observe(self) -> np.ndarray:
        if not self.env.road:
            return np.zeros(self.space().shape, dtype=np.float32)
        obs = super().observe()
        return with_style_columns(obs, self.env._style.columns(self.rows))
