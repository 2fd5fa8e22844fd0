"""Replay speed: 1,000 recorded tracks, fit + predict every learner, and where the time goes.

    python benchmarks/bench_replay.py [--tracks 1000]              # one split, four learners
    python benchmarks/bench_replay.py --command [--workers 1,2]     # the replay command itself
    python benchmarks/bench_replay.py --real DIR --map MAP.osm [--files 5 --seeds 4 --workers 2] [--baseline REV]

The scene is simulated (roundabout passage drivers of three styles, written in the INTERACTION format with a
Lanelet2 map), because real recordings may not be redistributed.

Default: one train/test split (75/25 by track), 2 s history, 3 s horizon, a prediction every 1 s
along each test track. Target: under 60 s in total.

``--command``: the wall time of the command a user runs on a real-data-sized recording,
``pirl-sim replay --tracks T --map M --knn-k 5,10,19,30 --seeds 4 [--workers J]`` (default learners TIRL,
PIRL-GMM, PIRL-kNN; a fresh process per run, output in a temporary directory so that nothing is resumed), for
each ``--workers`` value, with the load average at the start. Target: under 120 s. BLAS threads: the command's
own policy (one thread, `pirl_sim.threads`).

``--real``: the default replay (``--preset best``) of a local copy of real recordings, ``pirl-sim replay --tracks
DIR --map MAP --files 5 --seeds 4 --workers 2`` in a fresh process: wall time, the load average before and
after, and per learner the median fit and predict time over the split seeds. Target: under 5 minutes for five
track files of a development roundabout. ``--baseline REV`` also times the same settings, given as options, on
revision REV of the package (`_baseline.export_revision`), and prints the ratio.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import warnings

from pirl_sim.experiments.recorded import replay_seed
from pirl_sim.experiments.replay_report import ReplayProtocol, collect_replay
from pirl_sim.scenarios.passage import PassageConfig, generate, write_scene
from pirl_sim.scenarios.replay import load_replay

SPECS = [
    ("TIRL", "tirl", {}),
    ("PIRL-GMM (k=3)", "pirl-gmm", {"n_components": 3, "random_state": 0}),
    ("PIRL-DPGMM", "pirl-dpgmm", {"random_state": 0}),
    ("PIRL-kNN (k=10)", "pirl-knn", {"n_neighbors": 10, "prior": "population", "stride": 2}),
]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tracks", type=int, default=1000)
    ap.add_argument("--command", action="store_true", help="time the replay command instead")
    ap.add_argument("--workers", default="1,2", help="--command: comma-separated --workers values to time; --real: "
                    "the last of them (default 2)")
    ap.add_argument("--real", type=str, default=None, metavar="DIR", help="time the default replay of these tracks")
    ap.add_argument("--map", type=str, default=None, help="--real: their Lanelet2 map")
    ap.add_argument("--files", type=int, default=5, help="--real: track files used (default 5)")
    ap.add_argument("--seeds", type=int, default=4, help="--real: split seeds (default 4)")
    ap.add_argument("--baseline", default=None, metavar="REV", help="--real: also time git revision REV")
    args = ap.parse_args(argv)
    if args.real is not None:
        if args.map is None:
            ap.error("--real needs --map")
        return _time_real(args)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate(PassageConfig(n_trajectories=args.tracks, n_train=args.tracks - 1))
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_scene(data, tmp)
        if args.command:
            return _time_command(paths, [int(j) for j in args.workers.split(",")], tmp)
        t0 = time.perf_counter()
        scene = load_replay([paths["tracks"]], paths["map"])
        t_load = time.perf_counter() - t0
        t0 = time.perf_counter()
        proto = ReplayProtocol(seeds=(0,))
        methods = [("CV (path)", "cv", {}), ("CA (path)", "ca", {}), *SPECS, ("CV (x, y)", "cv-xy", {})]
        result = collect_replay(scene, proto, {0: replay_seed(scene, 0, methods, proto)}, SPECS)
        t_run = time.perf_counter() - t0
    rows = result["rows"].set_index("method")
    total = t_load + t_run
    print(f"replay of {scene.n_tracks} tracks ({result['selected']} used), one split:")
    print(f"  read + match routes + Frenet + state estimation : {t_load:6.1f} s")
    for name, *_ in SPECS:
        print(f"  {name:18s} fit {rows.loc[name, 'fit_s']:6.1f} s, infer + predict {rows.loc[name, 'predict_s']:5.1f} s"
              f"  (MED {rows.loc[name, 'med']:.3f} m)")
    rest = t_run - rows["fit_s"].sum() - rows["predict_s"].sum()
    print(f"  baselines, windows and scoring                 : {rest:6.1f} s")
    print(f"  total                                          : {total:6.1f} s  (target < 60 s: {'met' if total < 60 else 'NOT met'})")


def _time_command(paths, workers: list[int], tmp: str) -> None:
    """Wall time of ``pirl-sim replay ... --knn-k 5,10,19,30 --seeds 4 --workers J`` per J."""
    print(f"replay command on {len(data_tracks(paths))} simulated tracks, --knn-k 5,10,19,30 --seeds 4 "
          f"(load average at the start {os.getloadavg()[0]:.1f}):")
    for j in workers:
        out = os.path.join(tmp, f"out_workers{j}")
        cmd = [sys.executable, "-m", "pirl_sim", "replay", "--tracks", str(paths["tracks"]), "--map",
               str(paths["map"]), "--knn-k", "5,10,19,30", "--seeds", "4", "--workers", str(j), "--out", out]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        print(f"  --workers {j}: {wall:6.1f} s  (target < 120 s: {'met' if wall < 120 else 'NOT met'})")


def best_as_options() -> list[str]:
    """This tree's default replay settings (``--preset best``) as options, for a revision whose defaults differ;
    the state estimate from speeds (the default with history starts) named too."""
    from pirl_sim.cli.replay import PRESETS

    out = ["--estimate", "speeds"]
    for name, value in PRESETS["best"].items():
        out += [f"--{name.replace('_', '-')}", ",".join(value) if isinstance(value, tuple) else value]
    return out


def _time_real(args) -> None:
    """Wall time of the default replay of ``args.real`` (and of revision ``args.baseline`` with the same settings)."""
    import pandas as pd

    from _baseline import export_revision

    workers = int(args.workers.split(",")[-1])
    tracks, osm = os.path.abspath(args.real), os.path.abspath(args.map)
    runs = [("this tree", None, [])]
    if args.baseline:
        runs.append((f"revision {args.baseline}", export_revision(args.baseline), best_as_options()))
    walls = {}
    for name, code, extra in runs:
        with tempfile.TemporaryDirectory() as tmp:
            env = dict(os.environ)
            if code is not None:
                env["PYTHONPATH"] = os.pathsep.join([str(code), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
            cmd = [sys.executable, "-m", "pirl_sim", "replay", "--tracks", tracks, "--map", osm, "--files",
                   str(args.files), "--seeds", str(args.seeds), "--workers", str(workers), "--quiet",
                   "--out", tmp, *extra]
            load0 = os.getloadavg()[0]
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=env, cwd=tmp)
            walls[name] = time.perf_counter() - t0
            rows = pd.read_csv(os.path.join(tmp, "rows.csv"))
        print(f"{name}: {walls[name]:.0f} s for {args.files} files, {args.seeds} seeds, --workers {workers} "
              f"(load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after; target < 300 s: "
              f"{'met' if walls[name] < 300 else 'NOT met'})")
        for method, g in rows.groupby("method", sort=False):
            if g["fit_s"].max() > 0:
                print(f"  {method:30s} fit {g['fit_s'].median():6.1f} s, predict {g['predict_s'].median():6.1f} s "
                      f"(median over seeds), MED {g['med'].mean():.3f} m")
    if args.baseline:
        print(f"ratio revision {args.baseline} / this tree: {walls[runs[1][0]] / walls['this tree']:.2f}")


def data_tracks(paths) -> list:
    """Track ids in the written tracks file (for the printout)."""
    import pandas as pd

    return sorted(pd.read_csv(paths["tracks"], usecols=["track_id"])["track_id"].unique())


if __name__ == "__main__":
    main()
