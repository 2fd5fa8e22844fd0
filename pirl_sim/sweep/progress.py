"""A progress bar with ETA on stderr: redrawn in place on a terminal, a line every few seconds otherwise."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress", "format_duration"]


def format_duration(seconds: float) -> str:
    """``1:02:03``, ``2:03`` or ``5 s``."""
    if seconds != seconds or seconds == float("inf"):
        return "?"
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class Progress:
    """Cells done out of ``total``, with an ETA from the mean time per computed cell so far.

    Parameters
    ----------
    total : int        cells in the sweep
    cached : int       cells already in the store (counted as done, not used for the ETA)
    stream : file      default sys.stderr
    enabled : bool     False: silent
    every : float      [s] minimum time between lines when the stream is not a terminal
    """

    WIDTH = 24

    def __init__(self, total: int, cached: int = 0, *, stream=None, enabled: bool = True, every: float = 5.0) -> None:
        self.total, self.cached = total, cached
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.every = every
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.computed = self.failed = 0
        self.t0 = time.perf_counter()
        self._last = -float("inf")
        self._shown = False

    def start(self) -> None:
        """Restart the clock (after worker start-up) and draw the bar."""
        self.t0 = time.perf_counter()
        self._draw(force=True)

    def update(self, *, failed: bool = False) -> None:
        self.computed += 1
        self.failed += failed
        self._draw(force=self.done >= self.total)

    @property
    def done(self) -> int:
        return self.cached + self.computed

    def line(self) -> str:
        elapsed = time.perf_counter() - self.t0
        todo = self.total - self.cached
        remaining = self.total - self.done
        eta = elapsed / self.computed * remaining if self.computed else float("nan")
        frac = self.done / self.total if self.total else 1.0
        filled = int(round(frac * self.WIDTH))
        bar = "#" * filled + "-" * (self.WIDTH - filled)
        parts = [f"sweep [{bar}] {self.done}/{self.total} cells", f"{self.computed}/{todo} run"]
        if self.cached:
            parts.append(f"{self.cached} from the store")
        if self.failed:
            parts.append(f"{self.failed} failed")
        parts.append(f"elapsed {format_duration(elapsed)}")
        parts.append("done" if remaining == 0 else f"ETA {format_duration(eta)}")
        return ", ".join(parts)

    def _draw(self, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty:
            if force or now - self._last >= 0.1:
                self.stream.write("\r\x1b[K" + self.line())
                self.stream.flush()
                self._last, self._shown = now, True
        elif force or now - self._last >= self.every:
            print(self.line(), file=self.stream, flush=True)
            self._last = now

    def close(self) -> None:
        if self.enabled and self.tty and self._shown:
            self.stream.write("\n")
            self.stream.flush()
