"""Run a sweep: cells missing from the store go to an executor, each result is stored as it finishes, and
the tidy table is assembled from the store.

A killed sweep loses only the cells that were running: run the same command again and only the missing cells
run (a cell's key is its full config and the code version, see `pirl_sim.engine.store`). A cell that raises is
reported (``errors/<key>.json``, the exit status) and the others go on; it runs again next time.

Simulated scenarios (``sumo``, ``highway``): the runs the missing cells need and the store does not hold are
simulated first, each (simulation parameters, seed) once, beside the cells of the other scenarios; the cells
that read a run are submitted once the runs are done (`pirl_sim.engine.worker.run_simulation`). A simulation that
fails fails its cells. Simulations need the results directory on a file system the workers share (local
workers, or Dask workers on this machine).
"""

from __future__ import annotations

import datetime as _dt
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

from pirl_sim.io.atomic import atomic_write_bytes, atomic_write_text
from pirl_sim.progress import reporter

from .worker import ONLINE_SCORES, knn_group, run_cells, run_simulation
from .config import SweepConfig, canonical_json
from .executors import make_executor
from .progress import Progress
from pirl_sim.experiments.registry import scenario_spec
from .store import ResultStore, code_version, simulation_key

__all__ = ["SweepRun", "run_sweep", "plan_cells", "cell_keys", "assemble_table", "read_table", "weights_table",
           "TIMING_COLUMNS", "SCORE_COLUMNS", "TABLE_COLUMNS", "WEIGHT_COLUMNS"]

#: wall-clock timings [s]: differ from run to run (everything else in the table does not)
TIMING_COLUMNS = ("generate_s", "fit_s", "evaluate_s", "cell_s", "cpu_s")
SCORE_COLUMNS = ("med", "med_std", "fde", "weight_error", "ari", "n_styles", "n_train", "n_test", "n_predictions",
                 "n_warnings", *ONLINE_SCORES)  # the online protocol's (`pirl_sim.engine.worker`): empty elsewhere
TABLE_COLUMNS = ("key", "experiment", "scenario", "scenario_label", "protocol", "protocol_kind", "history_steps",
                 "horizon", "learner", "learner_label", "k", "seed", *SCORE_COLUMNS, *TIMING_COLUMNS, "scenario_params",
                 "learner_params", "code_version")
#: columns of ``weights.csv``: weight recovery per cell, free feature and true style ("all": every test history)
WEIGHT_COLUMNS = ("key", "experiment", "scenario", "scenario_label", "protocol", "learner_label", "seed", "feature",
                  "style", "n", "median_abs_log_err", "p90_abs_log_err", "spearman")
_INT_COLUMNS = ("history_steps", "horizon", "k", "seed", "n_styles", "n_train", "n_test", "n_predictions", "n_warnings",
                "k_futures")
_FLOAT_SCORES = ("med", "med_std", "fde", "weight_error", "ari", *(c for c in ONLINE_SCORES if c != "k_futures"))
#: rough relative cost of a learner's cells: long cells go first
_COST = {"cv": 0, "ca": 0, "tirl": 1, "pirl-knn": 2, "pirl-gmm": 2, "pirl-dpgmm": 3, "ppo": 20}


@dataclass
class SweepRun:
    """What `run_sweep` did.

    Attributes
    ----------
    out : Path                  results directory
    table : DataFrame           one row per finished cell (`TABLE_COLUMNS`)
    computed, cached : list of str   keys computed by this run (in the order they finished), keys found in the store
    failed : dict {key: str}    cells that raised (not in the table)
    code_version, executor : str   the code version; where the cells ran
    wall_s, startup_s : float [s]   the whole call; starting and warming up the workers
    work_s, cpu_s : float [s]   sums of the computed cells' own time (``cell_s``) and CPU time (``cpu_s``)
    simulated : list of str     simulation keys simulated by this run
    records : dict {key: dict}  the stored record of every finished cell (`pirl_sim.engine.store`)
    keys : list of str          every cell's key, in the config's order (`cell_keys`)
    """

    out: Path
    table: pd.DataFrame
    computed: list = field(default_factory=list)
    cached: list = field(default_factory=list)
    failed: dict = field(default_factory=dict)
    code_version: str = ""
    executor: str = ""
    wall_s: float = 0.0
    startup_s: float = 0.0
    work_s: float = 0.0
    cpu_s: float = 0.0
    simulated: list = field(default_factory=list)
    records: dict = field(default_factory=dict)
    keys: list = field(default_factory=list)

    def check_failed(self, what: str) -> None:
        """RuntimeError when cells failed, naming how many of ``what`` and the first error (a report template's
        run: its files need every cell); the finished cells are kept, so the same call retries the others."""
        if self.failed:
            raise RuntimeError(f"{len(self.failed)} of {what} failed (first: {next(iter(self.failed.values()))}; "
                               f"details in {self.out}/errors/); the finished cells are kept: run the same command "
                               "again to retry the others")


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _manifest(config: SweepConfig, keys: list[str], version: str, command: str | None) -> str:
    cells = [{"key": k, **c.labels(), "learner": c.learner, "scenario": c.scenario, "seed": c.seed}
             for c, k in zip(config.cells, keys)]
    return json.dumps({"name": config.name, "description": config.description, "source": config.source,
                       "command": command, "code_version": version, "n_cells": len(cells),
                       "n_unique_cells": len(set(keys)), "cells": cells, "config": config.text}, indent=1) + "\n"


