"""``pirl-sim show``: a recording on its map as a PNG (one frame, or every track) or an animation (GIF, MP4)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from pirl_sim.validation import positive_float_arg

from .common import error, finish, subcommand, track_files

__all__ = ["add_parser", "run"]

DEFAULT_OUT = "show.png"
_STYLE = "style"  #: --color-by value that reads the styles from the recording's ground_truth.csv


def _size(text: str) -> tuple[int, int]:
    """argparse type: ``WIDTHxHEIGHT`` in pixels, each in [100, 4000]."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels (e.g. 800x600), got {text!r}") from None
    if not (100 <= w <= 4000 and 100 <= h <= 4000):
        raise argparse.ArgumentTypeError(f"width and height must be in [100, 4000] px, got {text!r}")
    return w, h


@subcommand("show", help="draw a recording on its map: one frame, every track, or an animation",
            description="Draw an INTERACTION-format recording (a track CSV file, a folder of them, or a pirl_sim "
            "simulated run) on its Lanelet2 map: one frame (--frame or --time) with the vehicles as oriented boxes, "
            "every track (the default), or an animation over a time span (--span, written as .gif or .mp4 by the "
            "suffix of --out). Tracks are coloured by --color-by: a column of the track file, 'speed', or 'style' "
            "(the drivers' styles from the run's ground_truth.csv). Given a replay's output folder, it draws one of "
            "the replay's scenes (--window gain or loss: where the best learner beats CA most or loses to it most).")
def add_parser(p) -> None:
    """The options of ``show``."""
    p.add_argument("tracks", type=Path, help="a vehicle_tracks_*.csv file, a folder with one (a simulated run), or "
                   "a replay's output folder (its scenes.json: see --window)")
    p.add_argument("--map", type=Path,
                   help="Lanelet2 map (.osm); default: map.osm beside the tracks when there is one, else no road")
    p.add_argument("--file", type=int, default=0, metavar="N",
                   help="which vehicle_tracks_*.csv of a folder, in name order (default 0: the first)")
    when = p.add_mutually_exclusive_group()
    when.add_argument("--frame", type=int, help="draw this frame_id")
    when.add_argument("--time", type=float, metavar="S", help="draw the frame at this time [s]")
    when.add_argument("--span", type=float, nargs=2, metavar=("START", "END"),
                      help="animate from START to END [s of the recording]")
    p.add_argument("--color-by", metavar="COLUMN", help="colour tracks by a column of the track file, "
                   "'speed' [m/s] or 'style' (default: one colour per track)")
    p.add_argument("--window", metavar="KIND", help="of a replay's output folder: the scene to draw, 'gain' (the "
                   "best learner beats CA most, the default) or 'loss' (it loses most)")
    p.add_argument("--fps", type=positive_float_arg, default=10.0, help="animation frames per second (default 10)")
    p.add_argument("--speed", type=positive_float_arg, default=1.0,
                   help="recording seconds per animation second (default 1: real time)")
    p.add_argument("--size", type=_size, default=(800, 600), metavar="WxH", help="image size [px] (default 800x600)")
    p.add_argument("--out", type=Path, help="output .png (frames, tracks) or .gif/.mp4 (--span); "
                   f"default {DEFAULT_OUT}, or show.gif with --span")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _track_file(path: Path, index: int) -> Path:
    """The track file ``path``, or the ``index``-th of the folder ``path`` (`track_files`)."""
    if path.is_file():
        return path
    if not path.is_dir():
        raise ValueError(f"tracks {str(path)!r}: no such file or folder")
    files = track_files(path)
    if not 0 <= index < len(files):
        raise ValueError(f"--file {index}: the folder has {len(files)} track file(s), so it must be in "
                         f"[0, {len(files) - 1}]")
    return files[index]


