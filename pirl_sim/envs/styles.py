"""Style-aware observations of ``pirl_sim/Roundabout-v0``: the neighbours' cost weights as observation columns.

With ``style_observation`` other than ``"none"``, every row of the ``Kinematics`` observation gets three more
columns, :data:`STYLE_COLUMNS`: ``style_known`` (1 where the row's weights are given) and the normalised weights
of ``speed_dev`` and ``acc_sq`` as ``clip(ln(theta_f) / LOG_WEIGHT_SCALE, -1, 1)``. Modes
(:data:`STYLE_OBSERVATIONS`): ``"none"``, ``"truth"`` (the PIRL drivers' ground truth) and ``"inferred"`` (a
fitted ``style_learner`` infers each observed vehicle's weights online from its history as the ego observed it).

The modes are explained in the documentation's "The gymnasium environment" page.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pirl_sim.scenarios.contract import STEP
from pirl_sim.scenarios.population_config import FEATURE_NAMES, FREE_FEATURES

__all__ = ["STYLE_OBSERVATIONS", "STYLE_COLUMNS", "LOG_WEIGHT_SCALE", "StyleObserver", "check_style_config",
           "style_columns_of_weights"]

STYLE_OBSERVATIONS = ("none", "truth", "inferred")  #: values of the ``style_observation`` option
STYLE_COLUMNS = ("style_known", *FREE_FEATURES)  #: the extra observation columns, in order
LOG_WEIGHT_SCALE = 3.0  #: ln(theta) of +-3 (theta = 0.05 or 20) maps to -+1
_FRAME_DT = STEP  # [s] (the simulator contract's step)
_FREE = [FEATURE_NAMES.index(f) for f in FREE_FEATURES]


def style_columns_of_weights(theta) -> np.ndarray:
    """The :data:`STYLE_COLUMNS` (3,) of known normalised weights ``theta`` (K,) in :data:`FEATURE_NAMES` order."""
    theta = np.asarray(theta, dtype=float)
    return np.concatenate([[1.0], np.clip(np.log(theta[_FREE]) / LOG_WEIGHT_SCALE, -1.0, 1.0)])


def check_style_config(c: dict, route_ids: Sequence[str]) -> None:
    """Check (and normalise in place) ``style_observation``, ``style_learner`` and ``style_history``.

    ``style_learner`` may be a fitted learner (:class:`pirl_sim.learners.BaseLearner`) or the path of one saved
    with ``learner.save``; for ``"inferred"`` it is required and its model must be a route-set driver model
    with every route of the env (``route_ids``) at the env's 0.1 s step. ``ValueError``/``TypeError`` name the
    value and what is allowed.
    """
    mode = c["style_observation"]
    if mode not in STYLE_OBSERVATIONS:
        raise ValueError(f"style_observation must be one of {STYLE_OBSERVATIONS}, got {mode!r}")
    h = c["style_history"]
    if isinstance(h, bool) or not isinstance(h, (int, np.integer)) or h < 2:
        raise ValueError(f"style_history must be an integer >= 2 (frames of 0.1 s), got {h!r}")
    learner = c["style_learner"]
    if learner is None:
        if mode == "inferred":
            raise ValueError("style_observation 'inferred' needs style_learner: a fitted pirl_sim learner (e.g. "
                             "PIRL-kNN fitted on recordings of the same population) or the path of a saved one")
        return
    if isinstance(learner, (str, Path)):
        from pirl_sim.learners.model_io import load_learner

        learner = load_learner(learner)
        c["style_learner"] = learner
    from sklearn.exceptions import NotFittedError
    from sklearn.utils.validation import check_is_fitted

    from pirl_sim.learners import BaseLearner
    from pirl_sim.scenarios.drivers import RouteSetDriverModel

    if not isinstance(learner, BaseLearner):
        raise TypeError(f"style_learner must be a fitted pirl_sim learner, the path of a saved one, or None; got "
                        f"{type(learner).__name__}")
    try:
        check_is_fitted(learner)
    except NotFittedError:
        raise ValueError(f"style_learner {type(learner).__name__} is not fitted: call fit() first") from None
    model = learner.model_
    if not isinstance(model, RouteSetDriverModel):
        raise ValueError(f"style_learner's model must be a RouteSetDriverModel (the roundabout's routes), got "
                         f"{type(model).__name__}")
    missing = [r for r in route_ids if r not in model.routes.route_ids]  # type: ignore[union-attr]
    if missing:
        raise ValueError(f"style_learner's model lacks the env's routes {missing}; it has "
                         f"{', '.join(model.routes.route_ids)}")  # type: ignore[union-attr]
    if not math.isclose(model.dynamics.dt, _FRAME_DT):
        raise ValueError(f"style_learner's model steps by {model.dynamics.dt} s; the env's frames are {_FRAME_DT} s")


class StyleObserver:
    """The style columns of the observation's rows (see the module docstring).

    Parameters
    ----------
    mode : str
        One of :data:`STYLE_OBSERVATIONS`.
    learner : BaseLearner, optional
        Fitted, for ``"inferred"`` (checked by :func:`check_style_config`).
    history : int
        Frames of history per inference when the learner has no ``window``.
    """

    def __init__(self, mode: str, learner=None, history: int = 20) -> None:
        self.mode = mode
        self.learner = learner
        window = getattr(learner, "window", None)
        self.history = int(window if window is not None else history)
        self._tracks: dict[str, deque] = {}  # vehicle id -> (s_global [m], v [m/s]) of its last frames
        self._route: dict[str, int] = {}
        self._seen: set[str] = set()
        self.n_inferences = 0

    @property
    def width(self) -> int:
        """Extra columns: 0 for ``"none"``, else len(STYLE_COLUMNS)."""
        return 0 if self.mode == "none" else len(STYLE_COLUMNS)

    def record(self, vehicles: Sequence[tuple[str, str, float, float, float]]) -> None:
        """One 0.1 s frame as the ego observes it: ``(vehicle id, route id, x [m], y [m], speed [m/s])`` of every
        other vehicle on the road (``"inferred"`` only; no-op otherwise). Vehicles not in the frame lose their
        history (they left, or the ego lost sight of them)."""
        if self.mode != "inferred":
            return
        routes = self.learner.model_.routes
        present = {v[0] for v in vehicles}
        for gone in [vid for vid in self._tracks if vid not in present]:
            del self._tracks[gone]
        if not vehicles:
            return
        ids = [v[0] for v in vehicles]
        for vid, rid, *_ in vehicles:
            if vid not in self._route:
                self._route[vid] = routes.index(rid)
        r = np.array([self._route[vid] for vid in ids])
        xy = np.array([[v[2], v[3]] for v in vehicles], dtype=float)
        guess = np.array([self._tracks[vid][-1][0] - routes.offsets[self._route[vid]] if vid in self._tracks
                          else np.nan for vid in ids])
        try:
            s_local = routes.project(r, xy, guess)
        except ValueError:  # a warm start lost a vehicle (e.g. pushed by a crash): one by one, from scratch
            s_local = np.full(len(ids), np.nan)
            for k in range(len(ids)):
                try:
                    s_local[k] = routes.project(r[k:k + 1], xy[k:k + 1])[0]
                except ValueError:
                    pass
        s_global = routes.to_global(r, s_local)
        for k, vid in enumerate(ids):
            if not np.isfinite(s_global[k]):  # not on its route's path: its history starts again
                self._tracks.pop(vid, None)
                continue
            track = self._tracks.setdefault(vid, deque(maxlen=self.history + 2))
            track.append((float(s_global[k]), float(vehicles[k][4])))

    def _history(self, vid: str):
        """The vehicle's last ``history`` steps as a Trajectory of (s, v, a) and jerk, or None if too short."""
        from pirl_sim.trajectory import Trajectory

        track = self._tracks.get(vid)
        if track is None or len(track) < self.history + 2:
            return None
        sv = np.array(track)  # (history + 2, 2)
        acc = np.diff(sv[:, 1]) / _FRAME_DT  # (history + 1,) acceleration over each frame
        states = np.column_stack([sv[1:, 0], sv[1:, 1], acc])
        jerk = np.diff(acc)[:, None] / _FRAME_DT
        return Trajectory(states=states, controls=jerk, dt=_FRAME_DT, metadata={"agent_id": vid})

    def columns(self, rows: Sequence) -> np.ndarray:
        """(len(rows), width) style columns of the observation's rows 1.. (vehicles with ``vehicle_id``,
        ``kind`` and ``theta``; None for empty rows)."""
        out = np.zeros((len(rows), self.width))
        if self.mode == "truth":
            for i, v in enumerate(rows):
                if v is not None and getattr(v, "kind", None) == "pirl":
                    out[i] = style_columns_of_weights(v.theta)
        elif self.mode == "inferred":
            idx, histories = [], []
            for i, v in enumerate(rows):
                h = None if v is None else self._history(getattr(v, "vehicle_id", ""))
                if h is not None:
                    idx.append(i)
                    histories.append(h)
            if histories:
                theta = np.atleast_2d(self.learner.infer_weights(histories))
                self.n_inferences += len(histories)
                for i, th in zip(idx, theta):
                    if np.all(np.isfinite(th)) and np.all(th > 0):
                        out[i] = style_columns_of_weights(th)
        return out
