"""A road whose vehicles are redrawn on each call, for simulations that render while they run.

:class:`LiveView` draws the road once (cached background) and blits oriented boxes onto it per frame, as
:class:`pirl_sim.viz.SceneView` does for a recording; the SUMO backend of ``pirl_sim/Roundabout-v0`` renders
with it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.collections import PolyCollection

from .raster import DEFAULT_DPI, DEFAULT_SIZE_PX, figure_to_array, new_figure, place_axes
from .road import Road, road_axes
from .scene import check_extent, fit_equal_aspect
from .vehicles import box_corners

__all__ = ["LiveView"]

_MARGIN_M = 5.0  # [m] around the road when the extent is automatic


class LiveView:
    """A figure of a road; `render` draws vehicles on it and returns the pixels (TypeError / ValueError if invalid).

    Parameters
    ----------
    road : Road                          drawn once, beneath the vehicles
    extent : tuple of float, optional    ``(xmin, xmax, ymin, ymax)`` [m]; default the road's bounds + 5 m, 1:1
    size_px : tuple of int               width, height [px]
    dpi : float                          dots per inch (sizes of text and lines)
    title : str, optional
    """

    def __init__(self, road: Road, *, extent=None, size_px: tuple[int, int] = DEFAULT_SIZE_PX,
                 dpi: float = DEFAULT_DPI, title: str | None = None) -> None:
        if not isinstance(road, Road):
            raise TypeError(f"road must be a pirl_sim.viz.Road, got {type(road).__name__}")
        self.figure = new_figure(size_px, dpi=dpi)
        self.ax = road_axes(self.figure, title=title, road=road)
        self._boxes = PolyCollection([], closed=True, edgecolors="black", linewidths=0.6, zorder=4)
        self.ax.add_collection(self._boxes, autolim=False)
        self._clock = self.ax.text(0.02, 0.98, "", transform=self.ax.transAxes, ha="left", va="top",
                                   fontsize="small", zorder=6, bbox={"fc": "white", "ec": "none", "alpha": 0.8})
        place_axes(self.figure, title=bool(title))
        if extent is None:
            x0, y0, x1, y1 = road.bounds
            extent = (x0 - _MARGIN_M, x1 + _MARGIN_M, y0 - _MARGIN_M, y1 + _MARGIN_M)
        fit_equal_aspect(self.ax, check_extent(extent))
        self._background: Any = None  # the Agg canvas's saved region

    def render(self, x, y, psi, length, width, colors, time: float | None = None) -> np.ndarray:
        """The road with one box per vehicle, as ``(H, W, 3)`` uint8.

        Parameters
        ----------
        x, y : array_like (N,)
            Centres [m].
        psi : array_like (N,)
            Headings [rad], counter-clockwise from +x.
        length, width : array_like (N,)
            [m].
        colors : array_like (N, 3) or (N, 4)
            RGB(A) in [0, 1].
        time : float, optional
            [s] shown in a corner.
        """
        x = np.asarray(x, dtype=float)
        colors = np.asarray(colors, dtype=float).reshape(len(x), -1)
        corners = box_corners(x, np.asarray(y, dtype=float), np.asarray(psi, dtype=float),
                              np.asarray(length, dtype=float), np.asarray(width, dtype=float))
        self._boxes.set_verts(corners)  # type: ignore[arg-type]  # an (n, 4, 2) array of polygons
        self._boxes.set_facecolor(colors)
        self._clock.set_text("" if time is None else f"t = {time:.1f} s")
        canvas = self.figure.canvas
        if self._background is None:
            self._boxes.set_visible(False)
            self._clock.set_visible(False)
            canvas.draw()
            self._boxes.set_visible(True)
            self._clock.set_visible(True)
            self._background = canvas.copy_from_bbox(self.figure.bbox)  # type: ignore[attr-defined]  # Agg canvas
        canvas.restore_region(self._background)  # type: ignore[attr-defined]
        self.ax.draw_artist(self._boxes)
        self.ax.draw_artist(self._clock)
        return figure_to_array(self.figure, draw=False)
