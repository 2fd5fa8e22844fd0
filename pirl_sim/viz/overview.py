"""A whole recording on one figure: the road and every track as a line coloured by a column."""

from __future__ import annotations

from matplotlib.figure import Figure

from .colors import color_rows
from .frames import TrackFrames
from .raster import DEFAULT_DPI, DEFAULT_SIZE_PX, new_figure, place_axes
from .road import Road, draw_road, road_axes
from .scene import check_extent, fit_equal_aspect
from .tracks import draw_tracks

__all__ = ["draw_recording"]

_MARGIN_M = 5.0  # [m] around the tracks when the extent is automatic


def draw_recording(tracks, *, road: Road | None = None, color_by=None, extent=None,
                   size_px: tuple[int, int] = DEFAULT_SIZE_PX, dpi: float = DEFAULT_DPI, title: str | None = None,
                   linewidth: float = 1.2, **color_options) -> Figure:
    """A figure of every track of a recording over its road, coloured by ``color_by``.

    Parameters
    ----------
    tracks : pandas.DataFrame or TrackFrames
        INTERACTION-format rows (:data:`pirl_sim.viz.frames.SCENE_COLUMNS` at least).
    road : Road, optional
        Drawn beneath.
    color_by : str, mapping or None
        As :func:`pirl_sim.viz.draw_tracks`: None, a column (``"speed"`` from ``vx``, ``vy``), or a mapping
        ``track_id -> value`` (a style label, an inferred weight); explained by a legend or a colour bar.
    extent : tuple of float, optional
        ``(xmin, xmax, ymin, ymax)`` [m]; default the tracks' bounding box with a 5 m margin (1:1 aspect).
    size_px, dpi, title
        As :func:`pirl_sim.viz.draw_scene`.
    linewidth : float
        [pt].
    **color_options
        ``categorical``, ``cmap``, ``vmin``, ``vmax``, ``label`` of :func:`pirl_sim.viz.colors.color_rows`.

    Returns
    -------
    matplotlib.figure.Figure
        With an Agg canvas.

    Raises
    ------
    ValueError
        If ``color_by`` names a column the table lacks (the message lists the columns), or the table cannot be
        drawn.
    """
    frames = tracks if isinstance(tracks, TrackFrames) else TrackFrames(tracks)
    if road is not None and not isinstance(road, Road):
        raise TypeError(f"road must be a pirl_sim.viz.Road or None, got {type(road).__name__}")
    fig = new_figure(size_px, dpi=dpi)
    ax = road_axes(fig, title=title, road=None)
    colorbar = color_rows(frames.table, color_by, **color_options).cmap is not None
    place_axes(fig, title=bool(title), colorbar=colorbar)
    if road is not None:
        draw_road(ax, road)
    draw_tracks(ax, frames, color_by=color_by, linewidth=linewidth, **color_options)
    if extent is None:
        extent = (frames.x.min() - _MARGIN_M, frames.x.max() + _MARGIN_M, frames.y.min() - _MARGIN_M,
                  frames.y.max() + _MARGIN_M)
    fit_equal_aspect(ax, check_extent(extent))
    return fig
