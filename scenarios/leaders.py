"""The vehicle ahead at one instant: gap and speed from positions, headings, speeds and lengths alone.

One rule for every user of the ``headway`` feature, so that a simulated driver's cost and the learner that reads
its recording see the same vehicle ahead: among the vehicles ahead of a car (in front of it along its heading),
driving within `MAX_HEADING_DIFF_DEG` of its heading and at most ``max_lateral`` metres beside its heading line,
the nearest one bumper to bumper. :func:`frame_leaders` is that rule for the vehicles of one frame;
:func:`obstacle` turns its output into the states of `pirl_sim.dynamics.following` (gap capped at
`NO_LEADER_GAP`, also where there is none, which then drives at the car's own speed).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MAX_HEADING_DIFF_DEG", "MAX_LATERAL", "NO_LEADER_GAP", "frame_leaders", "obstacle"]

#: [deg] a vehicle ahead counts when it drives within this angle of the car's heading
MAX_HEADING_DIFF_DEG = 45.0
#: [m] a vehicle ahead counts when its centre is at most this far beside the car's heading line (a car in the
#: next lane is not in the way)
MAX_LATERAL = 2.0
#: [m] gap standing in for "no vehicle ahead" (beyond it the ``headway`` feature is zero at any roundabout speed)
NO_LEADER_GAP = 100.0


def frame_leaders(xy: np.ndarray, psi: np.ndarray, speed: np.ndarray, length: np.ndarray | None = None, *,
                  max_heading_diff_deg: float = MAX_HEADING_DIFF_DEG,
                  max_lateral: float | None = MAX_LATERAL) -> tuple[np.ndarray, np.ndarray]:
    """The nearest vehicle ahead of each of n vehicles at one instant.

    Parameters
    ----------
    xy : array (n, 2) [m]            centre positions
    psi : array (n,) [rad]           headings
    speed : array (n,) [m/s]         speeds
    length : array (n,) [m] or None  lengths: gaps bumper to bumper (NaN taken as 0); None: centre to centre
    max_heading_diff_deg : float     [deg] see the module doc
    max_lateral : float or None      [m] see the module doc (None: no limit)

    Returns
    -------
    gap : array (n,) [m]     to the vehicle ahead (inf where there is none)
    v_lead : array (n,)      its speed [m/s] (NaN where there is none)
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    n = len(xy)
    gap_out, v_out = np.full(n, np.inf), np.full(n, np.nan)
    if n < 2:
        return gap_out, v_out
    psi = np.asarray(psi, dtype=float)
    head = np.column_stack([np.cos(psi), np.sin(psi)])
    rel = xy[None, :, :] - xy[:, None, :]  # rel[i, j] = j seen from i
    gap = np.linalg.norm(rel, axis=-1)
    if length is not None:
        half = 0.5 * np.nan_to_num(np.asarray(length, dtype=float))
        gap = gap - half[:, None] - half[None, :]
    ahead = np.einsum("ijk,ik->ij", rel, head) > 0
    keep = ahead & (head @ head.T >= math.cos(math.radians(max_heading_diff_deg)))
    if max_lateral is not None:
        across = np.abs(rel[..., 1] * head[:, None, 0] - rel[..., 0] * head[:, None, 1])
        keep &= across <= max_lateral
    gap = np.where(keep, gap, np.inf)
    np.fill_diagonal(gap, np.inf)
    nearest = gap.argmin(axis=1)
    gap_out = gap[np.arange(n), nearest]
    v_out = np.where(np.isfinite(gap_out), np.asarray(speed, dtype=float)[nearest], np.nan)
    return gap_out, v_out


def obstacle(gap: np.ndarray, v_lead: np.ndarray, speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The gap [m] to the vehicle ahead capped at `NO_LEADER_GAP` (also where there is none), and its speed [m/s]
    (the car's own where there is none, so that the capped gap stays put over a prediction)."""
    gap, v_lead = np.asarray(gap, dtype=float), np.asarray(v_lead, dtype=float)
    none = ~np.isfinite(gap) | (gap > NO_LEADER_GAP)
    return np.where(none, NO_LEADER_GAP, gap), np.where(none | ~np.isfinite(v_lead), speed, v_lead)
