"""Replay speed (issue 6): 1,000 recorded tracks, fit + predict every learner, and where the time goes.

    python benchmarks/bench_replay.py [--tracks 1000]

The scene is simulated (roundabout passage drivers of three styles, written in the INTERACTION format with a
Lanelet2 map), because real recordings may not be redistributed. One train/test split (75/25 by track),
2 s history, 3 s horizon, a prediction every 1 s along each test track. Target: under 60 s in total.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings

from pirl_sim.harness.replay import ReplayProtocol, run_replay
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
    args = ap.parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate(PassageConfig(n_trajectories=args.tracks, n_train=args.tracks - 1))
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_scene(data, tmp)
        t0 = time.perf_counter()
        scene = load_replay([paths["tracks"]], paths["map"])
        t_load = time.perf_counter() - t0
        t0 = time.perf_counter()
        result = run_replay(scene, SPECS, ReplayProtocol(seeds=(0,)))
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


if __name__ == "__main__":
    main()
