"""One prediction window drawn: the history, the recorded future and K predicted futures with probabilities.

:class:`PredictionWindow` holds and checks the arrays; :class:`PredictionView` draws a window and can be
updated to the next one (an animation of predictions as the window advances); :func:`draw_prediction` is
the one-window figure. Each of the K futures gets its own colour (:func:`pirl_sim.viz.colors.distinct_colors`)
and a legend entry with its probability; line width grows with the probability.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from .colors import distinct_colors
from .frames import TrackFrames
from .raster import (
    DEFAULT_DPI,
    DEFAULT_SIZE_PX,
    figure_to_array,
    new_figure,
    place_axes,
)
from .road import Road, road_axes
from .scene import fit_equal_aspect
from .vehicles import box_corners

__all__ = ["PredictionWindow", "PredictionView", "draw_prediction", "HISTORY_COLOR", "FUTURE_COLOR"]

HISTORY_COLOR = "#000000"  #: the observed history
FUTURE_COLOR = "#606060"  #: the recorded future (dashed)
_PROBABILITY_TOL = 1e-3  # largest |sum(probabilities) - 1| accepted
_MARGIN_M = 5.0  # [m] around the window's points when the extent is automatic


def _xy(name: str, value, *, min_points: int = 1) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < min_points:
        raise ValueError(f"{name} must have shape (N, 2) with N >= {min_points} (x, y in metres), "
                         f"got {np.shape(value)}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} has values that are not finite")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class PredictionWindow:
    """One prediction: what was seen, what happened and what was predicted (validated on construction, ValueError).

    Attributes
    ----------
    history : numpy.ndarray            (T, 2) observed positions x, y [m], oldest first, T >= 1; the last is the present
    predictions : numpy.ndarray        (K, H, 2) predicted future positions [m], K >= 1 modes, H >= 1 steps
    probabilities : numpy.ndarray      (K,) probability of each mode, >= 0, summing to 1 (within 1e-3)
    future : numpy.ndarray or None     (F, 2) recorded future positions [m], if known
    frame : int or None                the recording's ``frame_id`` at the present (to draw the other vehicles)
    track_id : int or None             the predicted vehicle, left out of the other vehicles
    time_s : float or None             time [s] of the present, shown in the figure
    """

    history: np.ndarray
    predictions: np.ndarray
    probabilities: np.ndarray
    future: np.ndarray | None = None
    frame: int | None = None
    track_id: int | None = None
    time_s: float | None = None
    labels: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "history", _xy("history", self.history))
        pred = np.array(self.predictions, dtype=float)
        if pred.ndim != 3 or pred.shape[2] != 2 or pred.shape[0] < 1 or pred.shape[1] < 1:
            raise ValueError(f"predictions must have shape (K, H, 2) (K modes, H steps, x, y in metres), "
                             f"got {np.shape(self.predictions)}")
        if not np.isfinite(pred).all():
            raise ValueError("predictions has values that are not finite")
        pred.setflags(write=False)
        object.__setattr__(self, "predictions", pred)
        prob = np.array(self.probabilities, dtype=float)
        if prob.shape != (pred.shape[0],):
            raise ValueError(f"probabilities must have shape (K,) = ({pred.shape[0]},), one per predicted future, "
                             f"got {np.shape(self.probabilities)}")
        if not np.isfinite(prob).all() or (prob < 0).any() or abs(prob.sum() - 1.0) > _PROBABILITY_TOL:
            raise ValueError(f"probabilities must be >= 0 and sum to 1, got {np.round(prob, 4).tolist()} "
                             f"(sum {prob.sum():.4g})")
        prob.setflags(write=False)
        object.__setattr__(self, "probabilities", prob)
        if self.future is not None:
            object.__setattr__(self, "future", _xy("future", self.future))
        for name in ("frame", "track_id"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer))):
                raise ValueError(f"{name} must be an integer or None, got {v!r}")
        if self.labels is not None:
            labels = tuple(self.labels) if not isinstance(self.labels, str) else None
            if labels is None or len(labels) != pred.shape[0] or not all(isinstance(x, str) for x in labels):
                raise ValueError(f"labels must be {pred.shape[0]} strings, one per predicted future, got "
                                 f"{self.labels!r}")
            object.__setattr__(self, "labels", labels)
        if self.time_s is not None and not np.isfinite(float(self.time_s)):
            raise ValueError(f"time_s must be a finite number of seconds or None, got {self.time_s!r}")

    @property
    def k(self) -> int:
        """Number of predicted futures K."""
        return int(self.predictions.shape[0])

    def points(self) -> np.ndarray:
        """All points of the window, ``(M, 2)`` [m]."""
        parts = [self.history, self.predictions.reshape(-1, 2)]
        if self.future is not None:
            parts.append(self.future)
        return np.vstack(parts)


class PredictionView:
    """A reusable figure of prediction windows: `update` to a window, `render` to an array.

    Parameters
    ----------
    road : Road, optional                    drawn beneath
    tracks : pandas.DataFrame or TrackFrames, optional   the other vehicles at a window's ``frame``, as grey boxes
    extent : tuple of float, optional        ``(xmin, xmax, ymin, ymax)`` [m]; default each window's points + 5 m
    max_k : int                              most futures a window may have (colours fixed per mode index)
    size_px, dpi : see `pirl_sim.viz.raster.new_figure`.
    title : str, optional
    """

    def __init__(self, *, road: Road | None = None, tracks=None, extent=None, max_k: int = 10,
                 size_px: tuple[int, int] = DEFAULT_SIZE_PX, dpi: float = DEFAULT_DPI, title: str | None = None):
        if road is not None and not isinstance(road, Road):
            raise TypeError(f"road must be a pirl_sim.viz.Road or None, got {type(road).__name__}")
        self.frames = None if tracks is None else (tracks if isinstance(tracks, TrackFrames) else TrackFrames(tracks))
        self.colors = distinct_colors(max_k)
        self.extent = extent
        self.figure: Figure = new_figure(size_px, dpi=dpi)
        ax = self.ax = road_axes(self.figure, title=title, road=road)
        place_axes(self.figure, title=bool(title))
        self._others = PolyCollection([], facecolors="#b0b0b0", edgecolors="#505050", linewidths=0.5, zorder=3)
        ax.add_collection(self._others, autolim=False)
        self._modes = [ax.plot([], [], color=c, lw=2.0, solid_capstyle="round", zorder=5)[0] for c in self.colors]
        self._future = ax.plot([], [], color=FUTURE_COLOR, lw=2.0, ls=(0, (4, 2)), zorder=4, label="recorded future")[0]
        self._history = ax.plot([], [], color=HISTORY_COLOR, lw=2.5, zorder=6, label="history")[0]
        self._now = ax.plot([], [], "o", color=HISTORY_COLOR, ms=6, zorder=7)[0]
        self._clock = ax.text(0.01, 0.99, "", transform=ax.transAxes, ha="left", va="top", fontsize="small",
                              family="monospace", zorder=8, clip_on=True,
                              bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.8))
        if extent is not None:
            fit_equal_aspect(ax, extent)
        self.window: PredictionWindow | None = None

    def update(self, window: PredictionWindow) -> PredictionView:
        """Draw ``window`` in place of the previous one.

        Raises
        ------
        TypeError
            If ``window`` is not a :class:`PredictionWindow`.
        ValueError
            If it has more futures than ``max_k``, or its ``frame`` is outside the recording.
        """
        if not isinstance(window, PredictionWindow):
            raise TypeError(f"window must be a PredictionWindow, got {type(window).__name__}")
        if window.k > len(self._modes):
            raise ValueError(f"the window has K = {window.k} predicted futures; this view draws at most "
                             f"max_k = {len(self._modes)}")
        for i, line in enumerate(self._modes):
            if i < window.k:
                line.set_data(window.predictions[i, :, 0], window.predictions[i, :, 1])
                line.set_linewidth(1.2 + 3.0 * float(window.probabilities[i]))
                line.set_visible(True)
            else:
                line.set_visible(False)
        if window.future is not None:
            self._future.set_data(window.future[:, 0], window.future[:, 1])
        self._future.set_visible(window.future is not None)
        self._history.set_data(window.history[:, 0], window.history[:, 1])
        self._now.set_data(window.history[-1:, 0], window.history[-1:, 1])
        verts = np.zeros((0, 6, 2))
        if self.frames is not None and window.frame is not None:
            f = self.frames
            rows = np.arange(len(f))[f.rows(window.frame)]
            if window.track_id is not None:
                rows = rows[f.track_id[rows] != window.track_id]
            verts = box_corners(f.x[rows], f.y[rows], f.psi[rows], f.length[rows], f.width[rows])
        self._others.set_verts(verts)  # type: ignore[arg-type]  # an (n, 4, 2) array of polygons
        self._clock.set_text("" if window.time_s is None else f"t = {window.time_s:.1f} s")
        self._clock.set_visible(window.time_s is not None)
        handles = [self._history] + ([self._future] if window.future is not None else []) + self._modes[:window.k]
        labels = ["history"] + (["recorded future"] if window.future is not None else []) + \
            (list(window.labels) if window.labels is not None
             else [f"mode {i + 1}: p = {p:.2f}" for i, p in enumerate(window.probabilities)])
        self.ax.legend(handles, labels, loc="best", fontsize="small", framealpha=0.85)
        if self.extent is None:
            pts = window.points()
            (x0, y0), (x1, y1) = pts.min(axis=0) - _MARGIN_M, pts.max(axis=0) + _MARGIN_M
            fit_equal_aspect(self.ax, (x0, x1, y0, y1))
        self.window = window
        return self

    def render(self, window: PredictionWindow | None = None) -> np.ndarray:
        """The figure (at ``window``, default the current one) as ``(H, W, 3)`` uint8."""
        if window is not None:
            self.update(window)
        if self.window is None:
            raise ValueError("no window drawn yet; call update(window) first")
        return figure_to_array(self.figure)


def draw_prediction(window: PredictionWindow, *, road: Road | None = None, tracks=None, extent=None,
                    size_px: tuple[int, int] = DEFAULT_SIZE_PX, dpi: float = DEFAULT_DPI,
                    title: str | None = None) -> Figure:
    """A figure of one prediction window: history (black), recorded future (grey, dashed), K futures in K colours.

    Parameters
    ----------
    window : PredictionWindow
    road, tracks, extent, size_px, dpi, title
        As :class:`PredictionView`; ``max_k`` is the window's K.

    Returns
    -------
    matplotlib.figure.Figure
        With an Agg canvas; the legend gives each future's probability.
    """
    if not isinstance(window, PredictionWindow):
        raise TypeError(f"window must be a PredictionWindow, got {type(window).__name__}")
    view = PredictionView(road=road, tracks=tracks, extent=extent, max_k=window.k, size_px=size_px, dpi=dpi,
                          title=title)
    return view.update(window).figure