def run_sweep(config: SweepConfig, out_dir, *, executor=None, workers: int | None = None, scheduler: str | None = None,
              scheduler_file=None, progress: bool = True, command: str | None = None, stream=None,
              tables: bool = True) -> SweepRun:
    """Run the cells of ``config`` that ``out_dir`` does not hold yet, then write the tables.

    Parameters
    ----------
    config, out_dir : SweepConfig, path   validated (`pirl_sim.engine.config.load_config`); results directory (created)
    executor : executor or None   of `pirl_sim.engine.executors` (kept open); None: made from the next three
    workers : int or None       local worker processes (None: the usable cores; 0: in this process)
    scheduler, scheduler_file : str or path, optional   Dask scheduler address ``tcp://HOST:PORT``, or its file
    progress, stream : bool, file   progress bar with ETA, on ``stream`` (default stderr)
    command, tables : str or None, bool   recorded in ``sweep.json``; write the tidy tables (False: only the store)

    Returns
    -------
    run : SweepRun
    """
    t_start, out = time.perf_counter(), Path(out_dir)
    store = ResultStore(out)
    version, keys, unique, records, todo = plan_cells(config, store)
    # connected first: an unreachable scheduler or workers of other versions fail before anything is written
    ex = make_executor(workers, scheduler, scheduler_file) if todo and executor is None else executor
    out.mkdir(parents=True, exist_ok=True)

    bar, startup_s, description = None, 0.0, "nothing to run"
    computed, failed, simulated = [], {}, []
    if todo:
        futures = {}
        try:
            description, t0 = ex.describe(), time.perf_counter()
            ex.warm_up()
            startup_s = time.perf_counter() - t0
            if code_version() != version:  # the sources changed while the workers started: plan again
                version, keys, unique, records, todo = plan_cells(config, store)
            atomic_write_text(out / "sweep.json", _manifest(config, keys, version, command))
            sims, waiting = _simulations(unique, todo, store, version)
            bar = Progress(len(unique), len(records), stream=stream, enabled=progress)
            extra = f" and {len(sims)} simulations" if sims else ""
            reporter(progress, stream=stream)(f"sweep {config.name!r}: {len(todo)} of {len(unique)} cells{extra} to "
                                              f"run on {description} (code {version}); results in {out}/")
            bar.start()
            root = str(out.resolve())

            def cells_done(ks, fut):
                try:
                    results = fut.result()
                except Exception as exc:  # noqa: BLE001 - a failing cell must not stop the others
                    results = [{"error": f"{type(exc).__name__}: {exc}"}] * len(ks)
                for k, res in zip(ks, results):
                    if "error" in res:
                        fail(k, res["error"])
                        continue
                    record = {"key": k, "code_version": version, "cell": unique[k].spec(), "result": res["scores"],
                              "timings": res["timings"], "recovery": res["recovery"], "weights": res.get("weights"),
                              "warnings": res["warnings"], "worker": res["worker"], "finished_at": _now()}
                    store.write(record)
                    records[k] = record
                    computed.append(k)
                    bar.update()

            def fail(k, message):
                failed[k] = message
                store.write_error(k, {"key": k, "cell": unique[k].spec(), "error": message, "at": _now(),
                                      "code_version": version})
                bar.update(failed=True)

            def submit(ks):
                return ex.submit(run_cells, [unique[k].spec() for k in ks], version, root)

            # first: the simulations, and the cells that need none (PIRL-kNN cells differing only in k: one task)
            tasks = _tasks(unique, todo)
            # an absolute directory: a Dask worker may run in another working directory
            futures.update({ex.submit(run_simulation, *sims[sk], str(store.simulation_dir(sk).resolve()), version):
                            ("sim", sk) for sk in sims})
            futures.update({submit(ks): ("cells", ks) for ks in tasks if ks[0] not in waiting})
            sim_errors = {}
            for fut in ex.as_completed(futures):
                what, k = futures[fut]
                if what == "cells":
                    cells_done(k, fut)
                    continue
                try:
                    fut.result()
                    simulated.append(k)
                except Exception as exc:  # noqa: BLE001 - its cells fail, the others go on
                    sim_errors[k] = f"simulation failed: {type(exc).__name__}: {exc}"
            # then the cells that read the simulations (those of a failed simulation fail)
            for ks in tasks:
                if waiting.get(ks[0]) in sim_errors:
                    for k in ks:
                        fail(k, sim_errors[waiting[k]])
            later = {submit(ks): ks for ks in tasks if ks[0] in waiting and waiting[ks[0]] not in sim_errors}
            futures.update(later)
            for fut in ex.as_completed(later):
                cells_done(later[fut], fut)
        except BaseException:
            for f in futures:
                f.cancel()
            if executor is None:
                ex.close(cancel=True)
            raise
        finally:
            if bar is not None:
                bar.close()
        if executor is None:
            ex.close()
    else:
        atomic_write_text(out / "sweep.json", _manifest(config, keys, version, command))

    cached, table = [k for k in records if k not in set(computed)], assemble_table(config, keys, records)
    if tables:
        _write(out / "table.parquet", table)
        _write(out / "table.csv", table)
        _write(out / "recovery.parquet", _recovery_frame(config, keys, records), keep_empty=False)
        _write(out / "weights.csv", weights_table(config, keys, records), keep_empty=False)
    work_s, cpu_s = (sum((records[k]["timings"][t] for k in computed), 0.0) for t in ("cell_s", "cpu_s"))
    return SweepRun(out, table, computed, cached, failed, version, description,
                    time.perf_counter() - t_start, startup_s, work_s, cpu_s, simulated, records, keys)


