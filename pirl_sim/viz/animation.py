"""Animations of a recording over a time span, or of prediction windows as they advance: frames and files.

Video time runs at ``speed`` times the recording's time: frame ``i`` of the video shows the recording at
``start_s + i * speed / fps`` (the last recorded frame at or before it), for ``i`` in
``0 .. round((end_s - start_s) * fps / speed) - 1``. Frames are drawn by one reused
:class:`pirl_sim.viz.SceneView` (blitting on a cached background) or :class:`pirl_sim.viz.PredictionView`.

- :func:`iter_scene_frames` / :func:`render_scene_frames`: the frames as ``(H, W, 3)`` uint8 arrays;
- :func:`animate_scene`: a ``.gif`` (Pillow) or ``.mp4`` (ffmpeg) file;
- :func:`iter_prediction_frames` / :func:`animate_predictions`: the same for prediction windows.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from .frames import TrackFrames
from .prediction import PredictionView, PredictionWindow
from .raster import DEFAULT_DPI, DEFAULT_SIZE_PX, check_size
from .scene import SceneView
from .writers import check_format, check_fps, open_writer

__all__ = ["frame_schedule", "iter_scene_frames", "render_scene_frames", "animate_scene",
           "iter_prediction_frames", "render_prediction_frames", "animate_predictions", "MAX_ARRAY_BYTES"]

MAX_ARRAY_BYTES = 2 * 1024 ** 3  #: largest stack of frames the render_* functions build in memory [bytes]
_MARGIN_M = 5.0  # [m] around all windows' points in a prediction animation
_TIME_TOL_S = 1e-6  # [s] slack on the recording's time range

Progress = Callable[[int, int], object] | bool | None


def _number(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not np.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def frame_schedule(frames: TrackFrames, *, start_s: float | None = None, end_s: float | None = None,
                   fps: float = 10.0, speed: float = 1.0) -> np.ndarray:
    """The recording's frame shown at each video frame.

    Parameters
    ----------
    frames : TrackFrames
    start_s, end_s : float, optional   half-open time span [s] of the recording's own timestamps; default all of it
    fps : float                        video frames per second
    speed : float                      recording seconds per video second (1 = real time)

    Returns
    -------
    frame_ids : numpy.ndarray          (N,) int64, ``N = round((end_s - start_s) * fps / speed)``; ValueError for a
                                       span outside the recording or shorter than a video frame, or a bad fps, speed
    """
    fps = check_fps(fps)
    speed = _number("speed", speed)
    if speed <= 0:
        raise ValueError(f"speed must be a positive number (recording seconds per video second), got {speed!r}")
    t0, t1 = frames.time_range_s
    start = t0 if start_s is None else _number("start_s", start_s)
    end = t1 if end_s is None else _number("end_s", end_s)
    if start < t0 - _TIME_TOL_S or end > t1 + _TIME_TOL_S or start >= end:
        raise ValueError(f"time span {start:g}..{end:g} s is not a non-empty span of the recording, which covers "
                         f"{t0:g}..{t1:g} s (frames {frames.first_frame}..{frames.last_frame})")
    n = int(round((end - start) * fps / speed))
    if n < 1:
        raise ValueError(f"time span {start:g}..{end:g} s is shorter than one video frame at fps={fps:g}, "
                         f"speed={speed:g}")
    return np.array([frames.frame_at(start + i * speed / fps) for i in range(n)], dtype=np.int64)


def _progress(progress: Progress, total: int, desc: str):
    """``(step, close)``: call ``step(done)`` after each frame and ``close()`` at the end."""
    if progress is None or progress is False:
        return (lambda done: None), (lambda: None)
    if progress is True:
        from pirl_sim.progress import bar

        pbar = bar(total, desc, unit="frame")
        return (lambda done: pbar.update(1)), pbar.close
    if callable(progress):
        return (lambda done: progress(done, total)), (lambda: None)
    raise TypeError(f"progress must be None, a bool or a callable(done, total), got {progress!r}")


def _check_stack(n: int, size_px) -> None:
    w, h = check_size(size_px)
    need = n * w * h * 3
    if need > MAX_ARRAY_BYTES:
        raise ValueError(f"{n} frames of {w}x{h} px would take {need / 1024 ** 3:.1f} GiB (more than "
                         f"{MAX_ARRAY_BYTES / 1024 ** 3:g}); iterate over them with the iter_* function or write "
                         "a file")


def iter_scene_frames(tracks, *, start_s: float | None = None, end_s: float | None = None, fps: float = 10.0,
                      speed: float = 1.0, progress: Progress = None, size_px: tuple[int, int] = DEFAULT_SIZE_PX,
                      dpi: float = DEFAULT_DPI, **view_options) -> Iterator[np.ndarray]:
    """Frames of a recording over a time span, drawn one by one (arguments checked before the first is drawn).

    Parameters
    ----------
    tracks : pandas.DataFrame or TrackFrames   INTERACTION-format rows
    start_s, end_s, fps, speed : see `frame_schedule`
    progress : bool or callable, optional      True: a tqdm bar on stderr; a callable: ``progress(done, total)``
    size_px, dpi, **view_options : see `pirl_sim.viz.SceneView` (``road``, ``color_by``, ``trail_s``, ...)

    Yields
    ------
    frame : numpy.ndarray                      (H, W, 3) uint8, one per video frame (a new array each time)
    """
    view = SceneView(tracks, size_px=size_px, dpi=dpi, **view_options)
    schedule = frame_schedule(view.frames, start_s=start_s, end_s=end_s, fps=fps, speed=speed)
    return _iterate(schedule, view.render, progress, "drawing frames")


def _iterate(items: Sequence | np.ndarray, draw: Callable, progress: Progress, desc: str) -> Iterator[np.ndarray]:
    step, close = _progress(progress, len(items), desc)

    def frames():
        try:
            for i, item in enumerate(items):
                yield draw(item)
                step(i + 1)
        finally:
            close()

    return frames()


def render_scene_frames(tracks, **options) -> np.ndarray:
    """All frames of :func:`iter_scene_frames` (same parameters) as one ``(N, H, W, 3)`` uint8 array.

    Raises
    ------
    ValueError
        Also when the frames would take more than :data:`MAX_ARRAY_BYTES`.
    """
    frames = tracks if isinstance(tracks, TrackFrames) else TrackFrames(tracks)
    n = len(frame_schedule(frames, start_s=options.get("start_s"), end_s=options.get("end_s"),
                           fps=options.get("fps", 10.0), speed=options.get("speed", 1.0)))
    _check_stack(n, options.get("size_px", DEFAULT_SIZE_PX))
    return np.stack(list(iter_scene_frames(frames, **options)))


def animate_scene(tracks, path, *, start_s: float | None = None, end_s: float | None = None, fps: float = 10.0,
                  speed: float = 1.0, progress: Progress = None, **view_options) -> Path:
    """Write an animation of a recording over a time span (arguments checked before anything is drawn).

    Parameters
    ----------
    tracks : pandas.DataFrame or TrackFrames
    path : str or os.PathLike          ``.gif`` (Pillow) or ``.mp4`` (ffmpeg on PATH, else RuntimeError)
    start_s, end_s, fps, speed, progress, **view_options : see `iter_scene_frames`

    Returns
    -------
    path : pathlib.Path                the file written; ValueError for another suffix, a bad span, fps or option
    """
    check_format(path)
    frames = iter_scene_frames(tracks, start_s=start_s, end_s=end_s, fps=fps, speed=speed, progress=progress,
                               **view_options)
    return _write(frames, path, fps)


def _write(frames: Iterator[np.ndarray], path, fps: float) -> Path:
    with open_writer(path, fps) as writer:
        for frame in frames:
            writer.append(frame)
    return Path(path)


def _windows(windows: Iterable[PredictionWindow]) -> list[PredictionWindow]:
    out = list(windows)
    if not out:
        raise ValueError("windows is empty; give at least one PredictionWindow")
    for i, w in enumerate(out):
        if not isinstance(w, PredictionWindow):
            raise TypeError(f"windows[{i}] must be a PredictionWindow, got {type(w).__name__}")
    return out


def _union_extent(windows: list[PredictionWindow]) -> tuple[float, float, float, float]:
    pts = np.vstack([w.points() for w in windows])
    (x0, y0), (x1, y1) = pts.min(axis=0) - _MARGIN_M, pts.max(axis=0) + _MARGIN_M
    return float(x0), float(x1), float(y0), float(y1)


def iter_prediction_frames(windows: Iterable[PredictionWindow], *, repeat: int = 1, progress: Progress = None,
                           extent=None, **view_options) -> Iterator[np.ndarray]:
    """Frames of prediction windows in order, each drawn ``repeat`` times (one view, redrawn per window).

    Parameters
    ----------
    windows : iterable of PredictionWindow   e.g. one track's windows as its present advances
    repeat : int                          video frames per window
    progress : bool or callable, optional   as `iter_scene_frames`
    extent : tuple of float, optional     ``(xmin, xmax, ymin, ymax)`` [m]; default all windows' points + 5 m, fixed
    **view_options : see `pirl_sim.viz.PredictionView` (``road``, ``tracks``, ``size_px``, ``dpi``, ``title``)

    Yields
    ------
    frame : numpy.ndarray                 (H, W, 3) uint8
    """
    windows = _windows(windows)
    if isinstance(repeat, bool) or not isinstance(repeat, (int, np.integer)) or repeat < 1:
        raise ValueError(f"repeat must be a positive integer, got {repeat!r}")
    view = PredictionView(extent=_union_extent(windows) if extent is None else extent,
                          max_k=max(w.k for w in windows), **view_options)
    cache: dict[int, np.ndarray] = {}

    def draw(i: int) -> np.ndarray:
        k = i // repeat
        if k not in cache:
            cache.clear()
            cache[k] = view.render(windows[k])
        return cache[k].copy()

    return _iterate(range(len(windows) * repeat), draw, progress, "drawing predictions")


def render_prediction_frames(windows: Iterable[PredictionWindow], **options) -> np.ndarray:
    """All frames of :func:`iter_prediction_frames` (same parameters) as one ``(N, H, W, 3)`` uint8 array."""
    windows = _windows(windows)
    _check_stack(len(windows) * options.get("repeat", 1), options.get("size_px", DEFAULT_SIZE_PX))
    return np.stack(list(iter_prediction_frames(windows, **options)))


def animate_predictions(windows: Iterable[PredictionWindow], path, *, fps: float = 10.0, repeat: int = 1,
                        progress: Progress = None, **view_options) -> Path:
    """Write an animation of prediction windows (``.gif`` or ``.mp4``), ``repeat`` video frames per window.

    Raises
    ------
    ValueError
        For an unknown suffix, a bad ``fps`` or ``repeat``, or no windows.
    RuntimeError
        For ``.mp4`` without ffmpeg on PATH.
    """
    check_format(path)
    check_fps(fps)
    frames = iter_prediction_frames(windows, repeat=repeat, progress=progress, **view_options)
    return _write(frames, path, fps)
