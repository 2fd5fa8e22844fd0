"""TOML configuration files read in one place: clear errors naming the file, never a traceback."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

__all__ = ["read_text", "loads", "load", "MAX_DEPTH"]

MAX_DEPTH = 64  #: the deepest nesting of arrays and tables read (a configuration needs a handful of levels)


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
    """Parse TOML ``text``; ValueError naming ``source`` when it is not valid TOML or its arrays and tables are
    nested deeper than `MAX_DEPTH` levels (whatever the stack depth of the caller)."""
    too_deep = f"{source}: arrays or tables nested deeper than {MAX_DEPTH} levels (at most {MAX_DEPTH} are read)"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{source}: not valid TOML: {exc}") from None
    except RecursionError:  # tomllib recurses once or twice per level: hundreds of levels
        raise ValueError(too_deep) from None
    todo = [(data, 1)]
    while todo:  # without recursion: the checks that follow walk the values recursively
        value, depth = todo.pop()
        if depth > MAX_DEPTH:
            raise ValueError(too_deep)
        items = value.values() if isinstance(value, dict) else value
        todo.extend((v, depth + 1) for v in items if isinstance(v, (dict, list)))  # type: ignore[misc]
    return data


def load(path, what: str) -> tuple[dict[str, Any], str]:
    """The parsed contents and the text of the TOML file ``path`` (`read_text`, `loads`)."""
    text = read_text(path, what)
    return loads(text, str(path)), text
