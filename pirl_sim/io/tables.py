"""Reading CSV tables of a recording (e.g. ``driver_steps.csv``) with errors that name the file, line and column.

`read_csv_table` is `pandas.read_csv` with declared column types; where pandas would say "Bool column has NA
values in column 3" or "invalid literal for int()", it raises a ValueError naming the file, the 1-based line of
the text (the header is line 1), the column by name and the value found.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["read_csv_table"]

_BOOL_TEXT = {"true", "false", "1", "0"}


def read_csv_table(path, dtype: dict | None = None) -> pd.DataFrame:
    """``pandas.read_csv(path, dtype=dtype)`` of a UTF-8 CSV file with a header line.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        The file is not UTF-8, empty, not CSV, or a value does not have its column's declared type (bool: True or
        False; integers; floats); the message names the file and, for a value, its line and column.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"table not found: {path}")
    try:
        return pd.read_csv(path, dtype=dtype, encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text ({exc.reason} at byte offset {exc.start})") from None
    except pd.errors.EmptyDataError:
        raise ValueError(f"{path}: the file is empty (no header line)") from None
    except pd.errors.ParserError as exc:
        raise ValueError(f"{path}: malformed CSV: {exc}") from None
    except (ValueError, TypeError, OverflowError) as exc:
        raise ValueError(_diagnose(path, dtype or {}, exc)) from None


def _diagnose(path: Path, dtype: dict, exc: Exception) -> str:
    """The first value that does not have its column's type, as 'file: line N, column 'c': ...'."""
    text = pd.read_csv(path, dtype=str, keep_default_na=False, encoding="utf-8")
    for name, kind in dtype.items():
        if name not in text.columns:
            continue
        kind = np.dtype(kind)
        for i, value in enumerate(text[name].tolist()):
            if not _fits(value, kind):
                shown = "an empty value" if not value.strip() else repr(value)
                expected = {"b": "True or False", "i": "an integer", "u": "an integer"}.get(kind.kind, "a number")
                return f"{path}: line {i + 2}, column '{name}': expected {expected}, found {shown}"
    return f"{path}: {exc}"


def _fits(value: str, kind: np.dtype) -> bool:
    v = value.strip()
    if kind.kind == "b":
        return v.lower() in _BOOL_TEXT
    try:
        if kind.kind in "iu":
            int(v)
        elif kind.kind == "f":
            float(v) if v else None
        return True
    except ValueError:
        return False
