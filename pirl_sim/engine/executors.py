"""Where cells run: one small interface over local worker processes, Dask distributed, and the calling process.

The sweep loop (`pirl_sim.engine.run.run_sweep`) only uses ``submit(fn, *args) -> future``,
``as_completed(futures)`` (yields futures as they finish), ``future.result()``, ``warm_up()`` and ``close()``,
which `concurrent.futures` and `dask.distributed` both provide; so the same loop drives both:

- `LocalExecutor`: a `concurrent.futures.ProcessPoolExecutor` with the *spawn* start method (libsumo allows
  one simulation per process, and spawned workers share no state with the parent); each worker ends itself
  when the process that started it dies, even by SIGKILL (`watch_parent`), so no orphan keeps computing;
- `DaskExecutor`: a `dask.distributed.Client` connected to a scheduler (``tcp://HOST:PORT``; workers on any
  number of machines, each with pirl_sim installed at the same code version; start them with
  ``--nthreads 1``, one cell per process), or to a client you made (a ``LocalCluster`` in tests);
- `InlineExecutor`: runs the cells one by one in the calling process (``--workers 0``; debugging).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import re
import sys
import threading

from . import worker as cell

__all__ = ["LocalExecutor", "DaskExecutor", "InlineExecutor", "make_executor", "default_workers"]

_ADDRESS = re.compile(r"^[a-z][a-z0-9+]*://\S+$")

PARENT_POLL_SECONDS = 0.2  # [s] how often a local worker checks that the sweep's main process is alive


def _parent_gone(parent_pid: int) -> bool:
    """True once ``parent_pid`` is no longer this process's parent (it died and the process was re-parented)."""
    return os.getppid() != parent_pid


def _watch_parent_loop(parent_pid: int, interval: float) -> None:
    import time

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
    if isinstance(parent_pid, bool) or not isinstance(parent_pid, int) or parent_pid < 1:
        raise ValueError(f"parent_pid must be a positive integer, got {parent_pid!r}")
    if not interval > 0:
        raise ValueError(f"interval must be > 0 seconds, got {interval!r}")
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

    kind = "local"

    def __init__(self, workers: int, start_method: str = "spawn") -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"workers must be a positive integer, got {workers!r}")
        if start_method not in ("spawn", "fork"):
            raise ValueError(f"start_method must be 'spawn' or 'fork', got {start_method!r}")
        self.workers = workers
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
        seconds = 0.5 if self.workers > 1 else 0.0
        for f in [self._pool.submit(cell.warm_up, seconds) for _ in range(self.workers)]:
            f.result()

    def close(self, cancel: bool = False) -> None:
        self._pool.shutdown(wait=not cancel, cancel_futures=cancel)


class DaskExecutor(_Executor):
    """Cells on a Dask distributed cluster.

    Parameters
    ----------
    client_or_address : dask.distributed.Client or str
        A client, or a scheduler address such as ``tcp://10.0.0.5:8786`` (connected here, closed by `close`).
    """

    kind = "dask"

    def __init__(self, client_or_address) -> None:
        try:
            from dask.distributed import Client
        except ImportError:  # pragma: no cover - dask is an extra
            raise ValueError("--scheduler needs dask[distributed]: pip install 'pirl_sim[dask]'") from None
        self._own = isinstance(client_or_address, str)  # an address: a client of our own
        if self._own and not _ADDRESS.match(client_or_address):
            raise ValueError(f"scheduler address must look like tcp://HOST:PORT, got {client_or_address!r}")
        self.client = Client(client_or_address, timeout="30s") if self._own else client_or_address

    @property
    def workers(self) -> int:
        """Threads over all workers: how many cells run at once."""
        info = self.client.scheduler_info()["workers"]
        return sum(w.get("nthreads", 1) for w in info.values()) or 1

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


class _Deferred:
    """A cell to run in the calling process when `InlineExecutor.as_completed` reaches it."""

    def __init__(self, fn, args) -> None:
        self._fn, self._args, self._done, self._value, self._error = fn, args, False, None, None

    def _run(self) -> None:
        if not self._done:
            try:
                with cell.single_threaded():
                    self._value = self._fn(*self._args)
            except Exception as exc:  # noqa: BLE001 - handed to the caller through result()
                self._error = exc
            self._done = True

    def result(self):
        self._run()
        if self._error is not None:
            raise self._error
        return self._value

    def cancel(self) -> bool:
        return not self._done


class InlineExecutor(_Executor):
    """Cells in the calling process, one after another (each runs when `as_completed` reaches it)."""

    kind = "inline"
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


def make_executor(workers: int | None = None, scheduler: str | None = None):
    """`DaskExecutor` for a scheduler address, else `LocalExecutor` (``workers`` default: the usable cores),
    `InlineExecutor` for ``workers == 0``."""
    if scheduler is not None:
        if workers is not None:
            raise ValueError("give --workers or --scheduler, not both: with a scheduler the Dask workers run the cells")
        return DaskExecutor(scheduler)
    if workers == 0:
        return InlineExecutor()
    return LocalExecutor(default_workers() if workers is None else workers)
