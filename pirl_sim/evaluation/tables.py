"""Markdown tables of result frames, one format for every report of the harness."""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["cell", "markdown"]


def cell(x) -> str:
    """One table cell: floats to 3 significant digits, NaN empty, anything else as ``str``."""
    if isinstance(x, float):
        return "" if np.isnan(x) else f"{x:.3g}"
    return str(x)


def markdown(df: pd.DataFrame, fmt=cell) -> str:
    """A GitHub-flavoured Markdown table of ``df`` (its columns as the header, one line per row), each value
    written by ``fmt`` (default `cell`)."""
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, row in df.iterrows():
        lines.append("| " + " | ".join(fmt(row[c]) for c in cols) + " |")
    return "\n".join(lines) + "\n"
