"""Where cells run: one small interface over local worker processes, Dask distributed, and the calling process.

The sweep loop (`pirl_sim.engine.run.run_sweep`) only uses ``submit(fn, *args) -> future``,
``as_completed(futures)`` (yields futures as they finish), ``future.result()``, ``warm_up()`` and ``close()``,
which `concurrent.futures` and `dask.distributed` both provide; so the same loop drives both:

- `LocalExecutor`: a `concurrent.futures.ProcessPoolExecutor` with the *spawn* start method (libsumo allows
  one simulation per process, and spawned workers share no state with the parent); each worker ends itself
  when the process that started it dies, even by SIGKILL (`watch_parent`), so no orphan keeps computing;
- `DaskExecutor`: a `dask.distributed.Client` connected to a scheduler (``tcp://HOST:PORT``, or the scheduler
  file ``dask scheduler --scheduler-file`` wrote; workers on any number of machines, each with pirl_sim installed
  at the same code version and the same numerical packages, checked on connecting: `check_worker_versions`;
  start them with ``--nthreads 1``, one cell per process), or to a client you made (a ``LocalCluster`` in tests);
- `InlineExecutor`: runs the cells one by one in the calling process (``--workers 0``; debugging).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing
import os
import re
import sys
import threading
import time
from contextlib import suppress

from pirl_sim.extras import install_hint
from pirl_sim.validation import int_at_least, number

from . import worker as cell

__all__ = ["LocalExecutor", "DaskExecutor", "InlineExecutor", "make_executor", "default_workers", "package_versions",
           "check_worker_versions", "check_one_place", "VERSIONED_PACKAGES"]

_ADDRESS = re.compile(r"^[a-z][a-z0-9+]*://\S+$")

PARENT_POLL_SECONDS = 0.2  # [s] how often a local worker checks that the sweep's main process is alive

#: distributions whose versions every Dask worker must share with the client (besides pirl_sim's code version)
VERSIONED_PACKAGES = ("numpy", "scipy", "scikit-learn", "casadi")


def _parent_gone(parent_pid: int) -> bool:
    """True once ``parent_pid`` is no longer this process's parent (it died and the process was re-parented)."""
    return os.getppid() != parent_pid


def _watch_parent_loop(parent_pid: int, interval: float) -> None:
    while not _parent_gone(parent_pid):
        time.sleep(interval)
    try:
        sys.stderr.write(f"pirl_sim sweep worker {os.getpid()}: main process {parent_pid} is gone; exiting\n")
        sys.stderr.flush()
    finally:
        os._exit(1)  # skip atexit and the pool's own shutdown: nobody is left to talk to


def watch_parent(parent_pid: int, interval: float = PARENT_POLL_SECONDS) -> threading.Thread:
    """Worker initialiser: end this process when the process ``parent_pid`` that started it dies.

    A SIGKILL of the sweep's main process runs none of its clean-up, and `concurrent.futures` workers would wait
    on their task queue forever (and keep the multiprocessing resource tracker alive, which exits when the last
    holder of its pipe does). A daemon thread polls ``os.getppid()`` every ``interval`` seconds: when the
    parent dies the worker is re-parented (to init or a sub-reaper), and the thread exits the process at once
    (``os._exit``; cells hold no files open: the main process writes the cell store). A worker busy in a
    cell's numerics is stopped too, since the check runs in its own thread.

    Parameters
    ----------
    parent_pid : int      pid of the process that started this worker
    interval : float      [s] polling period (> 0)
    """
    int_at_least("parent_pid", parent_pid, 1)
    number("interval [s]", interval, low=0, allow_equal=False, finite=False)
    if _parent_gone(parent_pid):  # died while this worker started
        os._exit(1)
    thread = threading.Thread(target=_watch_parent_loop, args=(parent_pid, interval), name="pirl-watch-parent",
                              daemon=True)
    thread.start()
    return thread


def default_workers() -> int:
    """Cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


class _Executor:
    """A context manager: closed on exit, its pending cells cancelled when the block raised."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close(cancel=exc[0] is not None)


