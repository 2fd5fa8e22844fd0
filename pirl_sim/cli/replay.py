"""``pirl-sim replay``: learn from recorded tracks and score predictions against them, through the sweep engine.

The embedded preset ``pirl_sim/experiments/configs/replay.toml`` set by the options (`replay_config`; scenario
``recorded``, `pirl_sim.experiments.recorded`) runs with `pirl_sim.engine.run.run_sweep` into ``--out``
(``cells/``: one cell per split seed and method, stored as it finishes; a rerun of the same command resumes),
then the report template `pirl_sim.experiments.replay_report.write_replay_results` (and
`pirl_sim.experiments.replay_table` with ``--table``). ``--workers N`` runs the split seeds in N sweep worker
processes (forked after the scene is read, so it is read once; 1: in this process).

Defaults that depend on the data. A tracks directory with a pirl_sim ``run.json`` is a *pirl_sim recording*:
its drivers' model settings (path smoothing, desired-speed smoothing, a_lat, v_max) are used for the learned
model, the state estimate trusts its exact speeds (`pirl_sim.scenarios.replay.SIMULATED_NOISE`), and with
``--likelihood receding`` the step ``--dt`` defaults to the drivers' re-planning step and ``--mpc-horizon`` to
their MPC horizon; where it also has ``driver_steps.csv``, ``--selection`` defaults to ``steps``. Anything
else is *real data*: ``--dt 0.2`` (the paper's step), measured-speed noise
(`pirl_sim.scenarios.replay.MEASURED_NOISE`), ``--selection tracks``, and ``--likelihood receding`` needs
``--mpc-horizon``. Times given in seconds (``--history``, ``--horizon``) keep their meaning in seconds
whatever ``--dt``.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import time
from pathlib import Path

from pirl_sim.validation import list_arg, positive_float_arg, positive_int_arg

from .common import command_line, error, interrupted, seconds_to_steps

__all__ = ["add_parser", "run", "replay_config", "replay_settings", "replay_results"]

LEARNERS = ("tirl", "pirl-gmm", "pirl-dpgmm", "pirl-knn")
#: the default roundabouts of ``--table`` (INTERACTION names)
DEV_ROUNDABOUTS = ("DR_USA_Roundabout_EP", "DR_USA_Roundabout_FT", "DR_CHN_Roundabout_LN")
PIECE_DURATION = 20.0  # [s] longer tracks are cut into pieces of this duration (a whole roundabout passage)


def _horizon_arg(text: str) -> int:
    try:
        return positive_int_arg(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"--mpc-horizon must be a positive number of steps, got {text!r}") from None


def add_parser(sub) -> argparse.ArgumentParser:
    """Add ``replay`` to the command's subparsers; returns its parser."""
    rp = sub.add_parser(
        "replay",
        help="learn from recorded tracks (INTERACTION format) and score predictions against them",
        description="Replay INTERACTION-format track files on their Lanelet2 map: select non-interacting drivers, "
        "fit the learners, predict each test track from a history window, score MED/ADE/FDE in metres against "
        "baselines over several split seeds.",
    )
    rp.add_argument("--tracks", type=Path, default=None, help="a vehicle_tracks_*.csv file or a directory of them")
    rp.add_argument("--map", type=Path, default=None, help="the Lanelet2 OSM map of the recording")
    rp.add_argument("--table", type=Path, default=None, metavar="ROOT",
                    help="instead of --tracks/--map: run every roundabout of --roundabouts from an INTERACTION folder "
                         "ROOT (ROOT/recorded_trackfiles/NAME/vehicle_tracks_*.csv, ROOT/maps/NAME.osm) and write "
                         "one table (table.md/.csv) and each roundabout's results in --out/NAME")
    rp.add_argument("--roundabouts", default=",".join(DEV_ROUNDABOUTS),
                    help=f"names for --table (default {','.join(DEV_ROUNDABOUTS)})")
    rp.add_argument("--files", type=positive_int_arg, default=None,
                    help="use only the first N track files (sorted by name) of each recording (default all)")
    rp.add_argument("--futures", type=positive_int_arg, default=None, metavar="K",
                    help="also score K predicted futures per window and learner: minADE_K, minFDE_K, INTERACTION "
                         "miss rate, mixture NLL per step (columns min_ade@K ... in rows.csv; default: off)")
    rp.add_argument("--hindsight", action="store_true",
                    help="also score each test window under the cost fitted on its own recorded future (an oracle "
                         "row, 'hindsight cost (oracle)': what the model class reaches with perfect weights; not a "
                         "predictor, never the best PIRL learner)")
    rp.add_argument("--direct", action="store_true",
                    help="also score a regression without a cost: the arc lengths over the horizon regressed on the "
                         "history's speeds and accelerations, the road ahead and the place (row 'direct regression "
                         "(no cost)', pirl_sim.evaluation.direct): how much the history and the map tell; never the best "
                         "PIRL learner")
    rp.add_argument("--desired-speed", choices=["fit", "fixed"], default="fixed",
                    help="the desired speed's a_lat and v_max: 'fit' on each split's training tracks (robust fit of "
                         "speeds against curvature, pirl_sim.speed_fit) or 'fixed' (--a-lat, --v-max) "
                         "(default fixed)")
    rp.add_argument("--a-lat", type=positive_float_arg, default=None,
                    help="lateral-acceleration limit [m/s^2] of the desired speed (default 1.8; a pirl_sim "
                         "recording's drivers' value)")
    rp.add_argument("--v-max", type=positive_float_arg, default=None,
                    help="speed cap [m/s] of the desired speed (default 13.9; a pirl_sim recording's drivers' value)")
    rp.add_argument("--features", choices=["paper", "speed-level", "following"], default="paper",
                    help="the cost's features: 'paper' (speed_dev, acc_sq, jerk_sq), 'speed-level' (also speed_sq "
                         "and speed_hi: a speed level of each driver's own) or 'following' (speed-level and "
                         "headway: the gap to the recorded vehicle ahead, held at constant velocity over a "
                         "prediction; selection defaults to 'all') (pirl_sim.driving.roundabout_features) "
                         "(default paper)")
    rp.add_argument("--lateral", choices=["hold", "mean-path", "plane", "neighbours"], default="hold",
                    help="lateral offsets of every path-based prediction (baselines and learners): 'hold' the last "
                         "observed one, or follow the training tracks' 'mean-path' of the route, or their mean path "
                         "pooled over routes in the 'plane', or that plus the change of deviation of the nearest "
                         "training windows in the plane, 'neighbours' (pirl_sim.lateral) (default hold)")
    rp.add_argument("--start", choices=["history", "track"], default="history",
                    help="the states every prediction starts from and its learners see: estimated from the 2 s "
                         "history alone ('history': what an online predictor knows), or the whole track's estimate "
                         "('track': a smoother that also saw the future it predicts) "
                         "(default history)")
    rp.add_argument("--learners", default="tirl,pirl-gmm,pirl-knn",
                    help="comma-separated learners: tirl, pirl-gmm, pirl-dpgmm, pirl-knn, pirl-knn-next (PIRL-kNN "
                         "with costs of what followed each training window, looked up by the speed and acceleration "
                         "now, 0.5 s and 1 s ago and the road ahead, its neighbours' futures averaged: "
                         "learners/knn.py), pirl-select (the same costs, a bank of 256 mixed to come nearest to a "
                         "forecast of the next seconds from the same keys and the place: learners/selector.py) "
                         "(default tirl,pirl-gmm,pirl-knn)")
    rp.add_argument("--next-segments", choices=["history", "track"], default=None,
                    help="pirl-knn-next, pirl-select: where each training segment whose cost the IRL fits starts: "
                         "at its history's own estimate, the state an online prediction starts from ('history'), or "
                         "at the smoothed track's state ('track') (default: history "
                         "with --start history)")
    rp.add_argument("--lookup-ahead", type=list_arg(float, low=0, empty=True), default="0,10,20,30,45",
                    metavar="M1,M2,...",
                    help="pirl-knn-next, pirl-select: distances ahead [m] at which the road's curvature joins the "
                         "look-up keys ('' none) (default 0,10,20,30,45)")
    rp.add_argument("--ahead-weights", type=list_arg(float, low=0, empty=True), default="0,0.5,1",
                    metavar="W1,W2,...",
                    help="pirl-knn-next: candidate weights of the road ahead in the look-up; with several, each split "
                         "chooses the one that predicts held-out training windows best (learners/knn.py) "
                         "(default 0,0.5,1)")
    rp.add_argument("--gmm-k", type=positive_int_arg, default=3, help="clusters of PIRL-GMM (default 3)")
    rp.add_argument("--knn-k", type=list_arg(int, low=1), default="10",
                    help="neighbours of PIRL-kNN; several comma-separated values run one learner each and draw MED vs k "
                         "(default 10)")
    rp.add_argument("--seeds", type=positive_int_arg, default=3, help="number of train/test split seeds (default 3)")
    rp.add_argument("--workers", type=positive_int_arg, default=1,
                    help="split seeds run in this many sweep worker processes at once (default 1: in this process; "
                         "the results do not depend on it)")
    rp.add_argument("--history", type=positive_float_arg, default=2.0,
                    help="observed history [s], at least one step of --dt (default 2)")
    rp.add_argument("--horizon", type=positive_float_arg, default=3.0,
                    help="predicted horizon [s], at least one step of --dt (default 3)")
    rp.add_argument("--likelihood", choices=["trajectory", "receding"], default="trajectory",
                    help="the IRL's model of a demonstration: 'trajectory' (the paper's: one open-loop optimum) or "
                         "'receding' (each step's control is the first of an MPC plan over --mpc-horizon steps) "
                         "(default trajectory)")
    rp.add_argument("--mpc-horizon", type=_horizon_arg, default=None, metavar="H",
                    help="the drivers' MPC horizon [steps of --dt] for --likelihood receding and closed-loop "
                         "rollouts (default: drivers.horizon of a pirl_sim recording's run.json; required for "
                         "real data)")
    rp.add_argument("--dt", type=positive_float_arg, default=None,
                    help="model step [s], a multiple of the 0.1 s frames (default 0.2, the paper's; with "
                         "--likelihood receding on a pirl_sim recording its drivers' re-planning step)")
    rp.add_argument("--estimate", choices=["positions", "speeds"], default=None,
                    help="state estimate from positions only or from positions and recorded speeds (default: "
                         "speeds, positions with --start track and the trajectory likelihood)")
    rp.add_argument("--sigma-v", type=positive_float_arg, default=None,
                    help="speed noise [m/s] of --estimate speeds (default 0.05 for real data, 0.001 for pirl_sim "
                         "recordings)")
    rp.add_argument("--sigma-j", type=positive_float_arg, default=None,
                    help="jerk prior [m/s^3] of --estimate speeds (default 1 for real data, 3 for pirl_sim "
                         "recordings)")
    rp.add_argument("--selection", choices=["tracks", "steps", "free", "all"], default=None,
                    help="'tracks': whole tracks without a leader (the paper's); 'free': every track cut into its "
                         "free-flow runs (steps with a leader closer than 3 m bumper to bumper + 1.5 s x speed left "
                         "out); 'steps': every PIRL track with "
                         "a per-step mask from driver_steps.csv (pirl_sim recordings, --likelihood receding only); "
                         "'all': every track whole, leaders included (for --features following). "
                         "Default: steps where driver_steps.csv exists and the likelihood is receding, all with "
                         "--features following, free with --table, else tracks")
    rp.add_argument("--rollout", choices=["open", "closed"], default=None,
                    help="learners' predictions: 'open' (one MPC plan) or 'closed' (re-plan every step over "
                         "--mpc-horizon steps, as the drivers) (default: closed with --likelihood receding, open "
                         "otherwise)")
    rp.add_argument("--scan-horizon", type=list_arg(int, low=1), default=None, metavar="H1,H2,...",
                    help="instead of the replay: for each MPC horizon [steps], fit TIRL with the receding likelihood "
                         "on the training tracks and report the held-out residual NLL per step and MED "
                         "(horizon_scan.csv/.md)")
    rp.add_argument("--out", type=Path, default=Path("results") / "replay", help="output directory")
    rp.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    rp.add_argument("--dry-run", action="store_true",
                    help="validate the options and the scene's files, count the cells (one per split seed and method) "
                         "and those already in --out; run nothing")
    return rp


