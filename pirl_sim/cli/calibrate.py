"""``pirl-sim calibrate``: fit a population of PIRL drivers to a recording and write it as a scenario TOML that
``pirl-sim simulate`` runs (`pirl_sim.experiments.calibrate`)."""

from __future__ import annotations

from pathlib import Path

from pirl_sim.validation import positive_int_arg

from .common import add_seed_option, add_track_options, error, finish, reworded, subcommand, track_files

__all__ = ["add_parser", "run"]


def _share(text: str) -> float:
    """A number in [0, 1] (ValueError otherwise)."""
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise ValueError(text)
    return value


@subcommand("calibrate", help="fit a driver population to a recording; write a scenario TOML for simulate",
            description="Fit a population of PIRL drivers to recorded cars (INTERACTION track files on their "
            "Lanelet2 map): the desired speed's a_lat and v_max, one weight vector per car by the receding-horizon "
            "IRL on its free-flow steps (the simulated drivers' features, step and horizon; with --interaction on "
            "every step, also weighing the gaps to the vehicle ahead and to the point it yields at), and a Gaussian "
            "mixture over the log weights with the number of styles chosen by BIC. Writes a scenario TOML "
            "([drivers], [population]) for pirl-sim simulate sumo|highway --scenario; the simulated drivers' weights "
            "are drawn from the mixture and written to the ground truth.")
def add_parser(p) -> None:
    """The options of ``calibrate``."""
    add_track_options(p)
    p.add_argument("--out", type=Path, required=True, help="scenario TOML to write")
    p.add_argument("--desired-speed", choices=("likelihood", "speeds"), default="likelihood",
                   help="the desired speed's a_lat and v_max: of greatest likelihood of the cars' driving (their "
                        "weights fitted at each; slower) or fitted to the recorded speeds alone (default likelihood)")
    p.add_argument("--max-styles", type=positive_int_arg, default=4,
                   help="largest number of styles the BIC chooses among (default 4)")
    p.add_argument("--stride", type=positive_int_arg, default=2,
                   help="score every STRIDE-th free-flow step in the per-car fits (default 2)")
    p.add_argument("--n-vehicles", type=positive_int_arg, default=80,
                   help="vehicles in the written population (default 80)")
    p.add_argument("--background-share", type=reworded(_share, "must be a number in [0, 1], got {text!r}"),
                   default=0.0, help="share of them driven by the simulator's own model (default 0)")
    p.add_argument("--road", choices=("map", "ring"), default="map",
                   help="where the written scenario drives: the recording's own roundabout, its routes drawn as often "
                        "as the recorded cars took them (SUMO), or the simulators' parametric ring (SUMO or "
                        "highway-env) (default map)")
    p.add_argument("--interaction", action="store_true",
                   help="also fit the weights of the gap to the vehicle ahead (headway) and to the point a car yields "
                        "at (yielding), on every step of each car: the written drivers interact")
    add_seed_option(p, "the mixture's EM initialisation")


def run(args) -> int:
    """``pirl-sim calibrate``: 0, or 2 for a bad option or unusable data."""
    from pirl_sim.experiments.calibrate import calibrate
    from pirl_sim.io.atomic import atomic_write_text
    from pirl_sim.progress import reporter

    say = reporter(not args.quiet)
    try:
        if not args.tracks.exists():
            raise ValueError(f"--tracks {str(args.tracks)!r}: no such file or folder")
        if not args.map.is_file():
            raise ValueError(f"--map {str(args.map)!r}: no such file")
        files = track_files(args.tracks, args.files)
        cal = calibrate(files, args.map, max_styles=args.max_styles, stride=args.stride, seed=args.seed,
                        desired_speed=args.desired_speed, interaction=args.interaction, progress=say)
        text = cal.scenario_toml(", ".join(Path(f).name for f in files), args.n_vehicles, args.background_share,
                                 road=args.road)
        atomic_write_text(args.out, text)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        return error(exc)
    print(f"{cal.n_styles} style(s) from {len(cal.log_weights)} cars; desired speed a_lat {cal.a_lat:.3g} m/s^2, "
          f"v_max {cal.v_max:.3g} m/s; {cal.depart_rate:.0f} cars/h")
    for style in cal.styles():
        print(f"  {style['name']}: share {style['weight']:.2f}, mean weights "
              + ", ".join(f"{k} {v:.3g}" for k, v in style["mean"].items()))
    return finish(args.out)
