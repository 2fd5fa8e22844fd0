"""The sweep's progress bar with ETA on stderr, drawn by tqdm through `pirl_sim.progress.bar` (the project's one
progress library): redrawn in place on a terminal, a line every few seconds otherwise."""

from __future__ import annotations

import sys
from typing import Any

from pirl_sim.progress import LineStream

__all__ = ["Progress", "LineStream"]


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

    def __init__(self, total: int, cached: int = 0, *, stream=None, enabled: bool = True, every: float = 5.0) -> None:
        self.total, self.cached, self.enabled, self.every = total, cached, enabled, every
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.computed = self.failed = 0
        self._bar: Any = None  # a tqdm bar (an untyped library) once started

    def start(self) -> None:
        """Start the clock (after worker start-up) and draw the bar."""
        from pirl_sim.progress import bar

        self.close()  # a bar drawn before
        stream: Any = self.stream if self.tty else LineStream(self.stream)
        stream.muted = not self.tty  # tqdm draws on creation: the first line (not a terminal) has the counts below
        self._bar = bar(self.total, "sweep", enabled=self.enabled, initial=self.done, unit="cell", stream=stream,
                        every=self.every)
        self._bar.smoothing = 0  # rate = computed cells / elapsed: cells from the store do not count for the ETA
        self._bar.bar_format = "{desc} [{bar:24}] {n_fmt}/{total_fmt} cells{postfix}, elapsed {elapsed}, ETA {remaining}"
        self._postfix()
        stream.muted = False
        self._bar.refresh()

    def update(self, *, failed: bool = False) -> None:
        if self._bar is None:
            self.start()
        self.computed += 1
        self.failed += failed
        self._postfix()
        self._bar.update(1)

    @property
    def done(self) -> int:
        return self.cached + self.computed

    def _postfix(self) -> None:
        parts = [f"{self.computed}/{self.total - self.cached} run"]
        parts += [f"{n} {what}" for n, what in ((self.cached, "from the store"), (self.failed, "failed")) if n]
        self._bar.set_postfix_str(", ".join(parts), refresh=False)

    def line(self) -> str:
        """The bar as text, e.g. ``sweep [##########--------------] 4/10 cells, 2/8 run, 2 from the store, elapsed
        00:08, ETA 00:24``."""
        return "" if self._bar is None or not self.enabled else str(self._bar)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