def _styles(folder: Path) -> dict:
    """{track_id: style name} from a simulated run's ground_truth.csv."""
    import pandas as pd

    from pirl_sim.scenarios.recording import GROUND_TRUTH_FILE

    path = folder / GROUND_TRUTH_FILE
    if not path.is_file():
        raise ValueError(f"--color-by style reads the styles from {path}, which does not exist (use a column of "
                         "the track file or 'speed')")
    truth = pd.read_csv(path, usecols=["track_id", "style_name"], dtype={"style_name": str}, keep_default_na=False)
    return dict(zip(truth["track_id"], truth["style_name"]))


def _outputs(args, inputs: list[Path]) -> Path:
    animated = args.span is not None
    out = args.out if args.out is not None else Path("show.gif" if animated else DEFAULT_OUT)
    allowed = (".gif", ".mp4") if animated else (".png",)
    if out.suffix.lower() not in allowed:
        what = "an animation (--span)" if animated else "a picture"
        raise ValueError(f"--out {str(out)!r}: {what} is written as {' or '.join(allowed)}")
    if out.exists() and any(i.exists() and i.resolve() == out.resolve() for i in inputs):
        raise ValueError(f"--out {str(out)!r} is an input file: choose another name")
    if out.exists() and out.is_dir():
        raise ValueError(f"--out {str(out)!r} is a folder: give a file name")
    if not out.resolve().parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: the folder {str(out.resolve().parent)!r} does not exist")
    return out


def _replay_scene(args) -> Path:
    """Draw the scene ``--window`` of the replay output folder ``args.tracks`` (its scenes.json) as a PNG."""
    from pirl_sim.experiments.replay_scenes import SCENE_KINDS, draw_replay_scene

    given = [f"--{name.replace('_', '-')}" for name in ("frame", "time", "span", "color_by", "map")
             if getattr(args, name) is not None]
    if given:
        raise ValueError(f"{', '.join(given)}: a replay's output folder holds pictures of prediction windows; "
                         "choose one with --window")
    out = _outputs(args, [])
    draw_replay_scene(args.tracks, args.window or SCENE_KINDS[0], args.size).savefig(out)
    return out


def run(args) -> int:
    """``pirl-sim show``: 0, or 2 for a bad input (an unknown column, a frame outside the recording, ...)."""
    from pirl_sim.experiments.replay_scenes import SCENES_FILE
    from pirl_sim.io.interaction import read_tracks

    try:
        if args.tracks.is_dir() and (args.tracks / SCENES_FILE).is_file():
            return finish(_replay_scene(args))
        if args.window is not None:
            raise ValueError(f"--window draws a scene of a replay's output folder; {str(args.tracks)!r} has no "
                             f"{SCENES_FILE}")
        track_file = _track_file(args.tracks, args.file)
        folder = track_file.parent
        map_path = args.map if args.map is not None else (folder / "map.osm" if (folder / "map.osm").is_file()
                                                           else None)
        out = _outputs(args, [track_file, *([map_path] if map_path is not None else [])])
        tracks = read_tracks(track_file)
        from pirl_sim.viz import TrackFrames, animate_scene, draw_recording, draw_scene, road_from_lanelet2

        draw: dict[str, Any] = {"road": road_from_lanelet2(map_path) if map_path is not None else None,
                                "color_by": args.color_by, "size_px": args.size}
        if args.color_by == _STYLE and _STYLE not in tracks.columns:
            draw.update(color_by=_styles(folder), categorical=True, label="style")
        written = out
        if args.span is not None:
            written = animate_scene(tracks, out, start_s=args.span[0], end_s=args.span[1], fps=args.fps,
                                    speed=args.speed, progress=not args.quiet, title=track_file.name, **draw)
        elif args.frame is not None or args.time is not None:
            frames = TrackFrames(tracks)
            frame = args.frame if args.frame is not None else frames.frame_at(args.time)
            draw_scene(frames, frame, title=f"{track_file.name}, frame {frame}", **draw).savefig(out)
        else:
            draw_recording(tracks, title=track_file.name, **draw).savefig(out)
    except (ValueError, TypeError, FileNotFoundError, RuntimeError) as exc:
        return error(exc)
    except OSError as exc:
        return error(f"cannot write {args.out}: {exc.strerror or exc}")
    return finish(written)
