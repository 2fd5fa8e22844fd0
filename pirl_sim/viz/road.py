"""A road as polylines to draw (lane boundaries by marking style, lane centre lines), and drawing it.

:class:`Road` is independent of where the road came from; :mod:`pirl_sim.viz.road_sources` builds one from a
Lanelet2 map, a SUMO network or highway-env's roundabout. :func:`draw_road` puts it on an axes as three
line collections (one artist per marking style), so a road of thousands of points costs three artists.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from matplotlib.collections import LineCollection

__all__ = ["road_axes", "Road", "draw_road", "BOUNDARY_STYLES", "ROAD_COLORS"]

#: Boundary marking styles: a painted solid line or kerb, a painted dashed line, a virtual (unmarked) border.
BOUNDARY_STYLES: tuple[str, ...] = ("solid", "dashed", "virtual")
#: Colours of the road's lines by role.
ROAD_COLORS: dict[str, str] = {"solid": "#404040", "dashed": "#808080", "virtual": "#c8c8c8",
                               "centerline": "#9db8d9", "background": "#f2f2f2"}
_LINE_WIDTHS = {"solid": 1.2, "dashed": 0.9, "virtual": 0.6, "centerline": 0.6}  # [pt]
_LINE_STYLES = {"solid": "solid", "dashed": (0, (4, 4)), "virtual": (0, (1, 3)), "centerline": (0, (6, 3))}


def _polylines(lines, name: str) -> tuple[np.ndarray, ...]:
    out = []
    for i, line in enumerate(lines):
        arr = np.array(line, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < 2:
            raise ValueError(f"{name}[{i}] must be a (P, 2) polyline with P >= 2, got shape {np.shape(line)}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{name}[{i}] has coordinates that are not finite")
        arr.setflags(write=False)
        out.append(arr)
    return tuple(out)


@dataclass(frozen=True, eq=False)
class Road:
    """Lane boundaries and centre lines of a road, x, y [m] in the frame of the tracks driven on it (validated on
    construction: finite (P, 2) polylines, P >= 2, one style per boundary, at least one line).

    Attributes
    ----------
    boundaries : tuple of numpy.ndarray    lane borders, each (P, 2) [m]; a border shared by two lanes appears once
    styles : tuple of str                  one of `BOUNDARY_STYLES` per boundary
    centerlines : tuple of numpy.ndarray   lane centre lines, each (P, 2) [m], in driving direction
    source : str                           where the road came from (a file name or a description)
    """

    boundaries: tuple[np.ndarray, ...]
    styles: tuple[str, ...]
    centerlines: tuple[np.ndarray, ...] = ()
    source: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "boundaries", _polylines(self.boundaries, "boundaries"))
        object.__setattr__(self, "centerlines", _polylines(self.centerlines, "centerlines"))
        styles = tuple(self.styles)
        if len(styles) != len(self.boundaries):
            raise ValueError(f"styles must give one style per boundary: {len(styles)} styles for "
                             f"{len(self.boundaries)} boundaries")
        bad = sorted({s for s in styles if s not in BOUNDARY_STYLES}, key=str)
        if bad:
            raise ValueError(f"unknown boundary style(s) {bad}; allowed: {list(BOUNDARY_STYLES)}")
        object.__setattr__(self, "styles", styles)
        if not self.boundaries and not self.centerlines:
            raise ValueError(f"a road needs at least one boundary or centre line{self._of()}")

    def _of(self) -> str:
        return f" ({self.source})" if self.source else ""

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` [m] of every line."""
        pts = np.vstack(self.boundaries + self.centerlines)
        (x0, y0), (x1, y1) = pts.min(axis=0), pts.max(axis=0)
        return float(x0), float(y0), float(x1), float(y1)


def draw_road(ax, road: Road, *, centerlines: bool = True, zorder: float = 1.0) -> list[LineCollection]:
    """Draw a road's boundaries (by style) and, optionally, its centre lines on ``ax`` (TypeError for another road).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    road : Road
    centerlines : bool           draw the lane centre lines too (thin, dashed, light blue)
    zorder : float               drawing order of the road's lines; vehicles and tracks are drawn above 2

    Returns
    -------
    lines : list of matplotlib.collections.LineCollection   one per style present (and one for the centre lines),
        added to ``ax``, whose data limits grow to hold the road
    """
    if not isinstance(road, Road):
        raise TypeError(f"road must be a pirl_sim.viz.Road (see pirl_sim.viz.road_sources), got {type(road).__name__}")
    artists = []
    groups: list[tuple[str, Sequence[np.ndarray]]] = []
    if centerlines and road.centerlines:
        groups.append(("centerline", road.centerlines))
    for style in BOUNDARY_STYLES:
        lines: Sequence[np.ndarray] = [b for b, s in zip(road.boundaries, road.styles) if s == style]
        if lines:
            groups.append((style, lines))
    for role, lines in groups:
        coll = LineCollection(lines, colors=ROAD_COLORS[role], linewidths=_LINE_WIDTHS[role],
                              linestyles=_LINE_STYLES[role], zorder=zorder, capstyle="butt")
        ax.add_collection(coll, autolim=True)
        artists.append(coll)
    return artists


def road_axes(fig, *, title: str | None = None, road: Road | None = None):
    """The one axes of a scene figure: background, axis labels [m], small ticks, the title and the road."""
    ax = fig.add_subplot()
    ax.set_facecolor(ROAD_COLORS["background"])
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.tick_params(labelsize="small")
    if title:
        ax.set_title(title, fontsize="medium")
    if road is not None:
        draw_road(ax, road)
    return ax
