"""The engine's worker: run the cells of one task in a worker process and return JSON-serialisable results.

`run_cell` / `run_cells` are what executors ship to worker processes (local or Dask); they take cells' plain-JSON
specs (`pirl_sim.engine.config.Cell.spec`). Each worker limits BLAS/OpenMP to one thread before its first cell,
so a cell computes the same numbers on any executor; a worker whose code version differs from the sweep's
refuses the cell. Scenario data is cached per process (the last `CACHE_SIZE` data sets) and simulated runs are
read from the store (`run_simulation` records a missing one). A kind's own cell runner
(`pirl_sim.experiments.spec.ScenarioSpec.run_cells`) gets its cells; the others run as learner cells
(`pirl_sim.experiments.learner_cells`).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import tempfile
import time
import warnings
from collections import OrderedDict
from contextlib import contextmanager
from pathlib import Path


from pirl_sim.evaluation.protocols import Protocol
from pirl_sim.experiments.learner_cells import ONLINE_FUTURES, ONLINE_SCORES, knn_group, messages, run_learner_cells
from pirl_sim.experiments.registry import scenario_spec
from pirl_sim.io.atomic import atomic_write_text
from .store import SIMULATION_RECORD, ResultStore, code_version, simulation_key

__all__ = ["run_cell", "run_cells", "knn_group", "run_simulation", "limit_threads", "single_threaded", "warm_up",
           "CACHE_SIZE", "ONLINE_FUTURES", "ONLINE_SCORES"]

CACHE_SIZE = 3  #: scenario data sets kept per worker process

_CACHE: OrderedDict = OrderedDict()
_THREADS_LIMITED = False
_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
                "NUMEXPR_NUM_THREADS")


def limit_threads() -> None:
    """One BLAS/OpenMP thread in this process from now on (idempotent; see module doc)."""
    global _THREADS_LIMITED
    if _THREADS_LIMITED:
        return
    for var in _THREAD_VARS:
        os.environ[var] = "1"  # libraries loaded later, and child processes
    import scipy.linalg  # noqa: F401  load the BLAS and OpenMP runtimes the cells use, then limit them
    import sklearn.mixture  # noqa: F401
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
    _THREADS_LIMITED = True


@contextmanager
def single_threaded():
    """One BLAS/OpenMP thread inside the block only, for cells run in the calling process (InlineExecutor)."""
    global _THREADS_LIMITED
    if _THREADS_LIMITED:
        yield
        return
    from threadpoolctl import threadpool_limits

    import scipy.linalg  # noqa: F401
    import sklearn.mixture  # noqa: F401

    with threadpool_limits(limits=1):
        _THREADS_LIMITED = True
        try:
            yield
        finally:
            _THREADS_LIMITED = False


def warm_up(seconds: float = 0.0) -> int:
    """Import what cells use and limit threads (worker start-up, outside any cell's timing); returns the pid."""
    limit_threads()
    import pirl_sim.learners  # noqa: F401
    import pirl_sim.scenarios.passage  # noqa: F401
    import pirl_sim.scenarios.synthetic  # noqa: F401

    _worker_version()
    if seconds > 0:
        time.sleep(seconds)  # keeps this worker busy so that the next warm-up task starts another one
    return os.getpid()


_VERSION: str | None = None


def _worker_version() -> str:
    """The code version of this process: computed once, when it first runs a cell (after its imports)."""
    global _VERSION
    if _VERSION is None:
        _VERSION = code_version()
    return _VERSION


def _check_version(code_version: str | None) -> None:
    if code_version is not None and _worker_version() != code_version:
        raise RuntimeError(
            f"worker {socket.gethostname()} pid {os.getpid()} runs pirl_sim {_worker_version()}, the sweep "
            f"{code_version}: install the same code on every worker (or the sources changed while the sweep "
            "ran: run it again)"
        )


def run_simulation(scenario: str, params: dict, seed: int, out_dir: str, code_version: str | None = None) -> dict:
    """Record one run of a simulated scenario into ``out_dir`` (a directory of the store,
    `pirl_sim.engine.store.ResultStore.simulation_dir`): simulated beside it, its record written, then renamed
    into place, so the directory is complete or absent. Returns the record (``timings``: ``simulate_s``)."""
    t0 = time.perf_counter()
    limit_threads()
    _check_version(code_version)
    out = Path(out_dir)
    if (out / SIMULATION_RECORD).is_file():
        return json.loads((out / SIMULATION_RECORD).read_text(encoding="utf-8"))
    tmp = out.parent / f".{out.name}.{socket.gethostname()}.{os.getpid()}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        scenario_spec(scenario).simulate(params, seed, tmp)  # type: ignore[misc]
        record = {"scenario": scenario, "simulation": params, "seed": seed, "code_version": _worker_version(),
                  "timings": {"simulate_s": time.perf_counter() - t0},
                  "worker": {"host": socket.gethostname(), "pid": os.getpid()}}
        atomic_write_text(tmp / SIMULATION_RECORD, json.dumps(record, sort_keys=True, indent=1) + "\n")
        try:
            os.rename(tmp, out)
        except OSError:  # another worker finished the same simulation first: same bytes, keep theirs
            if not (out / SIMULATION_RECORD).is_file():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return record


def _simulation_dir(spec: dict, store_root: str | None) -> Path:
    """The recorded run a simulated scenario's cell reads: from the sweep's store (simulated now if absent, e.g.
    when a cell runs on its own), or a per-process temporary store without one."""
    global _TMP_STORE
    sim_params = scenario_spec(spec["scenario"]).simulation(spec["scenario_params"])  # type: ignore[misc]
    if store_root is None:
        if _TMP_STORE is None:
            _TMP_STORE = tempfile.TemporaryDirectory(prefix="pirl_sim-simulations-")  # type: ignore[assignment]
        store_root = _TMP_STORE.name  # type: ignore[attr-defined]
    store = ResultStore(store_root)
    key = simulation_key(spec["scenario"], sim_params, spec["seed"], _worker_version())
    if not store.has_simulation(key):
        run_simulation(spec["scenario"], sim_params, spec["seed"], str(store.simulation_dir(key)))
    return store.simulation_dir(key)


_TMP_STORE = None


def _data(spec: dict, store_root: str | None = None):
    key = json.dumps([spec["scenario"], spec["scenario_params"], spec["data_fingerprint"], spec["seed"]],
                     sort_keys=True)
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    scenario = scenario_spec(spec["scenario"])
    if scenario.simulation is not None:
        data = scenario.build(spec["scenario_params"], spec["seed"],  # type: ignore[misc]
                              _simulation_dir(spec, store_root))
    else:
        data = scenario.build(spec["scenario_params"], spec["seed"])  # type: ignore[misc]
    _CACHE[key] = data
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)
    return data