def replay_settings(args) -> dict:
    """Resolve the data-dependent defaults (module doc) into keyword arguments and protocol values.

    Returns dict with ``load`` (keyword arguments of `load_replay` besides files and map), ``dt``,
    ``mpc_horizon``, ``likelihood``, ``rollout``, ``recording`` (DriverSettings or None) and ``notes``.

    Raises ValueError for combinations that cannot work (naming the option).
    """
    from pirl_sim.scenarios.replay import (DRIVER_STEPS_FILE, MEASURED_NOISE, SIMULATED_NOISE, EstimateNoise,
                                           is_recording, recording_settings)

    rec = recording_settings(args.tracks)
    receding = args.likelihood == "receding"
    notes = []
    if args.dt is not None:
        dt = float(args.dt)
    elif receding and rec is not None:
        dt = rec.dt
        notes.append(f"--dt {dt:g} s: the drivers' re-planning step (run.json)")
    else:
        dt = 0.2
    horizon = args.mpc_horizon
    if horizon is None and rec is not None:
        if abs(dt - rec.dt) < 1e-9:
            horizon = rec.horizon
            notes.append(f"--mpc-horizon {horizon}: the drivers' drivers.horizon (run.json)")
        elif receding:
            raise ValueError(f"--dt {dt:g} s differs from the drivers' re-planning step {rec.dt:g} s, so their "
                             f"horizon of {rec.horizon} steps does not apply: give --mpc-horizon in steps of --dt")
    rollout = args.rollout or ("closed" if receding else "open")
    if (receding or rollout == "closed") and horizon is None and args.scan_horizon is None:  # a scan gives H
        what = "--likelihood receding" if receding else "--rollout closed"
        raise ValueError(f"{what} needs the drivers' MPC horizon: give --mpc-horizon H (steps of --dt = {dt:g} s); "
                         f"{args.tracks} is not a pirl_sim recording with a run.json to take it from")
    steps_file = (args.tracks if args.tracks.is_dir() else args.tracks.parent) / DRIVER_STEPS_FILE
    selection = args.selection or ("steps" if receding and steps_file.is_file() else
                                   "all" if getattr(args, "features", "paper") == "following" else
                                   "free" if getattr(args, "table", None) is not None else "tracks")
    if selection == "steps" and not receding:
        raise ValueError("--selection steps needs --likelihood receding: the trajectory likelihood scores whole "
                         "trajectories and cannot leave the overridden steps out")
    if selection == "steps" and not steps_file.is_file():
        raise ValueError(f"--selection steps needs {DRIVER_STEPS_FILE} beside the tracks (pirl_sim recordings); "
                         f"none in {steps_file.parent}")
    # history starts: a position-only fit over 2 s damps the jerks so hard that its last speed lags the car's
    estimate = args.estimate or ("speeds" if receding or getattr(args, "start", "history") == "history"
                                 else "positions")
    base = SIMULATED_NOISE if is_recording(args.tracks) else MEASURED_NOISE
    noise = EstimateNoise(base.sigma_s, args.sigma_v or base.sigma_v, args.sigma_j or base.sigma_j, base.sigma_a)
    load = {"dt": dt, "estimate": estimate, "noise": noise, "selection": selection,
            "max_steps": max(1, int(round(PIECE_DURATION / dt))), "features": getattr(args, "features", "paper")}
    if is_recording(args.tracks):  # simulated drivers plan from their projected positions
        load["arc_length"] = "observed"
    if rec is not None:
        load.update(smoothing=rec.smoothing, speed_smoothing=rec.speed_smoothing, a_lat=rec.a_lat, v_max=rec.v_max)
        notes.append(f"model: the drivers' path smoothing {rec.smoothing:g} m, desired-speed smoothing "
                     f"{rec.speed_smoothing:g} m, a_lat {rec.a_lat:g}, v_max {rec.v_max:g} (run.json)")
    for name in ("a_lat", "v_max"):
        if getattr(args, name, None) is not None:
            load[name] = float(getattr(args, name))
    return {"load": load, "dt": dt, "mpc_horizon": horizon, "likelihood": args.likelihood, "rollout": rollout,
            "recording": rec, "notes": notes}


