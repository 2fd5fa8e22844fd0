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
    """A figure of every track of a recording over its road, coloured by ``color_by`` (ValueError if undrawable).

    Parameters
    ----------
    tracks : pandas.DataFrame or TrackFrames   INTERACTION-format rows (`pirl_sim.viz.frames.SCENE_COLUMNS` at least)
    road, color_by : Road, optional; str, mapping or None   drawn beneath; as `pirl_sim.viz.tracks.draw_tracks`
    extent : tuple of float, optional          ``(xmin, xmax, ymin, ymax)`` [m]; default the tracks' box + 5 m, 1:1
    size_px, dpi, title, linewidth : see `pirl_sim.viz.scene.draw_scene`; the lines' width [pt]
    **color_options : see `pirl_sim.viz.colors.color_rows` (``categorical``, ``cmap``, ``vmin``, ``vmax``, ``label``)

    Returns
    -------
    figure : matplotlib.figure.Figure          with an Agg canvas
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
