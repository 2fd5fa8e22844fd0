"""Scenes, recordings and runs that several test modules replay: one copy of each builder (plain functions; the
session fixtures built from them are in tests/conftest.py). Test modules ``import replay_scenes`` (tests/conftest.py
puts tests/ on sys.path; under --import-mode=importlib a test module cannot import another test module).

- generated roundabout passages written as recordings: `passage_scene`, `passage_root` (an INTERACTION folder),
  `small_replay` (a ``pirl-sim replay`` output);
- straight lanes written as INTERACTION files: `track_rows`, `straight_scene`, `two_lane_scene_dir`,
  `write_ground_truth`, `real_like_scene` (the weaving cars: tests/weaving.py);
- a small SUMO recording and its replay scene: `run_small_sumo`, `load_sumo_scene`;
- an in-memory recording: `recording_lanes`, `make_recording`;
- the replay through the sweep engine, as ``pirl-sim replay`` runs it: `replay_with_engine`;
- `check_bad_read_options`: a reader of recordings refusing unknown options.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

# ------------------------------------------------------------------------------ generated passages
ROUNDABOUT = "SIM_Roundabout_A"  #: the scene's name in `passage_root`


def passage_scene(out, n_trajectories=160, n_train=130, seed=4):
    """A generated roundabout-passage scene written into ``out`` as a pirl_sim recording (tracks, ground truth,
    map, run.json): (out, the `PassageData`)."""
    from pirl_sim.scenarios.passage import PassageConfig, generate, write_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate(PassageConfig(n_trajectories=n_trajectories, n_train=n_train, seed=seed))
    write_scene(data, out)
    return out, data


def passage_root(root: Path, name: str = ROUNDABOUT) -> Path:
    """A simulated roundabout scene (40 passages, seed 4) laid out in ``root`` as an INTERACTION folder
    (recorded_trackfiles/NAME, maps/NAME.osm): ``root``."""
    scene = root / "recorded_trackfiles" / name
    scene.mkdir(parents=True)
    passage_scene(scene, n_trajectories=40, n_train=30, seed=4)
    (root / "maps").mkdir()
    (scene / "map.osm").rename(root / "maps" / f"{name}.osm")
    return root


def roundabout_files(root: Path, name: str = ROUNDABOUT) -> tuple[Path, Path]:
    """(track file, map) of the scene ``name`` of a `passage_root` folder."""
    return root / "recorded_trackfiles" / name / "vehicle_tracks_000.csv", root / "maps" / f"{name}.osm"


def small_replay(root: Path) -> Path:
    """A small ``pirl-sim replay`` (one split seed, TIRL and the baselines) of a generated passage scene (40
    passages, seed 2, in root/scene) into root/out: the output directory."""
    pytest.importorskip("lanelet2")
    from pirl_sim.cli import main

    passage_scene(root / "scene", n_trajectories=40, n_train=30, seed=2)
    out = root / "out"
    assert main(["replay", "--preset", "paper",
                 "--tracks", str(root / "scene"), "--map", str(root / "scene" / "map.osm"), "--seeds", "1",
                 "--learners", "tirl", "--quiet", "--out", str(out)]) == 0
    return out


# ------------------------------------------------------------------------------ straight lanes
LANE_LENGTH = 500.0  # [m]
LANE_Y = {"A": 0.0, "B": 60.0}  # two parallel straight lanes, both +x, no routing-graph link between them
THETA = {"speed_dev": 1.0, "acc_sq": 2.0, "jerk_sq": 1.0}  # raw weights of the ground-truth sidecars


def track_rows(track_id, first_frame, x0, n, y, speed=10.0) -> pd.DataFrame:
    """INTERACTION rows of a car driving +x at ``speed`` [m/s] from ``x0`` [m] for ``n`` frames at ``y``."""
    frames = np.arange(first_frame, first_frame + n)
    x = x0 + speed * 0.1 * np.arange(n)
    yy = np.broadcast_to(np.asarray(y, dtype=float), (n,))
    return pd.DataFrame({"track_id": track_id, "frame_id": frames, "timestamp_ms": 100 * frames, "agent_type": "car",
                         "x": x, "y": yy, "vx": speed, "vy": 0.0, "psi_rad": 0.0, "length": 4.5, "width": 1.8})


def straight_scene(d: Path, tracks, speed=10.0) -> tuple[Path, Path]:
    """A map of the two lanes (`LANE_Y`) and one track file in ``d``; tracks: list of (lane, x0 [m], frames,
    y override or None), each in its own frames (no two tracks share a frame: nobody interacts). Returns (track
    file, map)."""
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map

    d.mkdir(parents=True, exist_ok=True)
    x = np.linspace(0.0, LANE_LENGTH, 41)
    write_map({k: np.column_stack([x, np.full_like(x, y)]) for k, y in LANE_Y.items()}, {}, d / "map.osm")
    rows, frame = [], 1
    for i, (lane, x0, n, y) in enumerate(tracks):
        rows.append(track_rows(i + 1, frame, x0, n, LANE_Y[lane] if y is None else y, speed))
        frame += n + 10
    write_tracks(pd.concat(rows, ignore_index=True), d / "vehicle_tracks_000.csv")
    return d / "vehicle_tracks_000.csv", d / "map.osm"


def two_lane_scene_dir(d: Path, n_tracks=8, n_frames=150, speed=10.0) -> tuple[Path, Path]:
    """`straight_scene` of ``n_tracks`` tracks of ``n_frames`` frames from x = 5 m, on lanes A and B in turn."""
    return straight_scene(d, [("AB"[i % 2], 5.0, n_frames, None) for i in range(n_tracks)], speed)


def write_ground_truth(d: Path, ids, styles, theta=THETA) -> None:
    """ground_truth.csv in ``d``: a style >= 0 with weights for PIRL tracks, style -1 without weights for the
    others."""
    rows = [{"track_id": i, "style": s, **{f"theta_{k}": (v if s >= 0 else np.nan) for k, v in theta.items()}}
            for i, s in zip(ids, styles)]
    pd.DataFrame(rows).to_csv(d / "ground_truth.csv", index=False)


def real_like_scene(d: Path) -> Path:
    """One straight lane and six tracks, no run.json (data as real data come) in ``d``: ``d``."""
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map

    x = np.linspace(0.0, 400.0, 41)
    write_map({"A": np.column_stack([x, np.zeros_like(x)])}, {}, d / "map.osm")
    rows = []
    for i in range(6):
        n = 80
        frames = np.arange(1 + 100 * i, 1 + 100 * i + n)
        rows.append(pd.DataFrame({"track_id": i + 1, "frame_id": frames, "timestamp_ms": 100 * frames,
                                  "agent_type": "car", "x": 10.0 + np.arange(n), "y": 0.0, "vx": 10.0, "vy": 0.0,
                                  "psi_rad": 0.0, "length": 4.5, "width": 1.8}))
    write_tracks(pd.concat(rows, ignore_index=True), d / "vehicle_tracks_000.csv")
    return d


# ------------------------------------------------------------------------------ SUMO
def run_small_sumo(out: Path):
    """A small SUMO run (20 vehicles departing every 1.5 s, drivers re-planning over 30 steps of 0.1 s, seed 1)
    written as a recording into ``out``: the run's result (skips without libsumo)."""
    pytest.importorskip("libsumo")
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION
    from pirl_sim.scenarios.sumo import SumoScenarioConfig, run_sumo_scenario

    pop = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=20, depart_interval=1.5)
    return run_sumo_scenario(SumoScenarioConfig(population=pop), seed=1, out_dir=out)