def _steps(seconds: float, dt: float) -> int:
    return max(1, int(round(seconds / dt)))


NEXT_KNN = "pirl-knn-next"  #: PIRL-kNN with target="next" (learners/knn.py), a key of --learners only
SELECT = "pirl-select"  #: the same costs chosen by a learned forecast (aggregate="selected"), a key of --learners only
ALWAYS = ("cv", "ca", "cv-xy")  #: the baselines of every replay (pseudo-learners of the preset)


def _cli_key(entry: dict) -> str:
    """The --learners key of a preset learner entry."""
    params = entry.get("params", {})
    if params.get("target") == "next":
        return SELECT if params.get("aggregate") == "selected" else NEXT_KNN
    return entry["name"]


def replay_config(args, settings: dict, tracks, map_path):
    """The embedded preset ``pirl_sim/experiments/configs/replay.toml`` with the command line's choices (see the preset's
    comment) as a validated `pirl_sim.engine.config.SweepConfig` of the scene ``tracks`` on ``map_path``.

    Raises
    ------
    ValueError
        Unknown learners, a bad --knn-k, or anything the sweep config rejects (named there).
    """
    from pirl_sim.engine.config import parse_config

    return parse_config(_replay_data(args, settings, tracks, map_path), source="<replay>")


def _replay_data(args, settings: dict, tracks, map_path) -> dict:
    """`replay_config`'s config as TOML data, before its check."""
    import tomllib

    from pirl_sim.engine.config import preset_text
    from pirl_sim.experiments.recorded import history_lags

    keys = [k.strip() for k in args.learners.split(",") if k.strip()]
    known = sorted([*LEARNERS, NEXT_KNN, SELECT])
    unknown = [k for k in keys if k not in known]
    if unknown or not keys:
        raise ValueError(f"unknown learners {unknown or keys}; choose from {known}")
    if "tirl" not in keys:
        keys.insert(0, "tirl")  # the reference of the paired differences
    dt, p = settings["dt"], _protocol(args, settings)
    text = preset_text("replay")
    data = tomllib.loads(text)
    data["seeds"] = list(range(args.seeds))
    exp = data["experiments"][0]
    exp["protocols"] = [{"kind": "rolling", "history_steps": p.history, "horizon": p.horizon, "stride": p.stride}]
    receding = settings["likelihood"] == "receding"
    irl = {"likelihood": "receding", "horizon": int(settings["mpc_horizon"])} if receding else {}
    learners = []
    for entry in ({"name": e} if isinstance(e, str) else dict(e) for e in exp["learners"]):
        key = _cli_key(entry)
        if key not in (*ALWAYS, *keys) and not (key == "hindsight" and args.hindsight) \
                and not (key == "direct" and args.direct):
            continue
        if key in keys:
            params = {**entry.get("params", {}), **irl}
            if receding:
                params.pop("prior", None)  # a prior of the trajectory likelihood's Laplace fit
            if key == "pirl-gmm":
                params["n_components"] = args.gmm_k
            if key in (NEXT_KNN, SELECT):
                segments = args.next_segments or ("history" if p.start == "history" else "track")
                if segments == "history" and p.start != "history":
                    raise ValueError("--next-segments history starts the training segments at their histories' "
                                     "own estimates, which --start track does not make: use --start history")
                params.update(target_steps=p.horizon, state_lags=history_lags(dt, p.history),
                              lookup_history=p.start == "history",
                              segment_start=segments, lookup_ahead=list(args.lookup_ahead),
                              ahead_weights=list(args.ahead_weights))
            if entry["name"] == "pirl-knn" and key != SELECT:  # the bank's choice has no neighbours
                entry["grid"] = {"n_neighbors": list(args.knn_k)}
            entry["params"] = params
        learners.append(entry)
    # learners in the order of --learners, between the baselines along the path and the others
    rank = {k: i for i, k in enumerate(keys)}
    exp["learners"] = sorted(learners, key=lambda e: (-1 if e["name"] in ("cv", "ca") else
                                                      rank.get(_cli_key(e), len(rank))))
    load = {k: (dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v) for k, v in settings["load"].items()}
    replay = {"fde_steps": list(p.fde_steps), "rollout": p.rollout, "lateral": p.lateral, "start": p.start,
              "n_futures": args.futures or 0,
              **({"mpc_horizon": p.mpc_horizon} if p.mpc_horizon is not None else {}),
              **({"desired_speed": "fit"} if args.desired_speed == "fit" else {})}
    exp["params"] = {"tracks": str(tracks), "map": str(map_path), "files": args.files or 0, "load": load,
                     "replay": replay}
    return data


