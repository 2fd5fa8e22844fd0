"""Small checks shared by every module that validates user input (each caller words its own error)."""

from __future__ import annotations

import numpy as np

__all__ = ["is_positive_int"]


def is_positive_int(value) -> bool:
    """True for an integer >= 1 (Python or numpy), False for bools, floats, strings and everything else."""
    return not isinstance(value, bool) and isinstance(value, (int, np.integer)) and value >= 1
