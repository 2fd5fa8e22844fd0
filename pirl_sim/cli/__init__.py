"""The ``pirl-sim`` command line: one module per subcommand, each with ``add_parser(subparsers)`` and
``run(args) -> int``. Building the parser imports no numerical library; a command imports its work when it runs."""

from __future__ import annotations

import argparse
import logging
import sys
from contextlib import contextmanager

from pirl_sim.extras import extra_of, install_hint
from pirl_sim.threads import resolve_blas_threads, thread_policy

from . import (agents, calibrate, fit_model, policy_recovery, predict, realism, recover, replay, report, reproduce,
               show, simulate, sweep, weight_space)
from .common import add_blas_threads_option, error

__all__ = ["main", "build_parser", "package_version", "cli_logging", "COMMANDS"]

#: the subcommands in the order of ``pirl-sim --help``: name (the module's, ``-`` for ``_``) -> module
COMMANDS = {module.__name__.rpartition(".")[2].replace("_", "-"): module for module in (reproduce, simulate, show,
    sweep, report, recover, replay, fit_model, predict, realism, calibrate, agents, policy_recovery, weight_space)}


def package_version() -> str:
    """The installed version of pirl_sim, from the package metadata (``pyproject.toml``'s ``version``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pirl_sim")
    except PackageNotFoundError:  # pragma: no cover - run from a source tree that was never installed
        return "unknown (not installed)"


class _VersionAction(argparse.Action):
    """``--version``: print ``pirl-sim VERSION`` and exit (the metadata is read only when asked)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        parser._print_message(f"{parser.prog} {package_version()}\n", sys.stdout)
        parser.exit()


@contextmanager
def cli_logging(verbose: bool = False):
    """Diagnostics of the ``pirl_sim`` loggers on stderr while a command runs: warnings always, progress and
    details (INFO) with ``--verbose``; the bare message, as the commands printed before. Removed on exit, so
    calling `main` again (tests, notebooks) adds no second handler."""
    logger, handler = logging.getLogger("pirl_sim"), logging.StreamHandler(sys.stderr)
    handler.setLevel(logging.INFO if verbose else logging.WARNING)
    handler.setFormatter(logging.Formatter("%(message)s"))
    old_level = logger.level
    if verbose and logger.getEffectiveLevel() > logging.INFO:
        logger.setLevel(logging.INFO)
    logger.addHandler(handler)
    try:
        yield handler
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)


def build_parser() -> argparse.ArgumentParser:
    """The parser of every subcommand (`COMMANDS`), with ``--version``, ``--verbose`` and ``--blas-threads``."""
    description = "Probabilistic IRL of diverse drivers: generate, learn, predict, score."
    parser = argparse.ArgumentParser(prog="pirl-sim", description=description)
    parser.add_argument("--version", action=_VersionAction, help="show program's version number and exit")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log progress and details (INFO) on stderr, not only warnings")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMANDS.values():
        module.add_parser(sub)
    add_blas_threads_option(parser)  # every command; the policy: pirl_sim.threads
    return parser


#: optional modules -> the extra of pyproject.toml that installs them (a missing one is named with its extra)


def main(argv: list[str] | None = None) -> int:
    """Run ``pirl-sim`` with ``argv`` (default: the process's arguments); returns the exit status: a command's
    own, 130 for Ctrl-C and 2 for a file system error (an unwritable or full output, a directory where a file is
    expected) or a missing optional module (named with its extra, `pirl_sim.extras`) that the command did not handle, each
    said in one line without a traceback."""
    args = build_parser().parse_args(argv)
    option = getattr(args, "blas_threads", None)
    try:
        resolve_blas_threads(option)  # a bad $PIRL_SIM_BLAS_THREADS stops the command before any work
    except ValueError as exc:
        return error(exc)
    try:
        with thread_policy(option), cli_logging(getattr(args, "verbose", False)):  # both restored on return
            return COMMANDS[args.command].run(args)
    except KeyboardInterrupt:
        print(f"\npirl-sim {args.command}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:
        return error(exc)
    except ModuleNotFoundError as exc:
        extra = extra_of(exc.name)
        if extra is None:
            raise
        return error(f"{exc.name} is not installed; pirl-sim {args.command} needs it: {install_hint(extra)}")
