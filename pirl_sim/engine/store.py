"""The result store: one small JSON file per finished cell, written atomically, keyed by config + code version.

`ResultStore` reads and writes a results directory: ``cells/<key>.json`` (one per finished cell),
``simulations/<key>/`` (a simulated scenario's recorded run, complete once its `SIMULATION_RECORD` is written),
``errors/<key>.json`` (a cell's last failure), ``sweep.json``, ``table.parquet`` / ``table.csv`` and
``recovery.parquet``. A cell's key is the sha256 of its full configuration (`pirl_sim.engine.config.Cell.spec`)
and the code version (`code_version`: the package version and a hash of `code_text` of the source files that
compute a cell, `CELL_CODE`, with a scenario's own code, `pirl_sim.experiments.spec.ScenarioSpec.code`).
`simulation_key` keys a recorded run the same way.

The layout and the keys are explained in the documentation's "Sweeps" page (the result store) and
"Architecture" page (how a cell is keyed).
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import json
import logging
from pathlib import Path

from pirl_sim.io.atomic import atomic_write_text

__all__ = ["ResultStore", "code_version", "code_text", "source_files", "simulation_key", "CELL_CODE", "NOT_CELL_CODE", "NAME_ONLY_CODE",
           "SIMULATION_RECORD"]

SIMULATION_RECORD = "simulation.json"  #: written last into a simulation's directory

log = logging.getLogger(__name__)

#: The code that computes a cell, whose source files make up the code version: modules, or packages with ``.*``
#: (the package and every module below it). Over-inclusion only costs recomputation; the test named in the
#: module doc catches a module that cells use and this list misses.
CELL_CODE: tuple[str, ...] = (
    # core maths (the package's __init__ holds its version)
    "pirl_sim", "pirl_sim.trajectory", "pirl_sim.dynamics", "pirl_sim.paths", "pirl_sim.features", "pirl_sim.model",
    "pirl_sim.population", "pirl_sim.driving", "pirl_sim.irl", "pirl_sim.receding", "pirl_sim.mpc",
    "pirl_sim.metrics", "pirl_sim.deconvolution", "pirl_sim.validation", "pirl_sim.extras",
    "pirl_sim.recovery",            # weight-recovery scores (the cells' ``weights``)
    "pirl_sim.lateral", "pirl_sim.simulate", "pirl_sim.speed_fit", "pirl_sim.joints",
    "pirl_sim.io.*",                # track and map formats (the replay and simulator scenarios read them)
    "pirl_sim.learners.*",
    "pirl_sim.scenarios.*",         # the scenario builders and simulators
    "pirl_sim.evaluation.protocols",  # protocols and scores
    "pirl_sim.evaluation.baselines",  # the kinematic baselines (pseudo-learners)
    "pirl_sim.evaluation.direct",   # the direct regression (a recorded-scenario method)
    "pirl_sim.experiments.spec",    # the experiment kinds (parameters -> data)
    "pirl_sim.experiments.simulated", "pirl_sim.experiments.recorded",
    "pirl_sim.experiments.learner_cells",  # the learner cell (fit, evaluate, recovery)
    "pirl_sim.engine.worker",       # the cell runner
    "pirl_sim.engine.store",        # where a cell finds its simulated run (and this list)
)
#: Modules inside `CELL_CODE` packages that no cell runs.
NOT_CELL_CODE: tuple[str, ...] = ()
#: Modules that cells run but whose code does not decide a result: the registry only names the kinds, whose
#: own modules are hashed (`CELL_CODE`, or a kind's ``code``), so adding a kind keeps stored cells valid.
NAME_ONLY_CODE: tuple[str, ...] = ("pirl_sim.experiments.registry",)


def _module_files(entry: str) -> dict[str, Path]:
    """{module name: source file} of one `CELL_CODE` entry."""
    pkg = entry[:-2] if entry.endswith(".*") else entry
    spec = importlib.util.find_spec(pkg)
    if spec is None or spec.origin is None:
        raise ValueError(f"CELL_CODE names {entry!r}, which is not an importable module")
    if not entry.endswith(".*"):
        return {pkg: Path(spec.origin)}
    if not spec.submodule_search_locations:
        raise ValueError(f"CELL_CODE entry {entry!r}: {pkg} is a module, not a package")
    out = {}
    for root in spec.submodule_search_locations:
        root = Path(root)  # type: ignore[assignment]
        for f in root.rglob("*.py"):  # type: ignore[attr-defined]
            if "__pycache__" in f.parts:
                continue
            parts = list(f.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([pkg, *parts])] = f
    return out


def source_files(extra: tuple[str, ...] = ()) -> list[tuple[str, Path]]:
    """The source files of `CELL_CODE` and ``extra`` (entries like `CELL_CODE`'s: a scenario's own code,
    `pirl_sim.experiments.spec.ScenarioSpec.code`), less `NOT_CELL_CODE`, as (module name, path), sorted by
    name: names do not depend on where the package is installed."""
    out: dict[str, Path] = {}
    for entry in (*CELL_CODE, *extra):
        out.update(_module_files(entry))
    for name in NOT_CELL_CODE:
        out.pop(name, None)
    return sorted(out.items())


def _strip_docstrings(tree: ast.AST) -> ast.AST:
    """``tree`` without the docstrings of its module, classes and functions (an empty body gets ``pass``)."""
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if not isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) or not body:
            continue
        first = body[0]
        if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
            node.body = body[1:] or [ast.Pass()]
    return tree


_CODE_CACHE: dict[tuple[str, int, int], bytes] = {}


def code_text(path: Path) -> bytes:
    """What of a source file counts for the code version: its syntax tree without docstrings, comments or
    layout, so that documentation edits keep stored cells valid and every change to the code does not."""
    stat = path.stat()
    key = (str(path), stat.st_mtime_ns, stat.st_size)
    if key not in _CODE_CACHE:
        tree = _strip_docstrings(ast.parse(path.read_bytes(), filename=str(path)))
        _CODE_CACHE[key] = ast.dump(tree, annotate_fields=False, include_attributes=False).encode()
    return _CODE_CACHE[key]


def code_version(extra: tuple[str, ...] = ()) -> str:
    """``<package version>+<16 hex digits of sha256 over the code of the cell code's source files>``
    (`source_files`, with a scenario's own code ``extra``; `code_text`: docstrings and comments do not count),
    from the files as they are now (workers keep the value of their first cell, the code they imported)."""
    from pirl_sim import __version__

    h = hashlib.sha256()
    for name, path in source_files(extra):
        h.update(name.encode() + b"\0" + code_text(path) + b"\0")
    return f"{__version__}+{h.hexdigest()[:16]}"


def simulation_key(scenario: str, params: dict, seed: int, version: str) -> str:
    """Key of one simulated run: sha256 of the scenario, its simulation parameters, the seed and the code version
    (32 hex digits)."""
    blob = json.dumps({"scenario": scenario, "simulation": params, "seed": seed, "code_version": version},
                      sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


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
        self.simulations_dir = self.root / "simulations"

    def simulation_dir(self, key: str) -> Path:
        return self.simulations_dir / key

    def has_simulation(self, key: str) -> bool:
        """True when the simulation ``key`` is complete (its record is written last, after a rename)."""
        return (self.simulation_dir(key) / SIMULATION_RECORD).is_file()

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
        (self.errors_dir / f"{record['key']}.json").unlink(missing_ok=True)  # its last failure, if any
        return path

    def write_error(self, key: str, record: dict) -> Path:
        return atomic_write_text(self.errors_dir / f"{key}.json", json.dumps(record, sort_keys=True, indent=1) + "\n")
