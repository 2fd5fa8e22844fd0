"""Colours: K distinguishable colours, and colouring a track table's rows by a column or a per-track value.

:func:`color_rows` decides between a legend (labels: style names, few integers, booleans) and a colour bar
(numbers: speed, an inferred weight) and gives every row of the table its RGBA colour, computed once so that
an animation only slices it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.colors import Colormap, Normalize, to_rgba

__all__ = ["distinct_colors", "color_rows", "RowColors", "MISSING_COLOR", "SPEED"]

MISSING_COLOR = (0.6, 0.6, 0.6, 1.0)  #: RGBA of rows without a value (NaN, or a track a mapping leaves out)
SPEED = "speed"  #: colour key computed as hypot(vx, vy) [m/s] when the table has no ``speed`` column
_MAX_LEGEND = 12  # most distinct integer values still shown as a legend rather than a colour bar
# Qualitative colours at least 60 apart in RGB (0-255) from each other and 49 from the road's greys, black and
# white: tab10 without its grey, then colours from Trubetskoy's list of 20 distinct colours.
_PALETTE = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22", "#17becf",
            "#000075", "#469990", "#800000", "#808000", "#bfef45", "#f032e6", "#ffe119", "#aaffc3", "#911eb4",
            "#42d4f4"]


def distinct_colors(k: int) -> np.ndarray:
    """``k`` colours told apart by eye and by pixel value.

    Parameters
    ----------
    k : int                  how many, >= 1 (else ValueError); up to 19 from a qualitative palette (tab10 without
                             grey, then colours at least 60 apart in RGB), beyond that hues evenly spaced

    Returns
    -------
    colors : numpy.ndarray   (k, 4) RGBA in [0, 1], all different
    """
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"k must be a positive integer, got {k!r}")
    if k <= len(_PALETTE):
        return np.array([to_rgba(c) for c in _PALETTE[:k]])
    return colormaps["hsv"](np.arange(k) / k)


@dataclass(frozen=True, eq=False)
class RowColors:
    """Colours of a track table's rows and how to explain them.

    Attributes
    ----------
    rgba : numpy.ndarray
        ``(n, 4)`` RGBA per row, in the row order of the table given.
    label : str
        What the colours show (the column name), "" when they only tell tracks apart.
    legend : tuple of (str, tuple)
        Category label and its RGBA, for a legend; empty when a colour bar explains the colours.
    cmap, norm : matplotlib colormap and Normalize, or None
        For a colour bar when the colours show numbers.
    """

    rgba: np.ndarray
    label: str = ""
    legend: tuple = ()
    cmap: Colormap | None = None
    norm: Normalize | None = None


def _values(table: pd.DataFrame, color_by, label: str | None) -> tuple[pd.Series, str]:
    if isinstance(color_by, Mapping):
        if not color_by:
            raise ValueError("color_by mapping is empty; it must map track_id to a value")
        ids = table["track_id"]
        known = ids.isin(list(color_by.keys()))
        if not known.any():
            some = sorted(ids.unique().tolist())[:8]
            raise ValueError(f"color_by mapping names none of the table's tracks (its keys must be track_id values, "
                             f"such as {some})")
        values = ids.map(lambda t: color_by.get(t, np.nan))
        return values, label if label is not None else "value"
    if not isinstance(color_by, str):
        raise TypeError(f"color_by must be a column name, a mapping track_id -> value or None, got {color_by!r}")
    if color_by in table.columns:
        return table[color_by], label if label is not None else color_by
    if color_by == SPEED and {"vx", "vy"} <= set(table.columns):
        return pd.Series(np.hypot(table["vx"].to_numpy(float), table["vy"].to_numpy(float))), \
            label if label is not None else "speed [m/s]"
    allowed = list(table.columns) + ([SPEED] if {"vx", "vy"} <= set(table.columns) else [])
    raise ValueError(f"unknown colour column {color_by!r}; the table has columns {allowed}")


def color_rows(table: pd.DataFrame, color_by=None, *, categorical: bool | None = None, cmap: str = "viridis",
               vmin: float | None = None, vmax: float | None = None, label: str | None = None) -> RowColors:
    """Colour each row of a track table (ValueError / TypeError for an unknown column or a bad ``color_by``, ``cmap``).

    Parameters
    ----------
    table : pandas.DataFrame            rows with a ``track_id`` column
    color_by : str, mapping or None     None: a colour per track (no legend); a column (``"speed"``: hypot(vx, vy)
                                        [m/s]); or ``track_id -> value`` (tracks left out are grey)
    categorical : bool, optional        labels or numbers; default labels for text, booleans, integers of <= 12 values
    cmap, vmin, vmax : str, float, float   colormap and colour bar range of numbers (default the values' range)
    label : str, optional               title of the legend or colour bar; default the column name

    Returns
    -------
    colors : RowColors
    """
    n = len(table)
    if color_by is None:
        ids = table["track_id"].to_numpy()
        _, inverse = np.unique(ids, return_inverse=True)
        palette = distinct_colors(len(_PALETTE))
        return RowColors(rgba=palette[inverse % len(palette)])
    values, name = _values(table, color_by, label)
    values = values.reset_index(drop=True)
    numeric = pd.api.types.is_numeric_dtype(values) and not pd.api.types.is_bool_dtype(values)
    if categorical is None:
        present = values.dropna()
        categorical = not numeric or (pd.api.types.is_integer_dtype(present.infer_objects())
                                      and present.nunique() <= _MAX_LEGEND)
    if categorical:
        present = values.dropna()
        cats = sorted(present.unique().tolist(), key=lambda v: (str(type(v)), v))
        colours = distinct_colors(max(1, len(cats)))
        lookup = {c: tuple(colours[i]) for i, c in enumerate(cats)}
        rgba = np.array([lookup.get(v, MISSING_COLOR) if not _isna(v) else MISSING_COLOR for v in values],
                        dtype=float).reshape(n, 4)
        legend = tuple((str(c), lookup[c]) for c in cats)
        if present.size < len(values):
            legend += (("no value", MISSING_COLOR),)
        return RowColors(rgba=rgba, label=name, legend=legend)
    try:
        nums = pd.to_numeric(values, errors="raise").to_numpy(dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"colour column {name!r} holds values that are not numbers; pass categorical=True "
                         "for labels") from None
    finite = np.isfinite(nums)
    lo = float(np.min(nums[finite])) if vmin is None and finite.any() else (0.0 if vmin is None else float(vmin))
    hi = float(np.max(nums[finite])) if vmax is None and finite.any() else (1.0 if vmax is None else float(vmax))
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    try:
        colormap = colormaps[cmap]
    except KeyError:
        raise ValueError(f"unknown colormap {cmap!r}; use a matplotlib colormap name such as 'viridis'") from None
    norm = Normalize(vmin=lo, vmax=hi)
    rgba = colormap(norm(np.where(finite, nums, lo)))
    rgba[~finite] = MISSING_COLOR
    return RowColors(rgba=np.asarray(rgba, dtype=float), label=name, cmap=colormap, norm=norm)


def _isna(v) -> bool:
    try:
        return bool(pd.isna(v))
    except (TypeError, ValueError):
        return False