def load_sumo_scene(run: Path, **kw):
    """The replay scene of a pirl_sim recording ``run`` read as ``pirl-sim replay --likelihood receding`` reads
    it (the drivers' own settings from run.json, recorded speeds, per-step masks), ``kw`` overriding
    `load_replay`'s arguments: (scene, `recording_settings`)."""
    from pirl_sim.scenarios.replay import SIMULATED_NOISE, load_replay, recording_settings

    rec = recording_settings(run)
    args = dict(dt=rec.dt, estimate="speeds", noise=SIMULATED_NOISE, selection="steps", max_steps=None,
                smoothing=rec.smoothing, speed_smoothing=rec.speed_smoothing, a_lat=rec.a_lat, v_max=rec.v_max,
                arc_length="observed")
    args.update(kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return load_replay([run / "vehicle_tracks_000.csv"], run / "map.osm", **args), rec


# ------------------------------------------------------------------------------ in-memory recording
def recording_lanes():
    """(lanes, successors) of a small map: a 50 m straight approach into a quarter circle of radius 20 m."""
    straight = np.column_stack([np.linspace(-50.0, 0.0, 11), np.zeros(11)])
    a = np.linspace(-np.pi / 2, 0.0, 13)
    curve = np.column_stack([20.0 * np.cos(a), 20.0 + 20.0 * np.sin(a)])  # starts at (0, 0), heading +x
    return {"approach": straight, "curve": curve}, {"approach": ["curve"]}


def make_recording(info=None):
    """A `ScenarioRecording` of three tracks on `recording_lanes`: two PIRL drivers (styles 0 and 2, the second
    interacted, collided and vanished) and one background track."""
    from pirl_sim.scenarios.recording import GROUND_TRUTH_COLUMNS, ScenarioRecording

    rows = []
    for tid, (t0, n, v) in enumerate([(0.1, 30, 10.0), (0.5, 20, 8.0), (1.0, 25, 12.0)], start=1):
        t = t0 + 0.1 * np.arange(n)
        x = -50.0 + v * (t - t0)
        rows.append(pd.DataFrame({"track_id": tid, "time_s": t, "agent_type": "car", "x": x,
                                  "y": np.zeros(n), "vx": v, "vy": 0.0, "psi_rad": 0.0, "length": 5.0,
                                  "width": 1.8}))
    tracks = pd.concat(rows).sort_values(["time_s", "track_id"], kind="stable").reset_index(drop=True)
    gt = pd.DataFrame({
        "track_id": [1, 2, 3], "agent_id": ["veh0", "veh1", "veh2"], "route_id": ["r", "r", "r"],
        "is_pirl": [True, True, False], "style": [0, 2, -1],
        "style_name": ["tracks desired speed", "no preference", "background"],
        "theta_speed_dev": [3.1, 0.29, np.nan], "theta_acc_sq": [0.31, 0.3, np.nan],
        "theta_jerk_sq": [1.0, 1.0, np.nan],
        "interacted": pd.array([False, True, pd.NA], dtype="boolean"), "collided": [False, True, False],
        "removed_early": [False, True, False], "overridden_fraction": [0.0, 0.25, np.nan],
        "status": ["arrived", "vanished", "arrived"], "n_frames": [30, 20, 25],
    }, columns=list(GROUND_TRUTH_COLUMNS))
    lanes, succ = recording_lanes()
    return ScenarioRecording(tracks, gt, lanes, succ, info if info is not None else {"simulator": "test", "seed": 1})


def check_bad_read_options(read, steps_match: str) -> None:
    """``read(**options)`` (a reader of recordings) refuses an unknown estimate and selection, and
    ``selection="steps"`` without driver steps (its message matching ``steps_match``), each a ValueError."""
    for options, match in (({"estimate": "lidar"}, "estimate must be one of"),
                           ({"selection": "frames"}, "selection must be one of"),
                           ({"selection": "steps"}, steps_match)):
        with pytest.raises(ValueError, match=match):
            read(**options)


# ------------------------------------------------------------------------------ the replay through the engine
def replay_with_engine(tracks, map_path, learners, proto, out, *, desired_speed=None, **load) -> dict:
    """The replay of the scene ``load_replay([tracks], map_path, **load)`` (``estimate`` "positions" unless
    given, as `load_replay`) through the sweep engine in this process, as ``pirl-sim replay`` runs it: the
    ``recorded`` scenario's cells (`pirl_sim.engine.run.run_sweep` into ``out``, inline) and the report's result
    dict from them (`pirl_sim.cli.replay.replay_results`, `pirl_sim.experiments.replay_report.collect_replay`).

    Parameters
    ----------
    tracks, map_path : path      a track file (or a directory of them) and its map
    learners : list              sweep learner entries (``"tirl"``, ``{"name": ..., "params": ...}``; rows named by
                                 the engine's labels, e.g. ``PIRL-kNN (k=10)``), between the baselines CV (path), CA
                                 (path) and CV (x, y) of ``pirl-sim replay`` (`pirl_sim.cli.replay.LEARNER_ENTRIES`)
    proto : ReplayProtocol       windows (history, horizon, stride), split seeds and the rest of the protocol
    out : path                   the sweep's results directory (a fresh one: finished cells are reused)
    desired_speed                None (the scene's), "fit" (per split seed) or (a_lat, v_max) [m/s^2, m/s]

    Returns
    -------
    dict: `collect_replay`'s (rows, paired, paired_ca, errors, selected, ...), and ``scene`` (the scene the cells
    replayed) and ``run`` (the `SweepRun`; its ``records`` hold every cell's warnings)
    """
    from pirl_sim.cli.replay import LEARNER_ENTRIES, replay_results
    from pirl_sim.engine.config import parse_config
    from pirl_sim.engine.run import run_sweep
    from pirl_sim.experiments.recorded import load_scene

    entries = [LEARNER_ENTRIES["cv"], LEARNER_ENTRIES["ca"], *learners, LEARNER_ENTRIES["cv-xy"]]  # the row order
    replay = {k: v for k, v in dataclasses.asdict(proto).items()
              if k not in ("history", "horizon", "stride", "seeds") and v is not None}
    if desired_speed is not None:
        replay["desired_speed"] = desired_speed
    params = {"tracks": str(tracks), "map": str(map_path), "files": 0, "load": {"estimate": "positions", **load},
              "replay": replay}
    config = parse_config({"seeds": list(proto.seeds), "experiments": [{
        "scenario": "recorded", "label": "replay", "params": params, "learners": entries,
        "protocols": [{"kind": "rolling", "history_steps": proto.history, "horizon": proto.horizon,
                       "stride": proto.stride}]}]}, source="<replay_with_engine>")
    run = run_sweep(config, out, workers=0, progress=False, tables=False)
    run.check_failed("the replay's cells")
    scene = load_scene(dict(config.cells[0].scenario_params))  # the cells' scene (kept by load_scene)
    return {**replay_results(config, run, scene, proto), "scene": scene, "run": run}
