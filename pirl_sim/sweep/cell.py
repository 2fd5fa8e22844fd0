"""One sweep cell, run in a worker: scenario data -> learner.fit -> evaluate -> a JSON-serialisable result.

`run_cell` is what executors ship to worker processes (local or Dask); it takes the cell's plain-JSON spec
(`pirl_sim.sweep.config.Cell.spec`) so nothing but small dicts crosses process or machine boundaries.

- **Same numbers everywhere.** Each worker process limits BLAS/OpenMP to one thread before its first cell
  (sweeps parallelise over cells), so a cell computes the same floating-point result whichever executor,
  worker or machine runs it, and workers do not oversubscribe the cores.
- **Same code everywhere.** A worker whose code version differs from the sweep's refuses the cell: its result
  would be stored under a key that claims other code.
- **One fit per PIRL-kNN k-grid.** `run_cells` runs the PIRL-kNN cells that differ only in ``n_neighbors`` as
  one task: the IRL, which does not depend on k, is fitted once and each k gets its own neighbour index
  (`pirl_sim.learners.knn.PIRLKNN.with_neighbors`); each cell's result is what `run_cell` gives it alone.
- **Online scores (issue 14).** Under the ``online`` protocol every learner that predicts several futures
  (``predict_futures``) is also scored on `ONLINE_FUTURES` futures per test history
  (`pirl_sim.harness.experiment.evaluate` with ``n_futures``, drawn with the cell's seed): ``min_ade``,
  ``min_fde`` [m], ``miss_rate`` and ``nll`` [nats per predicted step], ``k_futures`` the number it returned;
  and every learner with a style posterior (``predict_proba``) by ``style_accuracy`` and ``style_ari`` of its
  most probable style of each test history (`_style_scores`). These scores are None elsewhere; the other scores
  of a cell do not depend on them (the draws come after the point predictions).
- **Data cache.** Scenario data is cached per process (the last `CACHE_SIZE` data sets, by scenario, parameters
  and seed): cells of one scenario on one worker generate it once. Generation is deterministic, so caching
  never changes a result, only ``generate_s``.
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

import numpy as np

from pirl_sim.harness.experiment import Protocol, cases, evaluate, style_agreement
from pirl_sim.io.atomic import atomic_write_text
from pirl_sim.metrics import adjusted_rand_index, match_styles
from pirl_sim.recovery import weight_scores

from .baselines import BASELINES
from .scenarios import scenario_spec
from .store import SIMULATION_RECORD, ResultStore, code_version, simulation_key

__all__ = ["run_cell", "run_cells", "knn_group", "run_simulation", "limit_threads", "single_threaded", "warm_up",
           "CACHE_SIZE", "ONLINE_FUTURES", "ONLINE_SCORES"]

CACHE_SIZE = 3  #: scenario data sets kept per worker process
ONLINE_FUTURES = 6  #: K futures per test history under the online protocol (the INTERACTION challenge's number)
#: scores of the online protocol only (module doc); None in the cells of other protocols and learners
ONLINE_SCORES = ("style_accuracy", "style_ari", "k_futures", "min_ade", "min_fde", "miss_rate", "nll")
MAX_RECOVERY_POINTS = 200  #: test histories whose inferred weights are kept for the recovery scatter
MAX_WARNING_MESSAGES = 10

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
    `pirl_sim.sweep.store.ResultStore.simulation_dir`): simulated beside it, its record written, then renamed
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
        scenario_spec(scenario).simulate(params, seed, tmp)
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
    sim_params = scenario_spec(spec["scenario"]).simulation(spec["scenario_params"])
    if store_root is None:
        if _TMP_STORE is None:
            _TMP_STORE = tempfile.TemporaryDirectory(prefix="pirl_sim-simulations-")
        store_root = _TMP_STORE.name
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
        data = scenario.build(spec["scenario_params"], spec["seed"], _simulation_dir(spec, store_root))
    else:
        data = scenario.build(spec["scenario_params"], spec["seed"])
    _CACHE[key] = data
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)
    return data


def _recovery(learner, test, protocol, model, style_names=()) -> tuple[dict | None, list | None]:
    """True vs inferred normalised weights of up to `MAX_RECOVERY_POINTS` test histories, and
    `pirl_sim.recovery.weight_scores` over all of them (truth permitting; learners without weights, the baselines,
    give neither)."""
    if not all("theta" in t.metadata for t in test) or isinstance(learner, tuple(BASELINES.values())):
        return None, None
    hist, _, owner = cases(test, protocol)
    inferred = learner.infer_weights(hist)
    true = np.stack([np.asarray(test[i].metadata["theta"], dtype=float) for i in owner])
    styles = (np.array([int(test[i].metadata["style"]) for i in owner])
              if all("style" in t.metadata for t in test) else None)
    scores = weight_scores(inferred, true, styles, model, style_names)
    if len(hist) > MAX_RECOVERY_POINTS:
        pick = np.unique(np.linspace(0, len(hist) - 1, MAX_RECOVERY_POINTS).astype(int))
        inferred, true = inferred[pick], true[pick]
    names = list(model.features.names)
    ref = model.features.reference_index
    keep = [j for j in range(len(names)) if j != ref]
    return {
        "features": [names[j] for j in keep],
        "reference": names[ref],
        "true": true[:, keep].tolist(),
        "inferred": inferred[:, keep].tolist(),
    }, scores


def _style_scores(learner, train, test, protocol) -> dict:
    """Style posterior of the online test histories: ``style_accuracy``, the share of test histories whose most
    probable style (``learner.predict_proba``, p(style | first ``history_steps`` steps)) is their true style,
    learned styles paired with true ones by the training labels (`pirl_sim.metrics.match_styles`: a learned
    style left unpaired is always wrong), and ``style_ari``, the adjusted Rand index of those most probable
    styles against the true styles (no pairing needed). Both None for learners without ``predict_proba`` or
    ``labels_`` and for data without true styles. A feature-space mixture predicts with its feature look-up
    (`pirl_sim.learners.gmm.PIRLGMM.predict_style`), not with this posterior: these scores rate the styles it
    learned, judged by their likelihoods."""
    none = {"style_accuracy": None, "style_ari": None}
    if (protocol.kind != "online" or not hasattr(learner, "predict_proba") or not hasattr(learner, "labels_")
            or not all("style" in t.metadata for t in (*train, *test))):
        return none
    to_true = match_styles(np.array([int(t.metadata["style"]) for t in train]), learner.labels_)
    truth = np.array([int(t.metadata["style"]) for t in test])
    guess = learner.predict_proba([t.window(0, protocol.history_steps) for t in test]).argmax(axis=1)
    paired = np.array([to_true.get(int(j), -1) for j in guess])
    return {"style_accuracy": _float(np.mean(paired == truth)), "style_ari": _float(adjusted_rand_index(truth, guess))}


def _messages(caught) -> list[str]:
    """The distinct messages of caught warnings, in order (at most `MAX_WARNING_MESSAGES`)."""
    return list(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught))[:MAX_WARNING_MESSAGES]


def _float(x):
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def run_cell(spec: dict, code_version: str | None = None, store_root: str | None = None) -> dict:
    """Run one cell.

    Parameters
    ----------
    spec : dict
        `pirl_sim.sweep.config.Cell.spec`: scenario, scenario_params, data_fingerprint, protocol (Protocol
        fields), learner, learner_params, seed.
    code_version : str or None
        The sweep's `pirl_sim.sweep.store.code_version`; a worker running other code raises RuntimeError.
    store_root : str or None
        The sweep's results directory: where simulated scenarios' recorded runs are (`run_simulation`).

    Returns
    -------
    dict
        ``scores``: med, med_std, fde [m], weight_error (median |log| ratio, None without truth), ari (None
        for learners without clusters or data without styles), n_styles, n_train, n_test, n_predictions,
        n_warnings, and the online protocol's `ONLINE_SCORES` (module doc; None elsewhere); ``timings`` [s]:
        generate_s (0 when cached), fit_s, evaluate_s (the online scores included), cell_s (wall clock), cpu_s
        (CPU time of the worker process: below cell_s when the worker waited for a core);
        ``recovery`` (see `_recovery`) or None; ``weights``: `pirl_sim.recovery.weight_scores` (per free feature,
        overall and per style) or None; ``warnings``: distinct warning messages (of the data generation
        too, when this cell generated the data); ``worker``: host, pid.
    """
    return run_cells([spec], code_version, store_root, raise_errors=True)[0]


def knn_group(spec: dict) -> str | None:
    """What PIRL-kNN cells must share to run together in `run_cells` (their spec without ``n_neighbors``, as
    JSON), or None for a cell of another learner."""
    if spec["learner"] != "pirl-knn" or "n_neighbors" not in spec["learner_params"]:
        return None
    params = {k: v for k, v in spec["learner_params"].items() if k != "n_neighbors"}
    return json.dumps({**spec, "learner_params": params}, sort_keys=True)


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
    from pirl_sim.learners import LEARNERS

    first = specs[0]
    protocol = Protocol(**first["protocol"])
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as data_warnings:  # a data cache miss's: not in n_warnings
            warnings.simplefilter("always")
            if custom is not None:  # a scenario with its own cell runner (`pirl_sim.sweep.recorded`): one task
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
                 "warnings": _messages(data_warnings), "worker": {"host": socket.gethostname(), "pid": os.getpid()}}
                for scores, timings in outcomes]
    results = []
    fitted, fit_warnings = None, []
    charged = False  # the data's generation time and warnings go to the first cell that finishes
    for spec in specs:
        try:
            params = {k: tuple(v) if isinstance(v, list) else v for k, v in spec["learner_params"].items()}
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                t0 = time.perf_counter()
                if fitted is None:
                    learner = {**LEARNERS, **BASELINES}[spec["learner"]](
                        model=data.model, **params, **protocol.learner_params())
                    learner.fit(data.train)
                    shared = []
                else:  # the same fit with another k
                    learner = fitted.with_neighbors(params["n_neighbors"])
                    shared = fit_warnings
                fit_s = time.perf_counter() - t0
                if fitted is None and len(specs) > 1:
                    fitted, fit_warnings = learner, list(caught)
                t0 = time.perf_counter()
                futures = ({"n_futures": ONLINE_FUTURES, "random_state": spec["seed"]}
                           if protocol.kind == "online" and hasattr(learner, "predict_futures") else {})
                row = evaluate(learner, test, protocol, **futures)
                row.update(_style_scores(learner, data.train, test, protocol))
                evaluate_s = time.perf_counter() - t0
                ari = style_agreement(learner, data.train)
                recovery, weight_scores = _recovery(learner, test, protocol, data.model, data.style_names)
            caught = [*shared, *caught]
        except Exception as exc:
            if raise_errors:
                raise
            results.append({"error": f"{type(exc).__name__}: {exc}"})
            t_cell, cpu_cell = time.perf_counter(), time.process_time()
            continue
        n_styles = getattr(learner, "n_styles_", 1 if spec["learner"] == "tirl" else None)
        messages = _messages([*caught, *([] if charged else data_warnings)])
        scores = {
            "med": _float(row["med"]),
            "med_std": _float(row["med_std"]),
            "fde": _float(row["fde"]),
            "weight_error": _float(row.get("weight_error")),
            "ari": _float(ari),
            "n_styles": None if n_styles is None else int(n_styles),
            "n_train": len(data.train),
            "n_test": len(test),
            "n_predictions": int(row.get("n_predictions", len(test))),
            "n_warnings": len(caught),
            **{name: _float(row.get(name)) for name in ONLINE_SCORES},
        }
        if scores["k_futures"] is not None:
            scores["k_futures"] = int(scores["k_futures"])
        results.append({
            "scores": scores,
            "timings": {"generate_s": 0.0 if charged else generate_s, "fit_s": fit_s, "evaluate_s": evaluate_s,
                        "cell_s": time.perf_counter() - t_cell, "cpu_s": time.process_time() - cpu_cell},
            "recovery": recovery,
            "weights": weight_scores,
            "warnings": messages,
            "worker": {"host": socket.gethostname(), "pid": os.getpid()},
        })
        charged = True
        t_cell, cpu_cell = time.perf_counter(), time.process_time()  # the next cell's own time
    return results
