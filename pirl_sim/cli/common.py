"""What the ``pirl-sim`` commands share: argparse types and options, the command as typed, error and interrupt
messages, reading recorded tracks. Imports nothing heavy at module level: the parsers are built at start-up."""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pirl_sim.threads import AUTO, DEFAULT_THREADS, ENV_VAR, blas_threads_arg
from pirl_sim.validation import int_at_least, number, positive_int_arg, seed_arg

__all__ = ["subcommand", "reworded", "workers_arg", "optional_arg", "seconds_to_steps", "command_line", "interrupted",
           "finish", "table_text", "error", "add_blas_threads_option", "add_study_options", "add_seed_option",
           "add_track_options", "track_files", "driver_settings", "run_study", "print_plan", "load_track_scene"]


def subcommand(name: str, *, help: str, description: str):
    """Decorator of a command module's ``add_parser``, written for the command's own parser (its options): it
    becomes ``add_parser(subparsers)``, which adds the command ``name`` (``help`` in ``pirl-sim --help``,
    ``description`` in its own) to ``subparsers``, adds the options and returns the command's parser."""
    def decorate(add_options: Callable[[argparse.ArgumentParser], None]) -> Callable[[Any], argparse.ArgumentParser]:
        def add_parser(subparsers) -> argparse.ArgumentParser:
            """Add the command to ``subparsers`` (`subcommand`); returns its parser."""
            parser = subparsers.add_parser(name, help=help, description=description)
            add_options(parser)
            return parser
        return add_parser
    return decorate


def reworded(parse: Callable[[str], Any], message: str) -> Callable[[str], Any]:
    """The argparse type ``parse`` (e.g. `positive_float_arg`) with its error, or a ValueError it raises, said as
    ``message``: a format string of ``text``, the text given (``"expected ..., got {text!r}"``)."""
    def convert(text: str):
        try:
            return parse(text)
        except (argparse.ArgumentTypeError, ValueError):
            raise argparse.ArgumentTypeError(message.format(text=text)) from None
    return convert


#: argparse type of a sweep's ``--workers``: an integer >= 0 (0: in this process)
workers_arg = reworded(lambda text: int_at_least("--workers", int(text), 0),
                       "expected a number of workers >= 0, got {text}")


def optional_arg(kind, what: str):
    """An argparse type: ``kind(text)``, or None for 'none'."""
    return reworded(lambda text: None if text.strip().lower() == "none" else kind(text),
                    f"expected {what} or 'none', got {{text!r}}")


def seconds_to_steps(seconds: float, dt: float, option: str) -> int:
    """A duration option [s] as a number of model steps of ``dt`` [s] (rounded); ValueError naming ``option``
    when it is not a finite number > 0 or shorter than half a step (it would round to no step at all)."""
    steps = int(round(number(option, seconds, low=0, allow_equal=False) / dt))
    if steps < 1:
        raise ValueError(f"{option} {seconds:g} s is less than one model step (dt {dt:g} s): give at least {dt:g} s")
    return steps


def command_line(name: str, fallback: list[str]) -> str:
    """The command ``name`` as typed (its arguments shell-quoted), or ``pirl-sim NAME FALLBACK...`` when it was
    called from Python: what ``sweep.json`` and the READMEs record."""
    argv = sys.argv[1:]
    return "pirl-sim " + shlex.join(argv[argv.index(name):] if name in argv else [name, *fallback])


def interrupted(out) -> int:
    """Say that an interrupted run keeps its finished cells in ``out``; exit status 130."""
    print(f"\ninterrupted: finished cells are kept in {out}/cells/; run the same command to resume", file=sys.stderr)
    return 130


def finish(written, *lines: str) -> int:
    """Print ``lines`` (tables, summaries), then ``wrote WRITTEN``; returns 0, the exit status of a finished
    command."""
    print(*lines, f"wrote {written}", sep="\n")
    return 0


