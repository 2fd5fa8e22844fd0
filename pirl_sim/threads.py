"""Thread policy of single-process commands: one BLAS/OpenMP thread unless the user says otherwise.

pirl_sim's heavy work is many small dense solves, for which extra BLAS threads buy nothing on a quiet machine and
cost multiples on a loaded one (OpenBLAS's threads spin-wait for each other); parallelism comes from processes
(the sweep's workers, ``recover --workers``). The ``pirl-sim`` command line applies the policy to every command
(:func:`thread_policy`; :func:`apply_thread_policy` applies it to the rest of a process):

- default: **1 thread** per BLAS/OpenMP library in this process (threadpoolctl), and ``OMP_NUM_THREADS``,
  ``OPENBLAS_NUM_THREADS``, ... set to 1 for the child processes it starts;
- ``--blas-threads N`` (any command) or ``PIRL_SIM_BLAS_THREADS=N``: N threads (the option wins);
- ``auto`` as N: leave the libraries to their own defaults.

Results do not depend on the setting beyond floating-point rounding. Library code never changes threads itself:
a program that imports pirl_sim decides, e.g. with :func:`blas_threads` as a context manager.
"""

from __future__ import annotations

import argparse
import os
from contextlib import contextmanager
from collections.abc import Iterator

__all__ = ["ENV_VAR", "AUTO", "DEFAULT_THREADS", "THREAD_VARS", "parse_blas_threads", "blas_threads_arg",
           "resolve_blas_threads", "apply_thread_policy", "thread_policy", "blas_threads",
           "current_blas_threads"]

ENV_VAR = "PIRL_SIM_BLAS_THREADS"  #: the environment variable of the policy (a positive integer or "auto")
AUTO = "auto"  #: leave the libraries' own thread counts alone
DEFAULT_THREADS = 1  #: BLAS/OpenMP threads per process unless the user says otherwise
#: variables read by BLAS/OpenMP runtimes when they load (child processes inherit them)
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
               "NUMEXPR_NUM_THREADS")


def parse_blas_threads(value: str | int, label: str = ENV_VAR) -> int | None:
    """A thread setting as given by a user: a positive integer, or ``"auto"`` (returned as None).

    Raises
    ------
    ValueError
        Naming ``label`` and the bad value, for anything else (0, negative numbers, other words).
    """
    if isinstance(value, str):
        text = value.strip().lower()
        if text == AUTO:
            return None
        try:
            n = int(text)
        except ValueError:
            raise ValueError(f"{label} must be a positive integer or {AUTO!r}, got {value!r}") from None
    elif isinstance(value, int) and not isinstance(value, bool):
        n = value
    else:
        raise ValueError(f"{label} must be a positive integer or {AUTO!r}, got {value!r}")
    if n < 1:
        raise ValueError(f"{label} must be a positive integer or {AUTO!r}, got {value!r}")
    return n


def blas_threads_arg(text: str) -> str:
    """argparse type of ``--blas-threads``: checks the value, keeps the text (``"auto"`` or an integer)."""
    try:
        parse_blas_threads(text, "--blas-threads")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def resolve_blas_threads(option: str | int | None = None, environ=None) -> int | None:
    """The thread count the policy gives: ``option`` if given, else ``$PIRL_SIM_BLAS_THREADS`` if set, else
    :data:`DEFAULT_THREADS`; None means ``auto`` (leave the libraries alone)."""
    if option is not None:
        return parse_blas_threads(option, "--blas-threads")
    environ = os.environ if environ is None else environ
    value = environ.get(ENV_VAR)
    if value is not None and value.strip():
        return parse_blas_threads(value, ENV_VAR)
    return DEFAULT_THREADS


def _load_runtimes() -> None:
    """Import numpy's and scipy's BLAS, so that threadpoolctl sees and limits them. Runtimes loaded later
    (scikit-learn's OpenMP, libsumo's OpenBLAS) read the thread variables the policy has set when they load;
    importing scikit-learn here would cost commands that never use it ~1 s of start-up."""
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401


def apply_thread_policy(option: str | int | None = None) -> int | None:
    """Apply the policy to this process from now on and to the child processes it starts.

    Parameters
    ----------
    option : str or int, optional   ``--blas-threads`` (a positive integer or ``"auto"``); None: the environment
                                    variable, else 1; ValueError for a bad value

    Returns
    -------
    threads : int or None           the thread count set, or None for ``auto`` (nothing changed)
    """
    n = resolve_blas_threads(option)
    if n is None:
        return None
    for var in THREAD_VARS:
        os.environ[var] = str(n)  # runtimes loaded later, and spawned child processes
    _load_runtimes()
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=n)
    return n


@contextmanager
def thread_policy(option: str | int | None = None) -> Iterator[int | None]:
    """`apply_thread_policy` for the duration of a block: on exit the thread counts and the environment
    variables are what they were (how ``pirl_sim.cli.main`` runs a command, so that calling it from Python,
    e.g. in tests, leaves the calling process as it was). Yields the thread count set (None: ``auto``).

    Raises
    ------
    ValueError
        For a bad option or environment value, before anything is changed.
    """
    n = resolve_blas_threads(option)
    if n is None:
        yield None
        return
    saved = {var: os.environ.get(var) for var in THREAD_VARS}
    _load_runtimes()
    from threadpoolctl import threadpool_limits

    try:
        for var in THREAD_VARS:
            os.environ[var] = str(n)  # for the child processes the command starts
        with threadpool_limits(limits=n):
            yield n
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value


@contextmanager
def blas_threads(n: int | None = DEFAULT_THREADS) -> Iterator[None]:
    """Limit every loaded BLAS/OpenMP runtime to ``n`` threads inside the block (None: no change); for programs
    and benchmarks that import pirl_sim. Restores the previous counts on exit; environment untouched."""
    if n is None:
        yield
        return
    n = parse_blas_threads(n, "n")
    _load_runtimes()
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=n):
        yield


def current_blas_threads() -> dict[str, int]:
    """``{internal_api: largest num_threads}`` over the loaded runtimes (e.g. ``{"openblas": 1, "openmp": 1}``)."""
    from threadpoolctl import threadpool_info

    out: dict[str, int] = {}
    for lib in threadpool_info():
        key = lib["internal_api"]
        out[key] = max(out.get(key, 0), int(lib["num_threads"]))
    return out
