"""Frame sinks for animations: GIF through Pillow, MP4 through the ffmpeg program.

:func:`open_writer` picks the format from the file suffix and checks what it needs before any frame is
drawn. Frames are ``(H, W, 3)`` uint8 arrays (as :meth:`pirl_sim.viz.SceneView.render` returns); the file
is written under a temporary name beside the target and renamed when complete, so an interrupted animation
leaves no truncated file under the target's name.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import IO, Any

import numpy as np

__all__ = ["FORMATS", "open_writer", "check_format", "GifWriter", "Mp4Writer", "check_fps"]

FORMATS: tuple[str, ...] = (".gif", ".mp4")  #: file suffixes animations can be written as
_NO_FFMPEG = ("writing {name}: MP4 needs the ffmpeg program on PATH and none was found; install ffmpeg "
              "(Debian: apt-get install ffmpeg) or write a .gif instead")
_FFMPEG_TIMEOUT_S = 600.0  # [s] longest wait for ffmpeg to finish encoding after the last frame


def check_fps(fps) -> float:
    """``fps`` as a float; ``ValueError`` unless a finite number of frames per second > 0."""
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) or not np.isfinite(fps) \
            or fps <= 0:
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}")
    return float(fps)


def _check_frame(frame, shape) -> np.ndarray:
    arr = np.asarray(frame)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise ValueError(f"a frame must be an (H, W, 3) uint8 RGB array, got shape {arr.shape} dtype {arr.dtype}")
    if shape is not None and arr.shape != shape:
        raise ValueError(f"all frames must have one size: got {arr.shape} after {shape}")
    return arr


class _Writer:
    """Shared part: temporary file beside the target, frame checks, context manager."""

    suffix = ""

    def __init__(self, path, fps: float) -> None:
        self.path = Path(path)
        self.fps = check_fps(fps)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=self.suffix, dir=self.path.parent)
        os.close(fd)
        self._tmp = Path(tmp)
        self.shape: tuple[int, int, int] | None = None
        self.n_frames = 0

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def append(self, frame) -> None:
        """Add one ``(H, W, 3)`` uint8 frame; all frames must have the size of the first."""
        arr = _check_frame(frame, self.shape)
        self.shape = arr.shape
        self._append(arr)
        self.n_frames += 1

    def close(self) -> Path:
        """Finish the file and move it to its name; returns the path."""
        if self.n_frames == 0:
            self.abort()
            raise ValueError(f"no frames were appended; {self.path} not written")
        self._finish()
        os.replace(self._tmp, self.path)
        return self.path

    def abort(self) -> None:
        """Stop without writing the target; remove the temporary file."""
        self._abort()
        self._tmp.unlink(missing_ok=True)

    def _append(self, arr: np.ndarray) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _finish(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _abort(self) -> None:
        pass


class GifWriter(_Writer):
    """Animated GIF through Pillow (as matplotlib's ``PillowWriter``), looping forever.

    Frames are reduced to 256 colours as they arrive (1 byte per pixel kept in memory until :meth:`close`),
    so GIF suits spans of a minute or two; use MP4 for long recordings. GIF stores frame durations in
    hundredths of a second, and Pillow merges consecutive identical frames into one longer frame.
    """

    suffix = ".gif"

    def __init__(self, path, fps: float) -> None:
        super().__init__(path, fps)
        self._frames: list[Any] = []  # PIL images

    def _append(self, arr: np.ndarray) -> None:
        from PIL import Image

        self._frames.append(Image.fromarray(arr).quantize(colors=256, method=Image.Quantize.FASTOCTREE,
                                                                      dither=Image.Dither.NONE))

    def _finish(self) -> None:
        first, *rest = self._frames
        first.save(self._tmp, format="GIF", save_all=True, append_images=rest, duration=1000.0 / self.fps, loop=0)
        self._frames = []


class Mp4Writer(_Writer):
    """H.264 MP4 through the ffmpeg program (as matplotlib's ``FFMpegWriter``): frames stream to its stdin.

    Raises
    ------
    RuntimeError
        If no ``ffmpeg`` is on PATH (checked when the writer is made), or ffmpeg fails (its message is given).
    """

    suffix = ".mp4"

    def __init__(self, path, fps: float) -> None:
        exe = shutil.which("ffmpeg")
        if exe is None:
            raise RuntimeError(_NO_FFMPEG.format(name=Path(path).name))
        self._exe: str = exe
        super().__init__(path, fps)
        self._proc: subprocess.Popen[bytes] | None = None
        self._log: IO[bytes] | None = None

    def _append(self, arr: np.ndarray) -> None:
        if self._proc is None:
            h, w = arr.shape[:2]
            self._log = tempfile.TemporaryFile()
            cmd = [self._exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
                   "-r", f"{self.fps:g}", "-i", "-", "-an", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                   "-c:v", "libx264", "-preset", "veryfast", "-pix_fmt", "yuv420p", "-f", "mp4", str(self._tmp)]
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._log)
        assert self._proc.stdin is not None  # stdin=PIPE
        try:
            self._proc.stdin.write(np.ascontiguousarray(arr).tobytes())
        except BrokenPipeError:
            self._fail()

    def _finish(self) -> None:
        assert self._proc is not None and self._proc.stdin is not None and self._log is not None  # a frame came
        self._proc.stdin.close()
        self._proc.wait(timeout=_FFMPEG_TIMEOUT_S)
        if self._proc.returncode != 0:
            self._fail()
        self._log.close()

    def _fail(self) -> None:
        assert self._proc is not None and self._log is not None  # ffmpeg was started
        self._proc.kill()
        self._proc.wait()
        self._log.seek(0)
        message = self._log.read().decode(errors="replace").strip()[-2000:]
        self._log.close()
        self._tmp.unlink(missing_ok=True)
        raise RuntimeError(f"ffmpeg failed writing {self.path} (exit code {self._proc.returncode}): {message}")

    def _abort(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        if self._log is not None:
            self._log.close()


def check_format(path) -> str:
    """The animation format of ``path`` (``".gif"`` or ``".mp4"``), checked before anything is drawn.

    Raises
    ------
    ValueError
        If the suffix is not one of :data:`FORMATS`.
    RuntimeError
        For ``.mp4`` when no ``ffmpeg`` is on PATH.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"cannot write an animation as {Path(path).name!r}: the suffix must be one of {list(FORMATS)}")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise RuntimeError(_NO_FFMPEG.format(name=Path(path).name))
    return suffix


def open_writer(path, fps: float) -> GifWriter | Mp4Writer:
    """A frame writer for ``path``, by its suffix.

    Parameters
    ----------
    path : str or os.PathLike     target file, ``.gif`` or ``.mp4`` (case-insensitive); its folder is created
    fps : float                   frames per second of the animation, > 0

    Returns
    -------
    writer : GifWriter or Mp4Writer
        A context manager; ``append(frame)`` each (H, W, 3) uint8 frame. ValueError for another suffix (`FORMATS`)
        or a bad ``fps``, RuntimeError for ``.mp4`` without ffmpeg on PATH.
    """
    suffix = check_format(path)
    check_fps(fps)
    return GifWriter(path, fps) if suffix == ".gif" else Mp4Writer(path, fps)