def table_text(table, digits: int = 3) -> str:
    """A DataFrame as the commands print it: no index, numbers to ``digits`` significant digits."""
    return table.to_string(index=False, float_format=lambda x: f"{x:.{digits}g}")


def error(exc, status: int = 2) -> int:
    """Print ``pirl-sim: error: <exc>`` on stderr; returns ``status`` (the exit status of a bad input)."""
    print(f"pirl-sim: error: {exc}", file=sys.stderr)
    return status


_OPTION_HELP = (f"BLAS/OpenMP threads of this process (default {DEFAULT_THREADS}, or ${ENV_VAR} if set; "
                f"'{AUTO}': the libraries' own defaults). Small solves run fastest on one thread, above all when "
                "the machine is loaded; use processes (--workers) for parallelism")


def run_study(name: str, make_config, report, args, command: str, ignore: str = "cells/\nerrors/\nsweep.json\n",
              source: str | None = None) -> int:
    """The cells of an experiment command through the engine into ``args.out``, then its report:
    ``make_config()`` gives the sweep config's data (validated here by `pirl_sim.engine.config.parse_config`, its
    source ``source``, default ``pirl-sim NAME``) and what else the command's report needs (errors there and a bad
    ``--out`` are exit 2, before anything is written); ``--dry-run`` counts printed, else
    `pirl_sim.engine.run.run_sweep` with ``--workers`` and ``--quiet``; ``ignore`` is written to ``OUT/.gitignore``
    (what the store keeps beside the report).

    Returns
    -------
    int
        ``report(result, config, study)``'s exit status, called with the finished `SweepRun`, its config and
        ``make_config``'s second value; or 0 after a dry run, 1 when cells failed (the others are kept), 2 for a
        bad value, 130 when interrupted.
    """
    from pirl_sim.engine.config import parse_config
    from pirl_sim.engine.run import run_sweep
    from pirl_sim.io.atomic import atomic_write_text
    from pirl_sim.validation import check_output_dir

    try:
        data, study = make_config()
        config, out = parse_config(data, source=source or f"pirl-sim {name}"), check_output_dir(args.out)
        if args.dry_run:
            print_plan(config, out, name)
            return 0
        result = run_sweep(config, out, workers=args.workers, progress=not args.quiet, command=command, tables=False)
    except (ValueError, FileNotFoundError) as exc:
        return error(exc)
    except KeyboardInterrupt:
        return interrupted(args.out)
    if result.failed:
        return error(next(iter(result.failed.values())), status=1)
    atomic_write_text(out / ".gitignore", ignore)
    return report(result, config, study)


def print_plan(config, out, what: str, unit: str = "cells", code: bool = False) -> None:
    """``--dry-run``: print ``WHAT: N UNIT, M already in OUT/, K to run`` for the distinct cells of the sweep config
    ``config`` and the results directory ``out`` (with ``code``, then the code version they are keyed under)."""
    from pirl_sim.engine.run import plan_cells
    from pirl_sim.engine.store import ResultStore

    version, _, unique, records, todo = plan_cells(config, ResultStore(out))
    print(f"{what}: {len(unique)} {unit}, {len(records)} already in {out}/, {len(todo)} to run"
          + (f" (code {version})" if code else ""))


def add_blas_threads_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--blas-threads`` to ``parser`` and, recursively, to each of its subcommands' parsers (so it may
    come before or after a command's name). Absent from the namespace unless given."""
    if not any("--blas-threads" in a.option_strings for a in parser._actions):
        parser.add_argument("--blas-threads", type=blas_threads_arg, default=argparse.SUPPRESS, metavar="N",
                            help=_OPTION_HELP)
    for action in (a for a in parser._actions if isinstance(a, argparse._SubParsersAction)):
        for sub in action.choices.values():
            add_blas_threads_option(sub)


