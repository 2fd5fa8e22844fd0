"""What the ``pirl-sim`` commands share: argparse types and options, the command as typed, error and interrupt
messages, reading recorded tracks. Imports nothing heavy at module level: the parsers are built at start-up."""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from pathlib import Path
from typing import Any

from pirl_sim.threads import AUTO, DEFAULT_THREADS, ENV_VAR, blas_threads_arg
from pirl_sim.validation import positive_int_arg

__all__ = ["workers_arg", "optional_arg", "seconds_to_steps", "command_line", "interrupted", "error",
           "add_blas_threads_option", "add_track_options", "load_track_scene"]


def workers_arg(text: str) -> int:
    """argparse type of a sweep's ``--workers``: an integer >= 0 (0: in this process)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of workers >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number of workers >= 0, got {value}")
    return value


def optional_arg(kind, what: str):
    """An argparse type: ``kind(text)``, or None for 'none'."""
    def parse(text: str):
        if text.strip().lower() == "none":
            return None
        try:
            return kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what} or 'none', got {text!r}") from None
    return parse


def seconds_to_steps(seconds: float, dt: float, option: str) -> int:
    """A duration option [s] as a number of model steps of ``dt`` [s] (rounded); ValueError naming ``option``
    when it is not a finite number > 0 or shorter than half a step (it would round to no step at all)."""
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) \
            or (isinstance(seconds, float) and not math.isfinite(seconds)) or seconds <= 0:
        raise ValueError(f"{option} must be a finite duration > 0 [s], got {seconds!r}")
    steps = int(round(seconds / dt))
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


def error(exc, status: int = 2) -> int:
    """Print ``pirl-sim: error: <exc>`` on stderr; returns ``status`` (the exit status of a bad input)."""
    print(f"pirl-sim: error: {exc}", file=sys.stderr)
    return status


_OPTION_HELP = (f"BLAS/OpenMP threads of this process (default {DEFAULT_THREADS}, or ${ENV_VAR} if set; "
                f"'{AUTO}': the libraries' own defaults). Small solves run fastest on one thread, above all when "
                "the machine is loaded; use processes (--workers) for parallelism")


def run_study(name: str, make_config, args, command: str, ignore: str = "cells/\nerrors/\nsweep.json\n"):
    """The cells of an experiment command through the engine into ``args.out``: ``make_config()`` gives the sweep
    config and what else the command's report needs (errors there and a bad ``--out`` are exit 2, before anything
    is written),
    ``--dry-run`` counts printed, else `pirl_sim.engine.run.run_sweep` with ``--workers`` and ``--quiet``;
    ``ignore`` is written to ``OUT/.gitignore`` (what the store keeps beside the report).

    Returns
    -------
    (result, config, study, status)
        The finished `SweepRun`, its config and ``make_config``'s second value, with status None; or Nones and the
        command's exit status (0 after a dry run, 1 when cells failed (the others are kept), 2 for a bad value,
        130 when interrupted).
    """
    from pirl_sim.engine.run import plan_cells, run_sweep
    from pirl_sim.engine.store import ResultStore
    from pirl_sim.io.atomic import atomic_write_text
    from pirl_sim.validation import check_output_dir

    try:
        config, study = make_config()
        out = check_output_dir(args.out)
        if args.dry_run:
            _, _, unique, _, todo = plan_cells(config, ResultStore(out))
            print(f"{name}: {len(unique)} cells, {len(unique) - len(todo)} already in {out}/, {len(todo)} to run")
            return None, None, None, 0
        result = run_sweep(config, out, workers=args.workers, progress=not args.quiet, command=command, tables=False)
    except (ValueError, FileNotFoundError) as exc:
        return None, None, None, error(exc)
    except KeyboardInterrupt:
        return None, None, None, interrupted(args.out)
    if result.failed:
        return None, None, None, error(next(iter(result.failed.values())), status=1)
    atomic_write_text(out / ".gitignore", ignore)
    return result, config, study, None


def add_blas_threads_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--blas-threads`` to ``parser`` and, recursively, to each of its subcommands' parsers (so it may
    come before or after a command's name). Absent from the namespace unless given."""
    if not any("--blas-threads" in a.option_strings for a in parser._actions):
        parser.add_argument("--blas-threads", type=blas_threads_arg, default=argparse.SUPPRESS, metavar="N",
                            help=_OPTION_HELP)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                add_blas_threads_option(sub)


def add_track_options(p: argparse.ArgumentParser) -> None:
    """``--tracks``, ``--map``, ``--files`` and ``--quiet``: the recorded tracks a model is fitted on or predicts."""
    p.add_argument("--tracks", type=Path, required=True, help="a vehicle_tracks_*.csv file or a directory of them")
    p.add_argument("--map", type=Path, required=True, help="the Lanelet2 OSM map of the recording")
    p.add_argument("--files", type=positive_int_arg, default=None,
                   help="use only the first N track files (sorted by name) (default all)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def load_track_scene(args, dt: float, say, receding: bool = False, *, features: str = "paper",
                     selection: str | None = None, a_lat: float | None = None, v_max: float | None = None):
    """The selected tracks (``selection``, `pirl_sim.scenarios.replay.load_replay`'s; default whole tracks without
    interaction, or, with the receding likelihood on a recording with per-step driver flags, every PIRL track
    with its step mask, as ``pirl-sim replay``) under a model of the feature set ``features`` whose desired speed
    has ``a_lat`` [m/s^2] and ``v_max`` [m/s] (default: a pirl_sim recording's drivers', else load_replay's)."""
    from pirl_sim.io.interaction import find_track_files
    from pirl_sim.scenarios.replay import (DRIVER_STEPS_FILE, SIMULATED_NOISE, is_recording, load_replay,
                                           recording_settings)

    files = find_track_files(args.tracks) if args.tracks.is_dir() else [args.tracks]
    if args.files is not None:
        files = sorted(files, key=lambda f: Path(f).name)[: args.files]
    load: dict[str, Any] = {"dt": dt, "features": features, **({"selection": selection} if selection else {})}
    rec = recording_settings(args.tracks)
    if is_recording(args.tracks):
        load.update(arc_length="observed", noise=SIMULATED_NOISE)
    if receding:
        load["estimate"] = "speeds"
        if ((args.tracks if args.tracks.is_dir() else args.tracks.parent) / DRIVER_STEPS_FILE).is_file():
            load["selection"] = "steps"
    if rec is not None:
        load.update(smoothing=rec.smoothing, speed_smoothing=rec.speed_smoothing, a_lat=rec.a_lat, v_max=rec.v_max)
    load.update({k: float(v) for k, v in (("a_lat", a_lat), ("v_max", v_max)) if v is not None})
    say(f"reading {len(files)} track files and {args.map} (dt {dt:g} s)")
    scene = load_replay(files, args.map, **load)
    say(f"{scene.n_converted} tracks converted, {scene.n_selected_tracks} selected; skipped {scene.skipped}")
    if not scene.selected:
        raise ValueError(f"no usable track in {args.tracks} (skipped: {scene.skipped})")
    return scene