class LocalExecutor(_Executor):
    """Cells in ``workers`` local processes (spawn start method by default).

    Parameters
    ----------
    workers : int         worker processes (>= 1)
    start_method : {"spawn", "fork"}
        ``"fork"``: the workers inherit what the calling process has read (``pirl-sim replay`` reads its scene
        once); not for simulated scenarios (libsumo allows one simulation per process).
    """

    def __init__(self, workers: int, start_method: str = "spawn") -> None:
        self.workers = workers = int_at_least("workers", workers, 1)
        if start_method not in ("spawn", "fork"):
            raise ValueError(f"start_method must be 'spawn' or 'fork', got {start_method!r}")
        self._pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(start_method),
                                            initializer=watch_parent, initargs=(os.getpid(),))

    def describe(self) -> str:
        return f"{self.workers} local worker process{'es' if self.workers > 1 else ''}"

    def submit(self, fn, *args):
        return self._pool.submit(fn, *args)

    def as_completed(self, futures):
        return cf.as_completed(futures)

    def warm_up(self) -> None:
        """Start every worker and import what cells need (so start-up is not charged to the first cells)."""
        for f in [self._pool.submit(cell.warm_up, 0.5 if self.workers > 1 else 0.0) for _ in range(self.workers)]:
            f.result()

    def close(self, cancel: bool = False) -> None:
        self._pool.shutdown(wait=not cancel, cancel_futures=cancel)


def package_versions() -> dict[str, str]:
    """{name: version} of this process: ``pirl_sim`` (its code version, `pirl_sim.engine.store.code_version`)
    and those of `VERSIONED_PACKAGES` that are installed."""
    from importlib import metadata

    from .store import code_version

    found = {"pirl_sim": code_version()}
    for name in VERSIONED_PACKAGES:
        with suppress(metadata.PackageNotFoundError):
            found[name] = metadata.version(name)
    return found


def check_worker_versions(client, versions=package_versions) -> None:
    """ValueError naming the worker, the package and both versions when a Dask worker's ``versions()`` (run on
    every worker connected now) differs from this process's `package_versions`; also when a worker cannot run it
    (e.g. pirl_sim is not installed there)."""
    expected = package_versions()
    try:
        reported = client.run(versions)
    except Exception as exc:  # noqa: BLE001 - e.g. a worker that cannot import pirl_sim
        raise ValueError(f"could not ask the Dask workers for their package versions ({type(exc).__name__}: {exc}); "
                         "install pirl_sim on every worker") from exc
    for worker, found in sorted(reported.items()):
        for name in sorted(set(expected) | set(found)):
            if found.get(name) != expected.get(name):
                raise ValueError(f"Dask worker {worker} runs {name} {found.get(name, '(not installed)')}, this client "
                                 f"{expected.get(name, '(not installed)')}: install the same versions on every worker")


def _scheduler_address(path) -> str:
    """The address in a Dask scheduler file; ValueError naming ``path`` when it is missing or unreadable (the
    client would wait for it forever)."""
    try:
        with open(path, encoding="utf-8") as f:
            info = json.load(f)
    except FileNotFoundError:
        raise ValueError(f"scheduler file {path} does not exist (start the scheduler with "
                         f"dask scheduler --scheduler-file {path})") from None
    except (OSError, ValueError) as exc:
        raise ValueError(f"cannot read the scheduler file {path}: {exc}") from None
    if not isinstance(info, dict) or not isinstance(info.get("address"), str):
        raise ValueError(f"scheduler file {path} holds no scheduler address")
    return info["address"]


