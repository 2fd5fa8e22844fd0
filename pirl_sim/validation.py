"""Small checks shared by every module that validates user input (errors name the setting and what is allowed)."""

from __future__ import annotations

import argparse
import math
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["is_positive_int", "number", "int_at_least", "check_keys", "positive_int_arg", "seed_arg", "list_arg",
           "check_output_dir", "SEED_LIMIT"]

SEED_LIMIT = 2**31  #: seeds are integers in [0, SEED_LIMIT): numpy and scikit-learn both take them


def is_positive_int(value) -> bool:
    """True for an integer >= 1 (Python or numpy), False for bools, floats, strings and everything else."""
    return (not isinstance(value, bool)  # type: ignore[return-value]
            and isinstance(value, (int, np.integer)) and value >= 1)


def number(label: str, value, *, low: float | None = None, allow_equal: bool = True, finite: bool = True) -> float:
    """``value`` as a float, or ``ValueError`` naming ``label`` unless it is a finite number (>= ``low``, or
    > ``low`` when not ``allow_equal``; no bound when ``low`` is None; ``finite=False`` also allows +-inf)."""
    ok = not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating)) \
        and (math.isfinite(value) or (not finite and not math.isnan(value)))
    if ok and low is not None:
        ok = value > low or (allow_equal and value == low)
    if not ok:
        bound = "" if low is None else f" {'>=' if allow_equal else '>'} {low:g}"
        raise ValueError(f"{label} must be a {'finite ' if finite else ''}number{bound}, got {value!r}")
    return float(value)


def int_at_least(label: str, value, low: int) -> int:
    """``value`` as an int, or ``ValueError`` naming ``label`` unless it is an integer >= ``low``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{label} must be an integer >= {low}, got {value!r}")
    return int(value)


def check_keys(label: str, given: Mapping[str, Any], valid: Iterable[str]) -> None:
    """``ValueError`` unless ``given`` is a mapping whose keys are all ``valid`` (naming the unknown ones and
    listing the valid ones)."""
    if not isinstance(given, Mapping):
        raise ValueError(f"{label} must be a table, got {given!r}")
    valid = tuple(valid)
    unknown = [k for k in given if k not in valid]
    if unknown:
        raise ValueError(f"{label}: unknown key(s) {', '.join(map(repr, unknown))}; valid keys: "
                         f"{', '.join(valid)}")


def positive_int_arg(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def positive_float_arg(text: str) -> float:
    """argparse type of numeric options (durations [s], speeds, noise): a finite number > 0 (argparse names the
    option in its error)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def list_arg(kind=float, *, low: float | None = None, empty: bool = False):
    """An argparse type for comma-separated lists: ``kind`` (``int``, ``float`` or ``str``) of each item, blank
    items skipped; numbers finite and >= ``low`` (no bound when None); no item at all (``''``) only when
    ``empty``. The parsed option is a tuple. E.g. ``list_arg(int, low=1)`` for ``--knn-k 10,20``."""
    if kind not in (int, float, str):
        raise TypeError(f"kind must be int, float or str, got {kind!r}")
    what = {int: "integers", float: "numbers", str: "names"}[kind] + ("" if low is None else f" >= {low:g}")

    def parse(text: str) -> tuple:
        try:
            values = tuple(kind(x.strip()) for x in text.split(",") if x.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}, got {text!r}") from None
        bad = kind is not str and any(not math.isfinite(v) or (low is not None and v < low) for v in values)
        if bad or (not values and not empty):
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}, got {text!r}")
        return values

    parse.__name__ = f"list of {what}"  # argparse names the type in some messages
    return parse


def seed_arg(text: str) -> int:
    """argparse type: a seed, an integer in [0, 2**31)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= value < SEED_LIMIT:
        raise argparse.ArgumentTypeError(f"the seed must be in [0, 2**31), got {value}")
    return value


def check_output_dir(path, label: str = "--out") -> Path:
    """Make sure results can be written to the directory ``path`` before any work is done: create it (and its
    parents) if missing and write and remove a probe file in it.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ValueError
        Naming ``label``, the path and the reason: it (or a parent) is an existing file, or it cannot be
        created or written to (permissions, a read-only file system, ...).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{label} {path} is an existing file, not a directory; give a directory for the results")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path, prefix=".write-probe-"):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ValueError(f"{label} {path} is not a writable directory ({reason}); give another directory") from None
    return path
