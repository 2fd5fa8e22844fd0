"""The result store: one small JSON file per finished cell, written atomically, keyed by config + code version.

Layout of a results directory::

    cells/<key>.json     one per finished cell: its full config, scores, timings, recovered weights
    errors/<key>.json    the last failure of a cell (not a result: the cell runs again next time)
    sweep.json           the sweep: config text, code version, every cell's key and labels, the command
    table.parquet/.csv   the tidy table, one row per cell (assembled from cells/)
    recovery.parquet     true vs inferred weights per test trajectory (where the truth is known)

A cell's key is the sha256 of its full configuration (`pirl_sim.sweep.config.Cell.spec`) and the code version
(`code_version`: the package version and a hash of every source file of the package, its scenarios and
learners), so a changed config or changed code never reuses an old result, and unchanged ones always do. A
file in ``cells/`` is complete or absent (`pirl_sim.io.atomic`: written beside, fsynced, renamed); a file that
does not parse (e.g. written by hand) is treated as absent and recomputed.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import logging
from pathlib import Path

from pirl_sim.io.atomic import atomic_write_text

__all__ = ["ResultStore", "code_version", "source_files"]

log = logging.getLogger(__name__)

#: packages whose sources make up the code version (scenarios and learners install as pirl_sim sub-packages)
SOURCE_PACKAGES = ("pirl_sim", "pirl_sim.scenarios", "pirl_sim.learners")


def source_files() -> list[tuple[str, Path]]:
    """Every ``*.py`` file of `SOURCE_PACKAGES` as (name independent of the install location, path), sorted."""
    out = {}
    for pkg in SOURCE_PACKAGES:
        spec = importlib.util.find_spec(pkg)
        for root in spec.submodule_search_locations or ():
            root = Path(root)
            for f in root.rglob("*.py"):
                if "__pycache__" in f.parts:
                    continue
                out[f"{pkg}/{f.relative_to(root).as_posix()}"] = f
    return sorted(out.items())


def code_version() -> str:
    """``<package version>+<16 hex digits of sha256 over the source files>``, from the files as they are now
    (a few milliseconds; workers keep the value of their first cell, the code they imported)."""
    from pirl_sim import __version__

    h = hashlib.sha256()
    for name, path in source_files():
        h.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return f"{__version__}+{h.hexdigest()[:16]}"


class ResultStore:
    """Finished cells of a results directory (see module doc).

    Parameters
    ----------
    root : path     the results directory; created on the first write
    """

    def __init__(self, root) -> None:
        self.root = Path(root)
        self.cells_dir = self.root / "cells"
        self.errors_dir = self.root / "errors"

    def path(self, key: str) -> Path:
        return self.cells_dir / f"{key}.json"

    def finished(self) -> set[str]:
        """Keys with a result file (one directory listing; a file that does not parse is found by `load`)."""
        if not self.cells_dir.is_dir():
            return set()
        return {p.stem for p in self.cells_dir.glob("*.json")}

    def load(self, key: str) -> dict | None:
        """The record of a finished cell, or None if absent or unreadable."""
        try:
            record = json.loads(self.path(key).read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as exc:
            log.warning("ignoring unreadable result %s (%s); the cell runs again", self.path(key), exc)
            return None
        if not isinstance(record, dict) or record.get("key") != key or "result" not in record:
            log.warning("ignoring malformed result %s; the cell runs again", self.path(key))
            return None
        return record

    def write(self, record: dict) -> Path:
        """Write a finished cell's record atomically (``record["key"]`` names the file)."""
        text = json.dumps(record, sort_keys=True, indent=1, allow_nan=False)
        path = atomic_write_text(self.path(record["key"]), text + "\n")
        err = self.errors_dir / f"{record['key']}.json"
        if err.exists():
            err.unlink(missing_ok=True)
        return path

    def write_error(self, key: str, record: dict) -> Path:
        return atomic_write_text(self.errors_dir / f"{key}.json", json.dumps(record, sort_keys=True, indent=1) + "\n")