def _tasks(unique: dict, todo: list[str]) -> list[list[str]]:
    """The cells to run as tasks, in ``todo``'s order (of each task's first cell): PIRL-kNN cells that differ only
    in ``n_neighbors`` form one task (`pirl_sim.engine.worker.run_cells`: one IRL fit for the whole k-grid, smallest
    k first), every other cell its own; a scenario with a ``task_group`` groups its cells itself (the
    ``recorded`` scenario: the methods of one split seed)."""
    by_group: dict[tuple, list[str]] = {}
    for k in todo:
        group = (scenario_spec(unique[k].scenario).task_group or knn_group)(unique[k].spec())
        by_group.setdefault(("cell", k) if group is None else ("group", group), []).append(k)
    return [sorted(ks, key=lambda k: unique[k].learner_params.get("n_neighbors", 0)) for ks in by_group.values()]


def _simulations(unique: dict, todo: list[str], store: ResultStore, version: str):
    """The simulations the cells to run need and the store lacks ({simulation key: (scenario, simulation
    parameters, seed)}), and {cell key: simulation key} of those cells."""
    sims: dict[str, tuple[str, dict, int]]
    sims, waiting = {}, {}
    for k in todo:
        cell, simulation = unique[k], scenario_spec(unique[k].scenario).simulation
        if simulation is not None:
            params = simulation(cell.spec()["scenario_params"])
            sk = simulation_key(cell.scenario, params, cell.seed, version)
            if not store.has_simulation(sk):
                sims.setdefault(sk, (cell.scenario, params, cell.seed))
                waiting[k] = sk
    return sims, waiting


def plan_cells(config: SweepConfig, store: ResultStore):
    """Keys under the current code version, the stored records, and the cells to run (in submission order)."""
    version = code_version()
    keys = cell_keys(config, version)
    unique = dict(zip(keys, config.cells))  # first occurrence of every key
    present = store.finished()  # one listing; a file that does not load is not stored: its cell runs again
    records = {k: rec for k in unique if k in present and (rec := store.load(k)) is not None}
    todo = [k for k in unique if k not in records]

    data_set = {k: canonical_json([unique[k].scenario, dict(unique[k].scenario_params), unique[k].seed]) for k in todo}
    first = {d: i for i, d in enumerate(dict.fromkeys(data_set.values()))}
    todo.sort(key=lambda k: (first[data_set[k]],  # the cells of one data set together (worker caches), long ones first
                             -_COST.get(unique[k].learner, 1) * (2 if unique[k].protocol["kind"] == "rolling" else 1)))
    return version, keys, unique, records, todo