def run_cell(spec: dict, code_version: str | None = None, store_root: str | None = None) -> dict:
    """Run one cell.

    Parameters
    ----------
    spec : dict                  `pirl_sim.engine.config.Cell.spec`
    code_version : str or None   the sweep's `pirl_sim.engine.store.code_version`; other code raises RuntimeError
    store_root : str or None     the sweep's results directory, where simulated runs are (`run_simulation`)

    Returns
    -------
    dict
        ``scores`` (errors [m], weight error, ARI, counts and `ONLINE_SCORES`; None where not defined),
        ``timings`` [s], ``recovery``, ``weights`` (`pirl_sim.recovery.weight_scores`), ``warnings``, ``worker``.
        The keys: the sweeps page, The result store and resumption.
    """
    return run_cells([spec], code_version, store_root, raise_errors=True)[0]


def run_cells(specs: list[dict], code_version: str | None = None, store_root: str | None = None,
              raise_errors: bool = False) -> list[dict]:
    """Run PIRL-kNN cells that differ only in ``n_neighbors`` (`knn_group`) with one fit (or the cells of one task
    of a scenario with its own cell runner).

    The first cell fits as `run_cell` does; the others take that fitted learner with their own k
    (`pirl_sim.learners.knn.PIRLKNN.with_neighbors`: the k-independent IRL is shared, only the neighbour index
    is rebuilt), which predicts exactly as a refit would, so every cell's scores equal `run_cell`'s. Their
    ``n_warnings`` and ``warnings`` include the shared fit's warnings, as a refit's would; their ``fit_s`` is
    the time to derive the learner. A cell that fails does not stop the others (a failed fit is retried by the
    next cell; with ``raise_errors`` its error is raised: `run_cell`).

    Returns
    -------
    list of dict, one per spec in order: `run_cell`'s result, or ``{"error": "Type: message"}``
    """
    groups = {knn_group(s) for s in specs}
    custom = scenario_spec(specs[0]["scenario"]).run_cells  # a scenario's own runner groups its own tasks
    if custom is None and len(specs) > 1 and (None in groups or len(groups) != 1):
        raise ValueError("run_cells runs PIRL-kNN cells that differ only in n_neighbors")
    t_cell, cpu_cell = time.perf_counter(), time.process_time()
    limit_threads()
    _check_version(code_version)
    first = specs[0]
    protocol = Protocol(**first["protocol"])
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as data_warnings:  # a data cache miss's: not in n_warnings
            warnings.simplefilter("always")
            if custom is not None and scenario_spec(first["scenario"]).simulation is not None:
                outcomes = custom(specs, _simulation_dir(first, store_root))  # a simulated kind's own runner
            elif custom is not None:  # a kind with its own cell runner (e.g. `pirl_sim.experiments.recorded`)
                outcomes = custom(specs)
            else:
                data = _data(first, store_root)
        generate_s = time.perf_counter() - t0
        if custom is None:
            test = [t for t in data.test if t.n_steps >= protocol.steps_needed()]
            if not test:
                need = protocol.steps_needed()
                raise ValueError(f"no test trajectory has the {need} steps the {protocol.name} protocol needs")
    except Exception as exc:
        if raise_errors:
            raise
        return [{"error": f"{type(exc).__name__}: {exc}"} for _ in specs]
    if custom is not None:  # the task's time shared equally; its warnings go to every cell
        share = {"generate_s": 0.0, "cell_s": (time.perf_counter() - t_cell) / len(specs),
                 "cpu_s": (time.process_time() - cpu_cell) / len(specs)}
        return [{"scores": scores, "timings": {**share, **timings}, "recovery": None, "weights": None,
                 "warnings": messages(data_warnings), "worker": {"host": socket.gethostname(), "pid": os.getpid()}}
                for scores, timings in outcomes]
    return run_learner_cells(specs, data, test, protocol, generate_s, data_warnings, t_cell, cpu_cell,
                             raise_errors=raise_errors)