class DaskExecutor(_Executor):
    """Cells on a Dask distributed cluster. On connecting, the workers' code and package versions are checked
    against this process's (`check_worker_versions`), before any cell is submitted.

    Parameters
    ----------
    client_or_address : dask.distributed.Client or str or None
        A client, or a scheduler address such as ``tcp://10.0.0.5:8786`` (connected here, closed by `close`).
    scheduler_file : path or None
        Instead: the JSON file ``dask scheduler --scheduler-file PATH`` wrote (connected here, closed by `close`).
    """

    def __init__(self, client_or_address=None, *, scheduler_file=None) -> None:
        try:
            from dask.distributed import Client
        except ImportError:  # pragma: no cover - dask is an extra
            raise ValueError(f"a Dask scheduler needs dask.distributed: {install_hint('dask')}") from None
        if (client_or_address is None) == (scheduler_file is None):
            raise ValueError("give a Dask client or scheduler address, or a scheduler file (one of them)")
        self._own = client_or_address is None or isinstance(client_or_address, str)  # a client of our own
        if scheduler_file is not None:
            _scheduler_address(scheduler_file)
            self.client = Client(scheduler_file=str(scheduler_file), timeout="30s")
        elif self._own:
            if not _ADDRESS.match(client_or_address):
                raise ValueError(f"scheduler address must look like tcp://HOST:PORT, got {client_or_address!r}")
            self.client = Client(client_or_address, timeout="30s")
        else:
            self.client = client_or_address
        try:
            check_worker_versions(self.client)
        except BaseException:
            self.close()
            raise

    @property
    def workers(self) -> int:
        """Threads over all workers: how many cells run at once."""
        return sum(w.get("nthreads", 1) for w in self.client.scheduler_info()["workers"].values()) or 1

    def describe(self) -> str:
        info = self.client.scheduler_info()["workers"]
        return f"Dask scheduler {self.client.scheduler.address}: {len(info)} workers, {self.workers} threads"

    def submit(self, fn, *args):
        return self.client.submit(fn, *args, pure=False)

    def as_completed(self, futures):
        from dask.distributed import as_completed

        return as_completed(list(futures))

    def warm_up(self) -> None:
        self.client.run(cell.warm_up)  # every worker, once

    def close(self, cancel: bool = False) -> None:
        if self._own:
            self.client.close()


class _Deferred(cf.Future):
    """A cell to run in the calling process when `InlineExecutor.as_completed` reaches it (or its result is asked
    for first)."""

    def __init__(self, fn, args) -> None:
        super().__init__()
        self._fn, self._args = fn, args

    def _run(self) -> None:
        if not self.done():
            try:
                with cell.single_threaded():
                    self.set_result(self._fn(*self._args))
            except Exception as exc:  # noqa: BLE001 - handed to the caller through result()
                self.set_exception(exc)

    def result(self, timeout=None):
        self._run()
        return super().result(timeout)


class InlineExecutor(_Executor):
    """Cells in the calling process, one after another (each runs when `as_completed` reaches it)."""

    workers = 1

    def describe(self) -> str:
        return "the calling process"

    def submit(self, fn, *args):
        return _Deferred(fn, args)

    def as_completed(self, futures):
        for f in list(futures):
            f._run()
            yield f

    def warm_up(self) -> None:
        cell._VERSION = None  # this process is the worker: take the code version of this run's files

    def close(self, cancel: bool = False) -> None:
        pass


def check_one_place(workers=None, scheduler=None, scheduler_file=None) -> None:
    """ValueError naming the options when more than one of ``--workers``, ``--scheduler`` and ``--scheduler-file``
    is given."""
    given = [name for name, value in (("--workers", workers), ("--scheduler", scheduler),
                                      ("--scheduler-file", scheduler_file)) if value is not None]
    if len(given) > 1:
        raise ValueError(f"give one of --workers, --scheduler and --scheduler-file, not "
                         f"{'both ' if len(given) == 2 else ''}{' and '.join(given)}: with a scheduler the Dask "
                         "workers run the cells")


def make_executor(workers: int | None = None, scheduler: str | None = None, scheduler_file=None):
    """`DaskExecutor` for a scheduler address or a scheduler file, else `LocalExecutor` (``workers`` default: the
    usable cores), `InlineExecutor` for ``workers == 0``."""
    check_one_place(workers, scheduler, scheduler_file)
    if scheduler is not None or scheduler_file is not None:
        return DaskExecutor(scheduler, scheduler_file=scheduler_file)
    return InlineExecutor() if workers == 0 else LocalExecutor(default_workers() if workers is None else workers)