def replay_results(config, run, scene, proto) -> dict:
    """The report template's result dict (`pirl_sim.experiments.replay_report.collect_replay`) from the stored cells of a
    finished `run_sweep` of ``config`` (a `replay_config` with the protocol ``proto``; every cell finished:
    `SweepRun.check_failed` passed) over ``scene`` (the scene its cells replayed)."""
    from pirl_sim.experiments.recorded import decode_method, method_id
    from pirl_sim.experiments.replay_report import collect_replay

    label = {method_id(c.spec()): c.learner_label for c in config.cells}
    per_seed: dict = {}
    for cell, key in zip(config.cells, run.keys):  # learner by learner, the seeds inside: a seed's methods in order
        entry, examples = decode_method(run.records[key]["result"])
        entry["row"] = {**entry["row"], "method": cell.learner_label}
        if entry["row"].get("irl_from"):
            entry["row"]["irl_from"] = label[entry["row"]["irl_from"]]
        per_seed.setdefault(cell.seed, {"methods": {}, "examples": examples})["methods"][cell.learner_label] = entry
    return collect_replay(scene, proto, per_seed, [(c.learner_label, c.learner, c.learner_params)
                                                   for c in config.cells])


def _replay(a, settings, out, say) -> tuple:
    """One scene (``a.tracks``, ``a.map``: the command's arguments, or their copy for one roundabout of --table)
    through the sweep engine into ``out``; returns (result, scene, protocol), result and scene None with
    ``--dry-run``. Finished cells in ``out/cells/`` are reused: an interrupted replay resumes."""
    config = replay_config(a, settings, a.tracks, a.map)  # validated before any work
    proto = _protocol(a, settings)
    run, scene = _run_cells(config, a, settings, out, say)
    return (None if run is None else replay_results(config, run, scene, proto)), scene, proto