def cell_keys(config: SweepConfig, version: str) -> list[str]:
    """The key of every cell of ``config`` (in order) under the code version ``version``, or, for a scenario with
    code of its own (`pirl_sim.experiments.spec.ScenarioSpec.code`), under the version that includes it."""
    codes = {name: scenario_spec(name).code for name in {c.scenario for c in config.cells}}
    versions = {name: code_version(extra) if extra else version for name, extra in codes.items()}
    return [c.key(versions[c.scenario]) for c in config.cells]


def _finished(config: SweepConfig, keys: list[str], records: dict, part: str | None = None):
    """(cell, key, record) of the cells of ``config`` whose record is in ``records``, in config order; with
    ``part``, of those whose record has a non-empty ``part``."""
    for cell, k in zip(config.cells, keys):
        rec = records.get(k)
        if rec is not None and (part is None or rec.get(part)):
            yield cell, k, rec


def assemble_table(config: SweepConfig, keys: list[str], records: dict) -> pd.DataFrame:
    """One row per cell of ``config`` whose result is in ``records`` (key -> stored record), in config order."""
    rows = [{"key": k, "experiment": cell.experiment, "scenario": cell.scenario, "scenario_label": cell.scenario_label,
             "protocol": cell.protocol_label, "protocol_kind": cell.protocol["kind"],
             "history_steps": cell.protocol["history_steps"], "horizon": cell.protocol["horizon"],
             "learner": cell.learner, "learner_label": cell.learner_label, "k": cell.k, "seed": cell.seed,
             **{c: rec["result"].get(c) for c in SCORE_COLUMNS}, **{c: rec["timings"].get(c) for c in TIMING_COLUMNS},
             "scenario_params": canonical_json(rec["cell"]["scenario_params"]),
             "learner_params": canonical_json(rec["cell"]["learner_params"]), "code_version": rec["code_version"]}
            for cell, k, rec in _finished(config, keys, records)]
    table = pd.DataFrame(rows, columns=list(TABLE_COLUMNS))
    for c in _INT_COLUMNS:
        table[c] = pd.array(table[c].tolist(), dtype="Int64")
    for c in (*_FLOAT_SCORES, *TIMING_COLUMNS):
        table[c] = pd.to_numeric(table[c], errors="coerce").astype(float)
    return table


def _write(path: Path, frame: pd.DataFrame, keep_empty: bool = True) -> None:
    """``frame`` written atomically to ``path`` (parquet or CSV by its suffix); without rows and not
    ``keep_empty``, ``path`` removed."""
    if frame.empty and not keep_empty:
        path.unlink(missing_ok=True)
    elif path.suffix == ".parquet":
        atomic_write_bytes(path, frame.to_parquet(index=False))
    else:
        atomic_write_text(path, frame.to_csv(index=False))


def _recovery_frame(config: SweepConfig, keys: list[str], records: dict) -> pd.DataFrame:
    """True and inferred normalised weights of the cells' test histories (``recovery.parquet``)."""
    frames = []
    for cell, k, rec in _finished(config, keys, records, "recovery"):
        r = rec["recovery"]
        true, inferred = np.asarray(r["true"], dtype=float), np.asarray(r["inferred"], dtype=float)
        for j, name in enumerate(r["features"]):
            frames.append(pd.DataFrame({"key": k, "experiment": cell.experiment, "scenario_label": cell.scenario_label,
                                        "protocol": cell.protocol_label, "learner_label": cell.learner_label,
                                        "seed": cell.seed, "feature": f"{name} / {r['reference']}",
                                        "point": np.arange(len(true)), "true": true[:, j], "inferred": inferred[:, j]}))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def weights_table(config: SweepConfig, keys: list[str], records: dict) -> pd.DataFrame:
    """Weight recovery per cell, free feature and true style (`WEIGHT_COLUMNS`), from the stored records."""
    rows = [{"key": k, "experiment": cell.experiment, "scenario": cell.scenario, "scenario_label": cell.scenario_label,
             "protocol": cell.protocol_label, "learner_label": cell.learner_label, "seed": cell.seed, **w}
            for cell, k, rec in _finished(config, keys, records, "weights") for w in rec["weights"]]
    table = pd.DataFrame(rows, columns=list(WEIGHT_COLUMNS))
    for c in ("median_abs_log_err", "p90_abs_log_err", "spearman"):
        table[c] = pd.to_numeric(table[c], errors="coerce").astype(float)
    return table


