"""TOML configuration files read in one place: clear errors naming the file, never a traceback."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

__all__ = ["read_text", "loads", "load"]


def read_text(path, what: str) -> str:
    """The text of a TOML file.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist (the message names ``what`` and the path).
    ValueError
        The file cannot be read or is not UTF-8 text (the message names the file and the first bad byte).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {path}") from None
    except OSError as exc:
        raise ValueError(f"{what} {path}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: the {what} is not UTF-8 text (byte {exc.start}: "
                         f"{data[exc.start:exc.start + 1]!r})") from None


def loads(text: str, source: str) -> dict[str, Any]:
    """Parse TOML ``text``; ValueError naming ``source`` when it is not valid TOML or nested too deeply."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{source}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ValueError(f"{source}: not valid TOML here: arrays or tables nested too deeply") from None


def load(path, what: str) -> tuple[dict[str, Any], str]:
    """The parsed contents and the text of the TOML file ``path`` (`read_text`, `loads`)."""
    text = read_text(path, what)
    return loads(text, str(path)), text
