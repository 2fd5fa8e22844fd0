"""Whole tracks as lines coloured by a column or a per-track value, explained by a legend or a colour bar."""

from __future__ import annotations

import numpy as np
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection
from matplotlib.lines import Line2D

from .colors import RowColors, color_rows
from .frames import TrackFrames

__all__ = ["draw_tracks", "explain_colors", "track_segments", "track_polylines"]


def track_segments(frames: TrackFrames, rows: slice | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Segments joining consecutive rows of each track.

    Parameters
    ----------
    frames : TrackFrames
    rows : slice, optional
        Only these rows (e.g. a span of frames); default all.

    Returns
    -------
    segments : numpy.ndarray
        ``(M, 2, 2)`` [m]: start and end point of each segment.
    start_rows : numpy.ndarray
        ``(M,)`` int, the row (index into ``frames``) each segment starts at.
    """
    rows = slice(0, len(frames)) if rows is None else rows
    idx = np.arange(len(frames))[rows]
    order = idx[np.lexsort((frames.frame_id[idx], frames.track_id[idx]))]
    same = frames.track_id[order[1:]] == frames.track_id[order[:-1]]
    a, b = order[:-1][same], order[1:][same]
    segs = np.stack([np.column_stack([frames.x[a], frames.y[a]]), np.column_stack([frames.x[b], frames.y[b]])], axis=1)
    return segs.reshape(-1, 2, 2), a


def track_polylines(frames: TrackFrames, rows: slice | None = None) -> tuple[list[np.ndarray], np.ndarray]:
    """Each track's points as one polyline (cheaper to draw than its segments, but of one colour).

    Parameters
    ----------
    frames : TrackFrames
    rows : slice, optional
        Only these rows (e.g. a span of frames); default all.

    Returns
    -------
    lines : list of numpy.ndarray
        ``(P, 2)`` [m] per track with at least two points in ``rows``, in frame order.
    last_rows : numpy.ndarray
        ``(len(lines),)`` int, the row of each line's last point.
    """
    rows = slice(0, len(frames)) if rows is None else rows
    idx = np.arange(len(frames))[rows]
    order = idx[np.lexsort((frames.frame_id[idx], frames.track_id[idx]))]
    cuts = np.flatnonzero(np.diff(frames.track_id[order]) != 0) + 1
    xy = np.column_stack([frames.x[order], frames.y[order]])
    starts = np.concatenate(([0], cuts))
    ends = np.concatenate((cuts, [len(order)]))
    keep = ends - starts >= 2
    lines = [xy[a:b] for a, b in zip(starts[keep], ends[keep])]
    return lines, order[ends[keep] - 1]


def explain_colors(ax, colors: RowColors, *, loc: str = "upper right") -> object | None:
    """Add the legend or colour bar that explains ``colors`` to ``ax``'s figure.

    Returns
    -------
    matplotlib.legend.Legend, matplotlib.colorbar.Colorbar or None
        None when the colours only tell tracks apart.
    """
    if colors.legend:
        handles = [Line2D([], [], color=rgba, lw=6) for _, rgba in colors.legend]
        return ax.legend(handles, [name for name, _ in colors.legend], title=colors.label or None, loc=loc,
                         fontsize="small", title_fontsize="small", framealpha=0.85)
    if colors.cmap is not None:
        mappable = ScalarMappable(norm=colors.norm, cmap=colors.cmap)
        return ax.figure.colorbar(mappable, ax=ax, label=colors.label, fraction=0.04, pad=0.02)
    return None


def draw_tracks(ax, tracks, *, color_by=None, categorical: bool | None = None, cmap: str = "viridis",
                vmin: float | None = None, vmax: float | None = None, label: str | None = None,
                linewidth: float = 1.5, explain: bool = True, zorder: float = 2.5) -> LineCollection:
    """Draw every track of a table as a line, coloured by ``color_by`` (a segment takes its first row's colour).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    tracks : pandas.DataFrame or TrackFrames   INTERACTION-format rows (`pirl_sim.viz.frames.SCENE_COLUMNS` at least)
    color_by, categorical, cmap, vmin, vmax, label : see `pirl_sim.viz.colors.color_rows`
    linewidth, zorder : float                  [pt]; drawing order
    explain : bool                             add a legend (labels) or colour bar (numbers)

    Returns
    -------
    lines : matplotlib.collections.LineCollection   one artist for all tracks, added to ``ax`` (ValueError: a
                                                    column is missing)
    """
    frames = tracks if isinstance(tracks, TrackFrames) else TrackFrames(tracks)
    colors = color_rows(frames.table, color_by, categorical=categorical, cmap=cmap, vmin=vmin, vmax=vmax, label=label)
    segs, start = track_segments(frames)
    coll = LineCollection(segs,  # type: ignore[arg-type]  # an (n, 2, 2) array of segments
                          colors=colors.rgba[start], linewidths=linewidth, zorder=zorder, capstyle="round")
    ax.add_collection(coll, autolim=True)
    ax.autoscale_view()
    if explain:
        explain_colors(ax, colors)
    return coll