def read_table(results) -> pd.DataFrame:
    """The tidy table of a results directory (``table.parquet``, else ``table.csv``) or of a table file."""
    path = Path(results)
    if path.is_dir() and template_run(path):
        return _stored_table(path)
    if path.is_dir():
        path = next((path / n for n in ("table.parquet", "table.csv")  # type: ignore[assignment]  # None: checked
                     if (path / n).exists()), None)
        if path is None:
            raise ValueError(f"{results}: no table.parquet or table.csv (run pirl-sim sweep first)")
    if not path.exists():
        raise ValueError(f"{results}: no such file or directory")
    if path.suffix not in (".parquet", ".csv"):
        raise ValueError(f"{results}: expected a results directory, table.parquet or table.csv")
    try:
        table = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    except Exception as exc:  # ParserError, EmptyDataError are ValueErrors; pyarrow's own for a damaged parquet
        if not (isinstance(exc, (OSError, ValueError)) or type(exc).__module__.startswith("pyarrow")):
            raise
        raise ValueError(f"{path}: not a readable sweep table ({type(exc).__name__}: {exc}); run pirl-sim sweep "
                         "again to rewrite it") from None
    for c in ONLINE_SCORES:  # a table written before these scores existed: empty columns
        if c not in table.columns:
            table.insert(list(TABLE_COLUMNS).index(c), c, pd.array([None] * len(table), dtype="Int64")
                         if c in _INT_COLUMNS else np.full(len(table), np.nan))
    _check_table(table, path)
    return table


def template_run(path: Path) -> bool:
    """Whether ``path`` is a report template's results directory (``pirl-sim replay``, ``reproduce``): the sweep's
    store and ``sweep.json`` without the sweep's ``table.parquet`` (a template writes tables of its own)."""
    return (path / "sweep.json").is_file() and (path / "cells").is_dir() and not (path / "table.parquet").exists()


def _stored_table(path: Path) -> pd.DataFrame:
    """The tidy table of a report template's results directory (`template_run`): the cells its ``sweep.json``
    lists whose records are in ``cells/``."""
    listed, store = json.loads((path / "sweep.json").read_text(encoding="utf-8"))["cells"], ResultStore(path)
    records = {c["key"]: rec for c in listed if (rec := store.load(c["key"])) is not None}
    cells = [SimpleNamespace(**c, protocol=records[c["key"]]["cell"]["protocol"] if c["key"] in records else None)
             for c in listed]
    return assemble_table(SimpleNamespace(cells=cells),  # type: ignore[arg-type]  # the cells are what it reads
                          [c["key"] for c in listed], records)


#: columns every row of a finished cell has (a row cut short loses the last ones)
_REQUIRED = ("key", "experiment", "scenario", "scenario_label", "protocol", "protocol_kind", "learner",
             "learner_label", "seed", "cell_s", "scenario_params", "learner_params", "code_version")
_TEXT_COLUMNS = tuple(c for c in _REQUIRED if c not in ("seed", "cell_s"))


def _check_table(table: pd.DataFrame, path: Path) -> None:
    """``ValueError`` naming the file and the first bad row unless ``table`` has every column of `TABLE_COLUMNS`,
    the required ones filled in every row, text where text belongs and numbers in the score and timing columns."""
    if missing := [c for c in TABLE_COLUMNS if c not in table.columns]:
        raise ValueError(f"{path}: not a sweep table: missing column(s) {', '.join(missing)} (expected "
                         f"{', '.join(TABLE_COLUMNS)})")
    line = 2 if path.suffix == ".csv" else None  # header = line 1 of a CSV file

    def where(i: int) -> str:
        return f"row {i}" + (f" (line {i + line})" if line else "")

    for c in _REQUIRED:
        empty = table[c].isna().to_numpy()
        if empty.any():
            raise ValueError(f"{path}: {where(int(empty.argmax()))} has no {c} (a truncated or damaged table?); run "
                             "pirl-sim sweep again to rewrite it")
    checks = [(c, "text", [not isinstance(v, str) for v in table[c]]) for c in _TEXT_COLUMNS]
    checks += [(c, "a number", pd.to_numeric(table[c], errors="coerce").isna() & table[c].notna())
               for c in (*_INT_COLUMNS, *_FLOAT_SCORES, *TIMING_COLUMNS)]
    for c, what, wrong in checks:
        if np.any(wrong):
            i = int(np.argmax(wrong))
            raise ValueError(f"{path}: {where(i)}, column {c!r}: expected {what}, found {table[c].iloc[i]!r}")
