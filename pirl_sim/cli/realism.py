"""``pirl-sim realism``: how real simulated traffic is against a recording of the same roundabout (per-feature
likelihoods, a weighted meta-metric with a 95 % interval over rollouts, distributions side by side)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from pirl_sim.validation import positive_int_arg

from .common import error, finish, reworded, subcommand, track_files

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["add_parser", "run"]


def _source(text: str) -> tuple[str, list[Path]]:
    """argparse type of ``--source``: ``LABEL=PATH[,PATH...]``, one rollout per path."""
    label, sep, paths = text.partition("=")
    label = label.strip()
    if not sep or not label or not paths.strip():
        raise argparse.ArgumentTypeError(f"expected LABEL=PATH[,PATH...] (one rollout per path), got {text!r}")
    return label, [Path(p.strip()) for p in paths.split(",") if p.strip()]


def _scenario(text: str) -> tuple[str, Path]:
    """argparse type of ``--scenario`` and ``--highway-scenario``: ``LABEL=TOML``, a scenario simulated for
    ``--seeds`` seeds."""
    label, sep, path = text.partition("=")
    label, path = label.strip(), path.strip()
    if not sep or not label or not path or "," in path:
        raise argparse.ArgumentTypeError(f"expected LABEL=SCENARIO.toml (one scenario), got {text!r}")
    return label, Path(path)


#: argparse type of ``--seeds``: a count >= 1
_seeds = reworded(positive_int_arg, "expected a whole number of seeds >= 1, got {text!r}")


@subcommand("realism", help="score simulated traffic against a recording: feature likelihoods and a meta-metric",
            description="Score how real simulated traffic is. The reference (recorded track files) is scored under "
            "the histograms of each source's features (speed, acceleration, jerk, yaw rate and its rate, lateral "
            "acceleration, distance to the nearest vehicle, gap, time headway and time to collision to the leader, "
            "stopped time, collisions, and with --map the offset from the lane centre, the wait before entering the "
            "ring and the time gap accepted there, these two for reading only). A source is LABEL=PATH,..., "
            "each PATH one rollout (a track file, or a folder whose track files make one rollout); the meta-metric "
            "is given per source as the mean over its rollouts with a 95 %% interval. Give the recording's other "
            "files as a source for the real-against-real reference row. A --scenario LABEL=TOML source is a SUMO "
            "scenario (e.g. from pirl-sim calibrate) run here for --seeds seeds into OUT/runs/LABEL/seed_S, a "
            "--highway-scenario LABEL=TOML source the same on highway-env (the same file runs in both); a run "
            "finished earlier is kept, so an interrupted command resumes where it stopped.")
def add_parser(p) -> None:
    """The options of ``realism``."""
    p.add_argument("--reference", type=Path, nargs="+", required=True, metavar="PATH",
                   help="the recorded track files (or folders of them) that are scored")
    p.add_argument("--source", type=_source, action="append", default=[], metavar="LABEL=PATH[,PATH...]",
                   help="a simulated source and its rollouts (repeat for several sources)")
    p.add_argument("--scenario", type=_scenario, action="append", default=[], metavar="LABEL=TOML",
                   help="a source simulated here: a SUMO scenario TOML run for --seeds seeds (repeat for several)")
    p.add_argument("--highway-scenario", type=_scenario, action="append", default=[], metavar="LABEL=TOML",
                   help="a source simulated here on highway-env: a scenario TOML run for --seeds seeds (repeat "
                        "for several)")
    p.add_argument("--seeds", type=_seeds, default=3,
                   help="seeds 0..N-1 of each --scenario and --highway-scenario (default 3)")
    p.add_argument("--map", type=Path, help="the Lanelet2 map (.osm): adds the lane-centre offset")
    p.add_argument("--out", type=Path, default=Path("realism"),
                   help="output folder: summary.csv, features.csv, realism.png, overlaps.csv and (with --map or "
                        "overlaps) overlaps.png (default ./realism)")


def _features(paths: list[Path], lmap):
    """The features of the tracks of ``paths`` (track files, or folders of them: `track_files`) on ``lmap``."""
    from pirl_sim.evaluation.realism import TrackFeatures, track_features
    from pirl_sim.io.interaction import read_tracks

    return TrackFeatures.combine([track_features(read_tracks(f), lmap) for p in paths for f in track_files(p)])


def _simulated(label: str, scenario: Path, seeds: int, out: Path, simulator: str) -> list[Path]:
    """The run folders of seeds ``0 .. seeds - 1`` of a scenario under ``out/runs/label``; a folder that holds a
    finished recording (its ``run.json``) is kept, the others are simulated in this process (``simulator``
    ``"sumo"``: libsumo, ``"highway"``: highway-env)."""
    from pirl_sim.scenarios.recording import INFO_FILE
    from pirl_sim.scenarios.simulators import simulator_scenarios

    sim = simulator_scenarios(simulator)
    load_scenario, simulate = sim.load, sim.run
    config = load_scenario(scenario)
    dirs = [out / "runs" / label / f"seed_{s}" for s in range(seeds)]
    for s, d in enumerate(dirs):
        if not (d / INFO_FILE).is_file():
            print(f"{label}: simulating seed {s} of {scenario}", flush=True)
            simulate(config, s, out_dir=d)
    return dirs


def run(args) -> int:
    """``pirl-sim realism``: 0, or 2 for a bad input (a missing file, a repeated label, tracks without samples)."""
    import pandas as pd

    from pirl_sim.evaluation.realism import compare_sources, overlap_map, realism_figure
    from pirl_sim.io.atomic import atomic_write_text
    from pirl_sim.io.lanelet2_map import load_map
    from pirl_sim.validation import check_output_dir
    from pirl_sim.viz import road_from_lanelet2

    try:
        scenarios = [(*x, "sumo") for x in args.scenario] + [(*x, "highway") for x in args.highway_scenario]
        if not args.source and not scenarios:
            raise ValueError("nothing to score: give at least one --source LABEL=PATH,..., --scenario LABEL=TOML or "
                             "--highway-scenario LABEL=TOML")
        labels = [label for label, *_ in [*args.source, *scenarios]]
        repeated = sorted({x for x in labels if labels.count(x) > 1})
        if repeated:
            raise ValueError(f"--source, --scenario and --highway-scenario labels must differ; repeated: {repeated}")
        for p in [*args.reference, *(q for _, ps in args.source for q in ps), *(s for _, s, _ in scenarios),
                  *([args.map] if args.map else [])]:
            if not p.exists():
                raise ValueError(f"{str(p)!r}: no such file or folder")
        out, lmap = check_output_dir(args.out), load_map(args.map) if args.map is not None else None
        reference = _features(list(args.reference), lmap)
        rollouts = dict(args.source)
        for label, scenario, simulator in scenarios:
            rollouts[label] = _simulated(label, scenario, args.seeds, out, simulator)
        sources = {label: [_features([p], lmap) for p in paths] for label, paths in rollouts.items()}
        summary, features = compare_sources(reference, sources)
        summary.to_csv(out / "summary.csv", index=False)
        features.to_csv(out / "features.csv", index=False)
        realism_figure(reference, sources, out / "realism.png")
        overlaps = _overlaps(reference, sources)
        atomic_write_text(out / "overlaps.csv", overlaps.to_csv(index=False))
        drawn = lmap is not None or len(overlaps) > 0
        if drawn:
            overlap_map({label: g for label, g in overlaps.groupby("source", sort=False)}, out / "overlaps.png",
                        road=road_from_lanelet2(lmap) if lmap is not None else None,
                        title="where vehicles overlap (first frame of each pair)")
    except (ValueError, TypeError, FileNotFoundError) as exc:
        return error(exc)
    with pd.option_context("display.width", 160, "display.max_columns", 20):
        print(f"reference: {reference.n_vehicles} vehicles, {reference.duration_s / 3600:.2f} vehicle-hours")
        print(summary.round(3).to_string(index=False))
        print(features.groupby(["feature", "source"], sort=False)["likelihood"].mean().unstack("source")
              .round(3).to_string())
    pairs = overlaps.groupby("source", sort=False).size().reindex(["reference", *sources], fill_value=0)
    print("pairs of vehicles whose boxes overlap (all rollouts): "
          + ", ".join(f"{label} {n}" for label, n in pairs.items()))
    written = ["summary.csv", "features.csv", "realism.png", "overlaps.csv"] + (["overlaps.png"] if drawn else [])
    return finish(", ".join(str(out / name) for name in written))


def _overlaps(reference, sources) -> pd.DataFrame:
    """The overlapping pairs of the reference and of every source's rollouts in one table: ``source``,
    ``rollout``, ``part`` (the track file within the rollout), then `pirl_sim.evaluation.realism.OVERLAP_COLUMNS`."""
    import pandas as pd

    from pirl_sim.evaluation.realism import OVERLAP_COLUMNS

    parts = [reference.overlaps.assign(source="reference", rollout=0)]
    parts += [f.overlaps.assign(source=label, rollout=r) for label, feats in sources.items() for r, f in enumerate(feats)]
    return pd.concat(parts, ignore_index=True)[["source", "rollout", "part", *OVERLAP_COLUMNS]]