def _run_cells(config, a, settings, out, say) -> tuple:
    """The cells of ``config`` (one recorded scene) into ``out``: (run, scene), both None with ``--dry-run``
    (which prints the counts). The scene is read here first: too few usable tracks fail before any cell, and
    ``--workers N`` > 1 forks N sweep workers that inherit it."""
    from pirl_sim.engine.executors import InlineExecutor, LocalExecutor
    from pirl_sim.engine.run import plan_cells, run_sweep
    from pirl_sim.engine.store import ResultStore
    from pirl_sim.experiments.recorded import load_scene, recorded_files, usable_tracks

    if a.dry_run:
        version, _, unique, records, _ = plan_cells(config, ResultStore(out))
        print(f"{config.experiments[0].label} of {a.tracks}: {len(unique)} cells, {len(records)} already in "
              f"{out}/, {len(unique) - len(records)} to run (code {version})")
        return None, None
    files = recorded_files(config.cells[0].scenario_params)
    say(f"reading {len(files)} track files and {a.map} (dt {settings['dt']:g} s, estimate "
        f"{settings['load']['estimate']}, selection {settings['load']['selection']})")
    scene = load_scene(dict(config.cells[0].scenario_params))  # the cells' scene (kept for them when inline)
    usable_tracks(scene, _protocol(a, settings, a.scan_horizon))
    with (InlineExecutor() if a.workers == 1 else LocalExecutor(a.workers, start_method="fork")) as executor:
        run = run_sweep(config, out, executor=executor, progress=not a.quiet, command=command_line("replay", []),
                        tables=False)
    run.check_failed(f"the {config.experiments[0].label}'s cells")
    say(f"{scene.n_converted} tracks converted (in {len(scene.trajectories)} pieces), {scene.n_selected_tracks} "
        f"selected; skipped {scene.skipped}; route repairs {scene.repairs}"
        + (f"; steps {scene.steps}" if scene.steps else ""))
    return run, scene


