"""A recorded scene at one frame: road, vehicles as oriented boxes, their recent trails, the recording's time.

:class:`SceneView` builds the figure once and then only moves its artists: :meth:`SceneView.set_frame`
updates the boxes' vertices and colours and the trails' segments; :meth:`SceneView.render` blits them onto a
cached background (road, whole tracks, legend, axes), which is what makes animations fast.
:func:`draw_scene` is the one-frame figure.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from .colors import color_rows
from .frames import TrackFrames
from .raster import (
    DEFAULT_DPI,
    DEFAULT_SIZE_PX,
    figure_to_array,
    new_figure,
    place_axes,
)
from .road import Road, road_axes
from .tracks import explain_colors, track_polylines, track_segments
from .vehicles import box_corners

__all__ = ["SceneView", "draw_scene", "check_extent", "fit_equal_aspect"]

_MARGIN_M = 5.0  # [m] around the tracks (and road) when the extent is automatic
_CLOCK_PX = (96, 22)  # [px] at 100 dpi: width, height of the clock's box


def fit_equal_aspect(ax, extent) -> None:
    """Set ``ax``'s limits to ``extent`` [m] widened on one axis so that a metre is as long in x as in y.

    Fixed limits (no autoscaling), computed from the axes' current size in pixels, so the view does not move
    when artists change and :func:`pirl_sim.viz.data_to_pixel` holds from the start.
    """
    x0, x1, y0, y1 = check_extent(extent)
    pos = ax.get_position()
    width_px, height_px = pos.width * ax.figure.bbox.width, pos.height * ax.figure.bbox.height
    scale = max((x1 - x0) / width_px, (y1 - y0) / height_px)  # [m / px]
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    ax.set_xlim(cx - 0.5 * scale * width_px, cx + 0.5 * scale * width_px)
    ax.set_ylim(cy - 0.5 * scale * height_px, cy + 0.5 * scale * height_px)
    ax.set_autoscale_on(False)


def check_extent(extent) -> tuple[float, float, float, float]:
    """``extent`` as ``(xmin, xmax, ymin, ymax)`` floats [m]; ``ValueError`` unless finite with min < max."""
    try:
        x0, x1, y0, y1 = (float(v) for v in extent)
    except (TypeError, ValueError):
        raise ValueError(f"extent must be (xmin, xmax, ymin, ymax) in metres, got {extent!r}") from None
    if not all(np.isfinite([x0, x1, y0, y1])) or x0 >= x1 or y0 >= y1:
        raise ValueError(f"extent must be finite with xmin < xmax and ymin < ymax, got {extent!r}")
    return x0, x1, y0, y1


class SceneView:
    """A reusable figure of a recording: update it to any frame and render it to an array ("Drawing scenes" page).

    Parameters
    ----------
    tracks : pandas.DataFrame or TrackFrames   INTERACTION-format rows, `pirl_sim.viz.frames.SCENE_COLUMNS` at least
    road : Road, optional                      drawn beneath (`pirl_sim.viz.road_sources`)
    color_by, categorical, cmap, vmin, vmax, label : see `pirl_sim.viz.colors.color_rows` (None: a colour per track)
    trail_s, show_tracks, extent : float, bool, tuple or None   trail [s] (0: none); all tracks faintly; see the page
    size_px, dpi, title : tuple of int, float, str or None   figure width, height [px]; dots per inch; title

    Raises
    ------
    ValueError, TypeError
        A track table that cannot be drawn, an unknown colour column, a bad extent, size or trail length.
    """

    def __init__(self, tracks, *, road: Road | None = None, color_by=None, categorical: bool | None = None,
                 cmap: str = "viridis", vmin: float | None = None, vmax: float | None = None,
                 label: str | None = None, trail_s: float = 2.0, show_tracks: bool = False, extent=None,
                 size_px: tuple[int, int] = DEFAULT_SIZE_PX, dpi: float = DEFAULT_DPI, title: str | None = None):
        self.frames = tracks if isinstance(tracks, TrackFrames) else TrackFrames(tracks)
        if road is not None and not isinstance(road, Road):
            raise TypeError(f"road must be a pirl_sim.viz.Road or None, got {type(road).__name__}")
        if isinstance(trail_s, bool) or not isinstance(trail_s, (int, float, np.integer, np.floating)) \
                or not np.isfinite(trail_s) or trail_s < 0:
            raise ValueError(f"trail_s must be a number of seconds >= 0, got {trail_s!r}")
        self.colors = color_rows(self.frames.table, color_by, categorical=categorical, cmap=cmap, vmin=vmin,
                                 vmax=vmax, label=label)
        self._trail_frames = int(round(trail_s * 1000.0 / self.frames.dt_ms))
        self.figure: Figure = new_figure(size_px, dpi=dpi)
        ax = self.ax = road_axes(self.figure, title=title, road=road)
        if show_tracks:
            segs, start = track_segments(self.frames)
            faint = self.colors.rgba[start].copy()
            faint[:, 3] = 0.35
            ax.add_collection(LineCollection(segs, colors=faint, linewidths=0.8, zorder=2))  # type: ignore[arg-type]
        self._boxes = PolyCollection([], closed=True, edgecolors="black", linewidths=0.6, zorder=4)
        self._trails = LineCollection([], linewidths=2.0, zorder=3, capstyle="round")
        ax.add_collection(self._trails, autolim=False)
        ax.add_collection(self._boxes, autolim=False)
        place_axes(self.figure, title=bool(title), colorbar=self.colors.cmap is not None)
        explain_colors(ax, self.colors)
        self._set_extent(road, extent)
        # the clock's white box is static (background); only its short text is drawn per frame
        pos, scale = ax.get_position(), dpi / DEFAULT_DPI
        box_w = min(0.5, _CLOCK_PX[0] * scale / (pos.width * self.figure.bbox.width))
        box_h = min(0.2, _CLOCK_PX[1] * scale / (pos.height * self.figure.bbox.height))
        ax.add_patch(Rectangle((0.0, 1.0 - box_h), box_w, box_h, transform=ax.transAxes, fc="white", ec="none",
                               alpha=0.8, zorder=5))
        self._clock = ax.text(0.5 * box_w, 1.0 - 0.5 * box_h, "", transform=ax.transAxes, ha="center", va="center",
                              fontsize="small", zorder=6, clip_on=True)
        self._dynamic = (self._trails, self._boxes, self._clock)
        self._background: Any = None  # the Agg canvas's saved region
        self._background_key: tuple[tuple[int, int], float] | None = None
        self.frame: int | None = None

    def _set_extent(self, road: Road | None, extent) -> None:
        ax = self.ax
        if extent is not None:
            x0, x1, y0, y1 = check_extent(extent)
        else:
            f = self.frames
            x0, x1, y0, y1 = f.x.min(), f.x.max(), f.y.min(), f.y.max()
            if road is not None:
                rx0, ry0, rx1, ry1 = road.bounds
                x0, x1, y0, y1 = min(x0, rx0), max(x1, rx1), min(y0, ry0), max(y1, ry1)
            x0, x1, y0, y1 = x0 - _MARGIN_M, x1 + _MARGIN_M, y0 - _MARGIN_M, y1 + _MARGIN_M
        fit_equal_aspect(ax, (x0, x1, y0, y1))

    def set_frame(self, frame: int) -> SceneView:
        """Move the vehicles, trails and clock to ``frame`` (a ``frame_id`` of the recording).

        Raises
        ------
        ValueError
            If ``frame`` is outside the recording (the message names the frame range).
        TypeError
            If ``frame`` is not an integer.
        """
        f = self.frames
        rows = f.rows(frame)
        corners = box_corners(f.x[rows], f.y[rows], f.psi[rows], f.length[rows], f.width[rows])
        self._boxes.set_verts(corners)  # type: ignore[arg-type]  # an (n, 4, 2) array of polygons
        self._boxes.set_facecolor(self.colors.rgba[rows])  # type: ignore[arg-type]
        if self._trail_frames > 0:
            lines, last = track_polylines(f, f.rows_between(frame - self._trail_frames, frame))
            self._trails.set_segments(lines)
            self._trails.set_color(self.colors.rgba[last])
        self._clock.set_text(f"t = {f.time_of(frame):.1f} s")
        self.frame = int(frame)
        return self

    def render(self, frame: int | None = None) -> np.ndarray:
        """The figure at ``frame`` (default the current one) as ``(H, W, 3)`` uint8.

        The static part is drawn once and cached; each call restores it and draws only the vehicles, trails
        and clock onto it.
        """
        if frame is not None:
            self.set_frame(frame)
        if self.frame is None:
            raise ValueError(f"no frame set yet; call set_frame with a frame in "
                             f"{self.frames.first_frame}..{self.frames.last_frame}")
        canvas = self.figure.canvas
        key = (canvas.get_width_height(), self.figure.dpi)
        if self._background is None or self._background_key != key:
            for artist in self._dynamic:
                artist.set_visible(False)
            canvas.draw()
            for artist in self._dynamic:
                artist.set_visible(True)
            self._background = canvas.copy_from_bbox(self.figure.bbox)  # type: ignore[attr-defined]  # Agg canvas
            self._background_key = key
        canvas.restore_region(self._background)  # type: ignore[attr-defined]
        for artist in self._dynamic:
            self.ax.draw_artist(artist)
        return figure_to_array(self.figure, draw=False)

    def invalidate(self) -> None:
        """Forget the cached background: call after changing anything static (limits, road, legend)."""
        self._background = None


def draw_scene(tracks, frame: int, *, road: Road | None = None, color_by=None, show_tracks: bool = False,
               trail_s: float = 2.0, extent=None, size_px: tuple[int, int] = DEFAULT_SIZE_PX,
               dpi: float = DEFAULT_DPI, title: str | None = None, **color_options) -> Figure:
    """A figure of the recording at ``frame``: road, vehicles as oriented boxes, trails, legend or colour bar.

    Parameters
    ----------
    tracks : pandas.DataFrame or TrackFrames   INTERACTION-format rows
    frame : int                                a ``frame_id`` of the recording
    road, color_by, show_tracks, trail_s, extent, size_px, dpi, title : see `SceneView`
    **color_options : see `pirl_sim.viz.colors.color_rows` (``categorical``, ``cmap``, ``vmin``, ``vmax``, ``label``)

    Returns
    -------
    figure : matplotlib.figure.Figure          with an Agg canvas (`pirl_sim.viz.raster.figure_to_array`); ValueError
                                               for a frame outside the recording, an unknown column or an undrawable table
    """
    view = SceneView(tracks, road=road, color_by=color_by, show_tracks=show_tracks, trail_s=trail_s, extent=extent,
                     size_px=size_px, dpi=dpi, title=title, **color_options)
    view.set_frame(frame)
    return view.figure
