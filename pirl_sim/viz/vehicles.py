"""Vehicle outlines: oriented boxes from position, heading and size (pure numpy)."""

from __future__ import annotations

import numpy as np

__all__ = ["box_corners"]

# Outline of a unit vehicle in its own frame (x forward, y left), as fractions of length and width: a
# rectangle whose front corners are cut, so the heading can be seen.
_OUTLINE = np.array([[-0.5, -0.5], [0.38, -0.5], [0.5, -0.3], [0.5, 0.3], [0.38, 0.5], [-0.5, 0.5]])
_RECTANGLE = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])


def box_corners(x, y, psi, length, width, *, nose: bool = True) -> np.ndarray:
    """Outline polygons of vehicles centred at ``(x, y)`` heading ``psi`` (example: "Drawing scenes" page).

    Parameters
    ----------
    x, y : array_like            (N,) centre [m]
    psi : array_like             (N,) heading [rad], counter-clockwise from +x
    length, width : array_like   (N,) size [m], along and across the heading
    nose : bool                  cut the front corners (six vertices) so the heading shows; False: rectangles

    Returns
    -------
    corners : numpy.ndarray      (N, 6, 2) or (N, 4, 2) vertices [m], counter-clockwise (ValueError: inputs that
                                 do not broadcast to one shape (N,))
    """
    try:
        x, y, psi, length, width = np.broadcast_arrays(*(np.asarray(v, dtype=float)
                                                         for v in (x, y, psi, length, width)))
    except ValueError:
        raise ValueError("x, y, psi, length and width must have one shape (N,), got "
                         f"{[np.shape(v) for v in (x, y, psi, length, width)]}") from None
    if x.ndim != 1:
        raise ValueError(f"x, y, psi, length and width must be 1-d arrays (N,), got shape {x.shape}")
    unit = _OUTLINE if nose else _RECTANGLE
    local_x = unit[None, :, 0] * length[:, None]  # (N, V)
    local_y = unit[None, :, 1] * width[:, None]
    c, s = np.cos(psi)[:, None], np.sin(psi)[:, None]
    return np.stack([x[:, None] + c * local_x - s * local_y, y[:, None] + s * local_x + c * local_y], axis=-1)