def run(args) -> int:
    """``pirl-sim replay``: 0, 2 for a bad option or unusable data, 130 when interrupted (finished cells are
    kept)."""
    from pirl_sim.experiments.replay_report import summarize, write_replay_results
    from pirl_sim.progress import reporter

    say = reporter(not args.quiet)
    if args.table is None and (args.tracks is None or args.map is None):
        return error("replay needs --tracks and --map (or --table ROOT)")
    try:
        if args.table is not None:
            return _run_table(args, say)
        settings = replay_settings(args)
        for note in settings["notes"]:
            say(note)
        if args.scan_horizon is not None:
            return _scan(args, settings, say)
        result, scene, _ = _replay(args, settings, args.out, say)
        if result is None:  # --dry-run
            return 0
    except (ValueError, FileNotFoundError, RuntimeError) as exc:
        return error(exc)
    except KeyboardInterrupt:
        return interrupted(args.out)
    write_replay_results(result, scene, args.out, command_line("replay", []))
    print(summarize(result).to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    print(result["paired_ca"].to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    print(f"wrote {args.out}/")
    return 0


def _scan(args, settings, say) -> int:
    """``--scan-horizon H1,H2,...``: the replay's scene and windows as the ``horizon-scan`` kind
    (`pirl_sim.experiments.horizon_scan`, one cell per split seed and H) instead of the replay."""
    from pirl_sim.engine.config import parse_config
    from pirl_sim.experiments.horizon_scan import LEARNER, scan_rows, write_scan

    data = _replay_data(args, {**settings, "mpc_horizon": settings["mpc_horizon"] or args.scan_horizon[0]},
                        args.tracks, args.map)
    exp = data["experiments"][0]
    exp.update(scenario="horizon-scan", label="horizon scan",
               learners=[{"name": LEARNER, "grid": {"horizon": list(args.scan_horizon)}}])
    exp["params"]["replay"] = {k: v for k, v in exp["params"]["replay"].items()
                               if k not in ("rollout", "mpc_horizon", "n_futures")}
    config = parse_config(data, source="<replay --scan-horizon>")
    run, _ = _run_cells(config, args, settings, args.out, say)
    if run is None:  # --dry-run
        return 0
    table = write_scan(scan_rows([run.records[k]["result"] for k in run.keys]), args.out,
                       command_line("replay", []))
    print(table.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    print(f"wrote {args.out}/")
    return 0


def _protocol(args, settings, scan=None):
    from pirl_sim.experiments.recorded import ReplayProtocol

    dt, horizon = settings["dt"], settings["mpc_horizon"]
    return ReplayProtocol(history=seconds_to_steps(args.history, dt, "--history"),
                          horizon=seconds_to_steps(args.horizon, dt, "--horizon"),
                          fde_steps=tuple(sorted({_steps(x, dt) for x in (1.0, 2.0, args.horizon)
                                                  if x <= args.horizon})),
                          stride=_steps(1.0, dt), seeds=tuple(range(args.seeds)), rollout=settings["rollout"],
                          mpc_horizon=horizon or (scan[0] if scan else None),
                          lateral=getattr(args, "lateral", "hold"), start=getattr(args, "start", "history"))


def _run_table(args, say) -> int:
    """``replay --table ROOT``: every roundabout of ``--roundabouts`` in turn (each through the sweep engine into
    ``--out/NAME``), then the table (`pirl_sim.experiments.replay_table`); errors are the command's to report."""
    from pirl_sim.experiments.recorded import recorded_files
    from pirl_sim.experiments.replay_report import write_replay_results
    from pirl_sim.experiments.replay_table import table_row, write_table

    names = [n.strip() for n in str(args.roundabouts).split(",") if n.strip()]
    rows = []
    for name in names:
        t0 = time.perf_counter()
        a = copy.copy(args)
        a.tracks = args.table / "recorded_trackfiles" / name
        a.map = args.table / "maps" / f"{name}.osm"
        if not a.map.is_file():
            raise FileNotFoundError(f"no map {a.map}")
        settings = replay_settings(a)
        result, scene, proto = _replay(a, settings, args.out / name, lambda m: say(f"{name}: {m}"))
        if result is None:  # --dry-run
            continue
        write_replay_results(result, scene, args.out / name, command_line("replay", []))
        elapsed = time.perf_counter() - t0
        files = [f.name for f in recorded_files({"tracks": a.tracks, "files": args.files or 0})]
        rows.append(table_row(name, files, result, scene, proto, elapsed))
        say(f"{name}: done in {elapsed:.0f} s")
    if args.dry_run:
        return 0
    text = write_table(rows, args.out, command_line("replay", []))
    print(text)
    print(f"wrote {args.out}/")
    return 0