def add_study_options(p: argparse.ArgumentParser, runs: str, count: str = "cells still to run") -> None:
    """``--workers`` (``runs`` at once, each in its own process), ``--dry-run`` (that counts the ``count``) and
    ``--quiet``: the options of a `run_study` command."""
    p.add_argument("--workers", type=workers_arg, default=1,
                   help=f"{runs} at once, each in its own process (default 1; 0: in this process)")
    p.add_argument("--dry-run", action="store_true", help=f"check the options and count the {count}")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def add_seed_option(p: argparse.ArgumentParser, what: str) -> None:
    """``--seed``, the seed of ``what`` (default 0)."""
    p.add_argument("--seed", type=seed_arg, default=0, help=f"seed of {what} (default 0)")


def add_track_options(p: argparse.ArgumentParser) -> None:
    """``--tracks``, ``--map``, ``--files`` and ``--quiet``: the recorded tracks a model is fitted on or predicts."""
    p.add_argument("--tracks", type=Path, required=True, help="a vehicle_tracks_*.csv file or a directory of them")
    p.add_argument("--map", type=Path, required=True, help="the Lanelet2 OSM map of the recording")
    p.add_argument("--files", type=positive_int_arg,
                   help="use only the first N track files (sorted by name) (default all)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def track_files(path: Path, limit: int | None = None) -> list[Path]:
    """The track file ``path``, or the ``vehicle_tracks_*.csv`` of the folder ``path`` (`find_track_files`), only
    the first ``limit`` of them (by name) when given."""
    from pirl_sim.io.interaction import find_track_files

    files = find_track_files(path) if path.is_dir() else [path]
    return files if limit is None else sorted(files, key=lambda f: Path(f).name)[:limit]


def driver_settings(rec, a_lat: float | None = None, v_max: float | None = None) -> dict[str, Any]:
    """`load_replay`'s keywords of the drivers' model: a pirl_sim recording's path and desired-speed settings
    (``rec``, `recording_settings`; None: none), its desired speed's ``a_lat`` [m/s^2] and ``v_max`` [m/s] when
    given."""
    own = {} if rec is None else {"smoothing": rec.smoothing, "speed_smoothing": rec.speed_smoothing,
                                  "a_lat": rec.a_lat, "v_max": rec.v_max}
    return {**own, **{k: float(v) for k, v in (("a_lat", a_lat), ("v_max", v_max)) if v is not None}}


def load_track_scene(args, dt: float, say, receding: bool = False, *, features: str = "paper",
                     selection: str | None = None, a_lat: float | None = None, v_max: float | None = None):
    """The selected tracks (``selection``, `pirl_sim.scenarios.replay.load_replay`'s; default whole tracks without
    interaction, or, with the receding likelihood on a recording with per-step driver flags, every PIRL track
    with its step mask, as ``pirl-sim replay``) under a model of the feature set ``features`` whose desired speed
    has ``a_lat`` [m/s^2] and ``v_max`` [m/s] (default: a pirl_sim recording's drivers', else load_replay's)."""
    from pirl_sim.scenarios.replay import (DRIVER_STEPS_FILE, SIMULATED_NOISE, is_recording, load_replay,
                                           recording_settings)

    files = track_files(args.tracks, args.files)
    load: dict[str, Any] = {"dt": dt, "features": features, **({"selection": selection} if selection else {})}
    if is_recording(args.tracks):
        load.update(arc_length="observed", noise=SIMULATED_NOISE)
    if receding:
        load["estimate"] = "speeds"
        if ((args.tracks if args.tracks.is_dir() else args.tracks.parent) / DRIVER_STEPS_FILE).is_file():
            load["selection"] = "steps"
    load.update(driver_settings(recording_settings(args.tracks), a_lat, v_max))
    say(f"reading {len(files)} track files and {args.map} (dt {dt:g} s)")
    scene = load_replay(files, args.map, **load)
    say(f"{scene.n_converted} tracks converted, {scene.n_selected_tracks} selected; skipped {scene.skipped}")
    if not scene.selected:
        raise ValueError(f"no usable track in {args.tracks} (skipped: {scene.skipped})")
    return scene
