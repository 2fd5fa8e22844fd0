"""Small generated INTERACTION-format recordings and pixel checks shared by the viz tests."""

from __future__ import annotations

import numpy as np
import pandas as pd

from shared_sample import SAMPLE_MAP, SAMPLE_TRACKS, needs_sample  # tests/ is on sys.path (tests/conftest.py)

__all__ = ["SAMPLE_MAP", "SAMPLE_TRACKS", "needs_sample", "straight_tracks", "has_color_near"]


def straight_tracks(n_tracks: int = 3, n_frames: int = 50, *, speed: float = 5.0, spacing: float = 10.0,
                    first_frame: int = 1) -> pd.DataFrame:
    """Vehicles driving along +x on parallel lines y = spacing * i [m], ``speed`` [m/s], frames 100 ms apart."""
    rows = []
    for i in range(n_tracks):
        for k in range(n_frames):
            frame = first_frame + k
            rows.append(dict(track_id=i + 1, frame_id=frame, timestamp_ms=100 * frame, agent_type="car",
                             x=speed * 0.1 * k, y=spacing * i, vx=speed, vy=0.0, psi_rad=0.0, length=4.0, width=1.8))
    return pd.DataFrame(rows)


def has_color_near(image: np.ndarray, pixel, rgb, *, radius: int = 3, tol: float = 40.0) -> bool:
    """Whether a pixel within ``radius`` of ``pixel`` (column, row) is within ``tol`` (RGB distance) of ``rgb``."""
    col, row = (int(round(v)) for v in pixel)
    h, w = image.shape[:2]
    patch = image[max(0, row - radius):min(h, row + radius + 1), max(0, col - radius):min(w, col + radius + 1)]
    target = np.asarray(rgb[:3], dtype=float) * (255.0 if np.max(rgb[:3]) <= 1.0 else 1.0)
    return bool((np.linalg.norm(patch.astype(float) - target, axis=-1) < tol).any())
