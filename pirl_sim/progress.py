"""How long-running commands report progress: one way, through tqdm, on stderr.

Results go to stdout and files; what a command is doing goes to stderr, through two functions:

- `reporter` (``enabled``) returns ``say(message)``, which writes one status line ("seed 2: PIRL-kNN fitted in
  43 s ...") with ``tqdm.write``, so that a bar drawn at the same time is not broken; ``--quiet`` commands pass
  ``enabled=False``.
- `bar` (``total``, ``desc``) is a tqdm bar with an ETA: redrawn in place on a terminal, otherwise a whole line
  (`LineStream`) at most every ``every`` seconds (logs of CI jobs and ``nohup`` runs stay short and readable).

Diagnostics (details behind ``pirl-sim -v``) go through `logging` (`pirl_sim.cli.cli_logging`); warnings through
`warnings`. Nothing here prints to stdout.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

__all__ = ["reporter", "bar", "LineStream"]


class LineStream:
    """A stream that turns tqdm's in-place redraws (``\\r`` + bar + padding) into one line each, for streams that
    are not terminals (logs of CI jobs and ``nohup`` runs); blank redraws (tqdm clearing the bar) write nothing."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self.muted = False
        self._last: str | None = None

    def write(self, text: str) -> int:
        line = text.replace("\r", "").rstrip()
        if line and not self.muted and line != self._last:
            self.stream.write(line + "\n")
            self._last = line
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:
        return False


def reporter(enabled: bool = True, *, stream=None) -> Callable[[str], None]:
    """``say(message)``: a status line on ``stream`` (default sys.stderr, looked up at each call) through
    ``tqdm.write``; a no-op when not ``enabled``."""
    if not enabled:
        return lambda message: None
    from tqdm import tqdm

    def say(message: str) -> None:
        tqdm.write(str(message), file=sys.stderr if stream is None else stream)

    return say


def bar(total: int, desc: str = "", *, enabled: bool = True, initial: int = 0, unit: str = "it", stream=None,
        every: float = 5.0):
    """A tqdm bar over ``total`` items (``initial`` already done) on ``stream`` (default sys.stderr);
    ``every`` [s]: the least time between lines when the stream is not a terminal. Use as a context manager and
    call ``update(n)``; ``disable`` when not ``enabled``."""
    from tqdm import tqdm

    stream = sys.stderr if stream is None else stream
    tty = bool(getattr(stream, "isatty", lambda: False)())
    if not tty and not isinstance(stream, LineStream):
        stream = LineStream(stream)  # whole lines in logs, not tqdm's in-place redraws
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=stream, disable=not enabled,
                mininterval=0.1 if tty else every, dynamic_ncols=tty, ascii=not tty, leave=True)
