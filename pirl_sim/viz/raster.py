"""Figures drawn off-screen with Agg, as RGB arrays, and where data points land on them.

Figures are built as ``matplotlib.figure.Figure`` with their own Agg canvas, never through ``pyplot``, so no
global backend or figure registry is touched and nothing needs closing.
"""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = ["new_figure", "figure_to_array", "data_to_pixel", "check_size", "place_axes", "DEFAULT_SIZE_PX",
           "DEFAULT_DPI"]

DEFAULT_SIZE_PX: tuple[int, int] = (800, 600)  #: [px] default figure width, height
DEFAULT_DPI = 100.0  #: [dots per inch] pixels per inch of figure size
_MIN_SIZE_PX = 16  # [px] smallest width or height of a figure


def new_figure(size_px: tuple[int, int] = DEFAULT_SIZE_PX, *, dpi: float = DEFAULT_DPI) -> Figure:
    """A figure of ``size_px`` pixels with an Agg canvas attached.

    Parameters
    ----------
    size_px : tuple of int         width and height [px], integers >= 16 (else ValueError)
    dpi : float                    dots per inch, > 0: the relative size of text and lines, not the pixel size

    Returns
    -------
    figure : matplotlib.figure.Figure   its ``canvas`` is a ``FigureCanvasAgg`` (`figure_to_array` renders it)
    """
    size = check_size(size_px)
    if isinstance(dpi, bool) or not isinstance(dpi, (int, float, np.integer, np.floating)) \
            or not np.isfinite(dpi) or dpi <= 0:
        raise ValueError(f"dpi must be a positive number, got {dpi!r}")
    fig = Figure(figsize=(size[0] / dpi, size[1] / dpi), dpi=float(dpi))
    FigureCanvasAgg(fig)
    return fig


def place_axes(fig: Figure, *, title: bool = False, colorbar: bool = False) -> None:
    """Margins for one axes with tick labels and axis labels, fixed in pixels so small figures keep them.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    title : bool
        Leave room for a title above the axes.
    colorbar : bool
        Leave room for a colour bar's tick labels on the right.
    """
    w, h = fig.bbox.width, fig.bbox.height
    scale = fig.dpi / DEFAULT_DPI  # text grows with dpi
    left, right = 68 * scale, (80 if colorbar else 12) * scale  # [px]: a colour bar, its ticks and label
    bottom, top = 42 * scale, (30 if title else 10) * scale
    fig.subplots_adjust(left=min(left / w, 0.3), right=max(1 - right / w, 0.7), bottom=min(bottom / h, 0.3),
                        top=max(1 - top / h, 0.7))


def check_size(size_px) -> tuple[int, int]:
    """``size_px`` as ``(width, height)`` ints [px]; ``ValueError`` unless two integers >= 16."""
    try:
        w, h = size_px
    except (TypeError, ValueError):
        raise ValueError(f"size_px must be (width, height) in pixels, got {size_px!r}") from None
    for name, v in (("width", w), ("height", h)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < _MIN_SIZE_PX:
            raise ValueError(f"size_px {name} must be an integer of at least {_MIN_SIZE_PX} pixels, got {v!r}")
    return int(w), int(h)


def figure_to_array(fig: Figure, *, draw: bool = True) -> np.ndarray:
    """The figure's pixels as an RGB array.

    Parameters
    ----------
    fig : matplotlib.figure.Figure   a figure with an Agg canvas (`new_figure`); else TypeError
    draw : bool                      render the whole figure first; False: the canvas buffer as it is (blitting)

    Returns
    -------
    pixels : numpy.ndarray           (H, W, 3) uint8, row 0 at the top, a copy
    """
    if not isinstance(fig, Figure):
        raise TypeError(f"fig must be a matplotlib Figure, got {type(fig).__name__}")
    canvas = fig.canvas
    if not isinstance(canvas, FigureCanvasAgg):
        raise TypeError(f"fig must have an Agg canvas (FigureCanvasAgg), got {type(canvas).__name__}; "
                        "build it with pirl_sim.viz.new_figure")
    if draw:
        canvas.draw()
    return np.array(canvas.buffer_rgba())[..., :3]


def data_to_pixel(ax, xy) -> np.ndarray:
    """Pixel positions of data points in the array `figure_to_array` returns.

    Parameters
    ----------
    ax : matplotlib.axes.Axes     the axes whose data coordinates ``xy`` are in (limits as last set)
    xy : array_like               (N, 2) or (2,) data coordinates x, y [m], finite (else ValueError)

    Returns
    -------
    pixels : numpy.ndarray        (N, 2) or (2,) float, column and row [px] (row 0 at the top): the pixel holding a
                                  point is ``array[int(row), int(col)]``
    """
    pts = np.asarray(xy, dtype=float)
    single = pts.shape == (2,)
    pts = pts.reshape(1, 2) if single else pts
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"xy must have shape (N, 2) or (2,), got {np.shape(xy)}")
    if not np.isfinite(pts).all():
        raise ValueError("xy must be finite")
    disp = ax.transData.transform(pts)
    height = ax.figure.bbox.height
    out = np.column_stack([disp[:, 0], height - disp[:, 1]])
    return out[0] if single else out
