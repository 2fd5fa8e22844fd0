"""highway-env's ``Kinematics`` observation without pandas, and with the observed vehicles kept.

:class:`RoundaboutKinematics` is highway-env's :class:`~highway_env.envs.common.observation.KinematicObservation`
(same options, same rows, same values) with two changes:

- **Speed.** highway-env builds a pandas DataFrame every step (~6 ms of a 10-frame env step with 20
  vehicles, most of the bare ``roundabout-v0``'s step time); here the rows are numpy arrays. Features
  ``presence``, ``x``, ``y``, ``vx``, ``vy``, ``heading``, ``cos_h``, ``sin_h`` are computed directly (as
  ``Vehicle.to_dict`` does: velocity = speed x (cos, sin) of the heading, the first four relative to the
  observer unless ``absolute``), others through ``to_dict``; normalisation is highway-env's ``lmap`` to
  [-1, 1] over ``features_range`` and clipping. The values equal highway-env's to float32 rounding (tested).
- **Which vehicle is in which row.** :attr:`RoundaboutKinematics.rows` holds the vehicles of rows
  1..V-1 of the last observation (None for empty rows), after the ``order = "shuffled"`` permutation
  (drawn from the env's ``np_random`` as highway-env does), so that the env's ``info`` can name the
  neighbour of each row even when rows are shuffled.
"""

from __future__ import annotations

import numpy as np
from highway_env.envs.common.observation import KinematicObservation
from highway_env.vehicle.kinematics import Vehicle

__all__ = ["RoundaboutKinematics"]

#: features computed without ``Vehicle.to_dict``
_DIRECT = ("presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h")
_RELATIVE = ("x", "y", "vx", "vy")  # relative to the observer unless absolute (as Vehicle.to_dict)


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

    def _values(self, objects: list) -> np.ndarray:
        """(len(objects), F) un-normalised feature values, row 0 the observer."""
        feats = self.features
        ego = self.observer_vehicle
        if not all(f in _DIRECT for f in feats) or not all(isinstance(o, Vehicle) for o in objects):
            dicts = [ego.to_dict()] + [o.to_dict(None if self.absolute else ego,
                                                 observe_intentions=self.observe_intentions) for o in objects[1:]]
            return np.array([[d[f] for f in feats] for d in dicts], dtype=float)
        pos = np.array([o.position for o in objects], dtype=float)
        heading = np.array([o.heading for o in objects], dtype=float)
        speed = np.array([o.speed for o in objects], dtype=float)
        cos_h, sin_h = np.cos(heading), np.sin(heading)
        cols = {"presence": np.ones(len(objects)), "x": pos[:, 0], "y": pos[:, 1], "vx": speed * cos_h,
                "vy": speed * sin_h, "heading": heading, "cos_h": cos_h, "sin_h": sin_h}
        if not self.absolute:
            for f in _RELATIVE:
                cols[f] = np.concatenate([cols[f][:1], cols[f][1:] - cols[f][0]])
        return np.column_stack([cols[f] for f in feats])

    def observe(self) -> np.ndarray:
        """(V, F) float32 rows: the observer, then its nearest vehicles (see highway-env's ``Kinematics``)."""
        if not self.env.road:
            return np.zeros(self.space().shape, dtype=self.space().dtype)
        if self.normalize and not self.features_range:  # highway-env's default ranges (set on first use)
            self.normalize_obs({})
        close = self._close()
        values = self._values([self.observer_vehicle] + close)
        if self.normalize:
            for j, f in enumerate(self.features):
                if f in self.features_range:
                    lo, hi = self.features_range[f]
                    values[:, j] = -1 + (values[:, j] - lo) * 2 / (hi - lo)  # highway_env.utils.lmap
                    if self.clip:
                        values[:, j] = np.clip(values[:, j], -1, 1)
        obs = np.zeros((self.vehicles_count, len(self.features)))
        obs[:len(values)] = values
        rows = close + [None] * (self.vehicles_count - 1 - len(close))
        if self.order == "shuffled":
            perm = np.arange(self.vehicles_count - 1)
            self.env.np_random.shuffle(perm)  # the draw highway-env makes for shuffling obs[1:]
            obs[1:] = obs[1:][perm]
            rows = [rows[i] for i in perm]
        self.rows = rows
        return obs.astype(self.space().dtype)
