"""A track table indexed by frame, so that a scene at any frame is a slice, not a search.

:class:`TrackFrames` takes an INTERACTION-format table (as :func:`pirl_sim.io.interaction.read_tracks`
returns), checks the columns drawing needs and sorts the rows by frame, then track. The rows of one frame,
or of a span of frames, are then one contiguous slice of each column array.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["TrackFrames", "SCENE_COLUMNS"]

#: Columns a track table needs to be drawn: ids, time [ms], position [m], heading [rad], size [m].
SCENE_COLUMNS: tuple[str, ...] = ("track_id", "frame_id", "timestamp_ms", "x", "y", "psi_rad", "length", "width")
_FLOAT_COLUMNS = ("x", "y", "psi_rad", "length", "width")


class TrackFrames:
    """Rows of a track table sorted by ``(frame_id, track_id)``, with the row range of every frame.

    Parameters
    ----------
    tracks : pandas.DataFrame    one row per vehicle and frame with at least `SCENE_COLUMNS`, all finite, on evenly
                                 spaced frames; other columns are kept. TypeError / ValueError otherwise.

    Attributes
    ----------
    table : pandas.DataFrame                  the rows, sorted, index reset
    track_id, frame_id : numpy.ndarray        (n,) int64
    x, y, psi, length, width : numpy.ndarray  (n,) float64 [m, m, rad, m, m]
    first_frame, last_frame : int             frame range of the recording (inclusive)
    dt_ms, t0_ms : float                      time between frames (100 for one frame), time of ``first_frame`` [ms]
    """

    table: pd.DataFrame

    def __init__(self, tracks: pd.DataFrame) -> None:
        if isinstance(tracks, TrackFrames):
            tracks = tracks.table
        if not isinstance(tracks, pd.DataFrame):
            raise TypeError("tracks must be a pandas DataFrame of INTERACTION-format rows, "
                            f"got {type(tracks).__name__}")
        missing = [c for c in SCENE_COLUMNS if c not in tracks.columns]
        if missing:
            raise ValueError(f"the track table lacks column(s) {missing}; it needs {list(SCENE_COLUMNS)} "
                             f"and has {list(tracks.columns)}")
        if len(tracks) == 0:
            raise ValueError("the track table has no rows")
        for col in SCENE_COLUMNS:
            if not pd.api.types.is_numeric_dtype(tracks[col]) or pd.api.types.is_bool_dtype(tracks[col]):
                raise ValueError(f"column {col!r} must be numeric, got dtype {tracks[col].dtype}")
            if not np.isfinite(tracks[col].to_numpy(dtype=float)).all():
                raise ValueError(f"column {col!r} has values that are not finite")
        table = tracks.sort_values(["frame_id", "track_id"], kind="stable").reset_index(drop=True)
        self.table = table
        self.track_id = table["track_id"].to_numpy(dtype=np.int64)
        self.frame_id = table["frame_id"].to_numpy(dtype=np.int64)
        dup = (np.diff(self.frame_id) == 0) & (np.diff(self.track_id) == 0)
        if dup.any():
            i = int(np.argmax(dup))
            raise ValueError(f"(track_id, frame_id) = ({self.track_id[i]}, {self.frame_id[i]}) appears more than once")
        self.x, self.y, self.psi, self.length, self.width = (table[c].to_numpy(dtype=np.float64)
                                                             for c in _FLOAT_COLUMNS)
        stamps = table["timestamp_ms"].to_numpy(dtype=np.float64)
        self.first_frame, self.last_frame = int(self.frame_id[0]), int(self.frame_id[-1])
        span = self.last_frame - self.first_frame
        self.dt_ms = float((stamps[-1] - stamps[0]) / span) if span else 100.0
        if span and self.dt_ms <= 0:
            raise ValueError(f"timestamps must increase with frame_id; frames {self.first_frame}..{self.last_frame} "
                             f"span {stamps[-1] - stamps[0]:g} ms")
        self.t0_ms = float(stamps[0])
        expected = self.t0_ms + self.dt_ms * (self.frame_id - self.first_frame)
        bad = np.abs(stamps - expected) > 1e-6 * max(1.0, self.dt_ms)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"timestamp_ms {stamps[i]:g} of frame {self.frame_id[i]} does not fit evenly spaced "
                             "frames "
                             f"({self.dt_ms:g} ms apart from {self.t0_ms:g} ms at frame {self.first_frame})")
        # start[k]: first row of frame first_frame + k; rows of that frame are start[k]:start[k + 1]
        self._start = np.searchsorted(self.frame_id, np.arange(self.first_frame, self.last_frame + 2))

    def __len__(self) -> int:
        return len(self.frame_id)

    @property
    def columns(self) -> list[str]:
        """Column names of the table."""
        return list(self.table.columns)

    @property
    def time_range_s(self) -> tuple[float, float]:
        """``(start, end)`` [s]: timestamp of the first frame and of the end of the last frame."""
        return self.t0_ms / 1000.0, (self.t0_ms + self.dt_ms * (self.last_frame - self.first_frame + 1)) / 1000.0

    def check_frame(self, frame) -> int:
        """``frame`` as an int; ``ValueError`` naming the frame range unless it is a frame of the recording."""
        if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)):
            raise TypeError(f"frame must be an integer frame_id, got {frame!r}")
        if not self.first_frame <= frame <= self.last_frame:
            raise ValueError(f"frame {frame} is outside the recording: frames {self.first_frame}..{self.last_frame}")
        return int(frame)

    def rows(self, frame: int) -> slice:
        """Row slice of ``frame`` (empty where no vehicle was recorded); the frame must be in the recording."""
        k = self.check_frame(frame) - self.first_frame
        return slice(int(self._start[k]), int(self._start[k + 1]))

    def rows_between(self, first: int, last: int) -> slice:
        """Row slice of frames ``first..last`` (inclusive), clipped to the recording."""
        a = min(max(first, self.first_frame), self.last_frame + 1) - self.first_frame
        b = min(max(last + 1, self.first_frame), self.last_frame + 1) - self.first_frame
        return slice(int(self._start[a]), int(self._start[max(a, b)]))

    def frame_at(self, t_s: float) -> int:
        """The frame shown at time ``t_s`` [s]: the last one that started at or before it (clipped to the range)."""
        k = int(np.floor((t_s * 1000.0 - self.t0_ms) / self.dt_ms + 1e-9))
        return self.first_frame + min(max(k, 0), self.last_frame - self.first_frame)

    def time_of(self, frame: int) -> float:
        """Timestamp [s] of ``frame``."""
        return (self.t0_ms + self.dt_ms * (frame - self.first_frame)) / 1000.0
