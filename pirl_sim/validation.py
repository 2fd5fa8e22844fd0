"""Small checks shared by every module that validates user input (errors name the setting and what is allowed)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

__all__ = ["is_positive_int", "number", "int_at_least", "check_keys", "positive_int_arg", "seed_arg"]


def is_positive_int(value) -> bool:
    """True for an integer >= 1 (Python or numpy), False for bools, floats, strings and everything else."""
    return not isinstance(value, bool) and isinstance(value, (int, np.integer)) and value >= 1


def number(label: str, value, *, low: float | None = None, allow_equal: bool = True) -> float:
    """``value`` as a float, or ``ValueError`` naming ``label`` unless it is a finite number (>= ``low``, or
    > ``low`` when not ``allow_equal``; no bound when ``low`` is None)."""
    ok = not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating)) \
        and math.isfinite(value)
    if ok and low is not None:
        ok = value > low or (allow_equal and value == low)
    if not ok:
        bound = "" if low is None else f" {'>=' if allow_equal else '>'} {low:g}"
        raise ValueError(f"{label} must be a finite number{bound}, got {value!r}")
    return float(value)


def int_at_least(label: str, value, low: int) -> int:
    """``value`` as an int, or ``ValueError`` naming ``label`` unless it is an integer >= ``low``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{label} must be an integer >= {low}, got {value!r}")
    return int(value)


def check_keys(label: str, given: Mapping[str, Any], valid: Iterable[str]) -> None:
    """``ValueError`` listing the keys of ``given`` that are not ``valid``, and the valid ones."""
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


def seed_arg(text: str) -> int:
    """argparse type: a seed, an integer in [0, 2**31)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= value < 2**31:
        raise argparse.ArgumentTypeError(f"the seed must be in [0, 2**31), got {value}")
    return value
