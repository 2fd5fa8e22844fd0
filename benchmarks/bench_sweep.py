"""Sweep speed: the machinery's overhead per cell, and the throughput of 2 workers against 1.

    python benchmarks/bench_sweep.py [--repeats 3] [--part all|overhead|throughput|kgrid|none] [--default-grid]

1. **Overhead per cell**: 40 cheap cells (synthetic, 60 trajectories, TIRL and kNN, 20 seeds) through
   ``run_sweep`` on 1 local worker. Overhead = (wall time - the cells' own time, summed over cells as
   measured inside the worker) / cells: cell keys, the store, submission and inter-process
   transfer, the atomic (fsynced) write of every result, the progress bar and the tables (parquet, CSV,
   recovery). Also in-process (``--workers 0``), without the inter-process part. Target: < 50 ms per cell.
2. **Throughput, 2 workers vs 1**: a small grid of roundabout cells (~1 s each: 200 passages; TIRL, PIRL-GMM,
   PIRL-kNN; paper and rolling protocols; 2 seeds) on 1 and on 2 local workers (their start-up is reported
   apart: it is paid once per sweep). Target: >= 1.7x. The share of the cells' wall time they spent on a core
   (CPU time / wall time, near 100 % on an idle machine) tells when other processes took a core.
   ``--default-grid`` also runs the embedded default sweep on 1 and 2 workers (several minutes each).

Medians over ``--repeats`` runs; every run on fresh workers in a fresh results directory, so every cell is
computed.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
import tomllib
from pathlib import Path

from pirl_sim.engine import default_config, parse_config, run_sweep

OVERHEAD_GRID = """
name = "overhead"
seeds = [%s]
[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 60, n_train = 40 }
protocols = ["paper"]
learners = ["tirl", { name = "pirl-knn", params = { n_neighbors = 1 } }]
""" % ", ".join(str(s) for s in range(20))

THROUGHPUT_GRID = """
name = "throughput"
seeds = [0, 1]
[[experiments]]
scenario = "passage"
params = { n_trajectories = 200, n_train = 160 }
protocols = ["paper", { kind = "rolling", history_steps = 10, horizon = 15, stride = 5 }]
learners = ["tirl", { name = "pirl-gmm", params = { n_components = 3 } },
            { name = "pirl-knn", params = { n_neighbors = 10, prior = "population", stride = 2 } }]
"""

KGRID = """
name = "kgrid"
seeds = [0]
[[experiments]]
scenario = "passage"
params = { n_trajectories = 200, n_train = 160 }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 15, stride = 5 }]
learners = [{ name = "pirl-knn", params = { prior = "population", stride = 2 }, grid = { n_neighbors = [1, 3, 5, 10, 20, 40] } }]
"""


def _config(text):
    return parse_config(tomllib.loads(text), text=text)


def _timed(config, workers: int, tmp: Path, tag: str):
    """One sweep in a fresh results directory on fresh workers: (wall time after worker start-up [s], sum of
    the cells' own time [s], cells, sum of their CPU time [s], worker start-up [s])."""
    run = run_sweep(config, tmp / tag, workers=workers, progress=False)
    assert not run.failed and not run.cached, (run.failed, len(run.cached))
    return run.wall_s - run.startup_s, run.work_s, len(run.computed), run.cpu_s, run.startup_s


def overhead(repeats: int, tmp: Path) -> None:
    config = _config(OVERHEAD_GRID)
    print(f"sweep overhead per cell, {len(config.cells)} cheap cells, medians of {repeats}:")
    for name, workers in (("1 local worker process", 1), ("in-process (--workers 0)", 0)):
        runs = [_timed(config, workers, tmp, f"oh{workers}-{r}") for r in range(repeats)]
        wall = statistics.median(r[0] for r in runs)
        work = statistics.median(r[1] for r in runs)
        start = statistics.median(r[4] for r in runs)
        n = runs[0][2]
        per = (wall - work) / n
        print(f"  {name:26s}: wall {wall:6.2f} s, cells' own work {work:6.2f} s ({1e3 * work / n:5.1f} ms/cell) -> "
              f"overhead {1e3 * per:5.1f} ms/cell  (target < 50 ms: {'met' if per < 0.05 else 'NOT met'})"
              + (f"; worker start-up {start:.1f} s once per sweep" if workers else ""))


def throughput(config, repeats: int, tmp: Path, title: str) -> None:
    print(f"{title}: {len(config.cells)} cells, medians of {repeats}:")
    result = {}
    for workers in (1, 2):
        runs = [_timed(config, workers, tmp, f"tp{workers}-{title[:5]}-{r}") for r in range(repeats)]
        wall = statistics.median(r[0] for r in runs)
        work = statistics.median(r[1] for r in runs)
        cpu = statistics.median(r[3] / r[1] for r in runs)
        start = statistics.median(r[4] for r in runs)
        n = runs[0][2]
        result[workers] = (wall, start)
        print(f"  {workers} worker{'s' if workers > 1 else ' '}: {wall:6.1f} s for {n} cells = {n / wall:5.2f} cells/s "
              f"(cells' own work {work:6.1f} s, {100 * cpu:3.0f} % of it on a core; start-up {start:.1f} s, once "
              "per sweep)")
    speed = result[1][0] / result[2][0]
    cold = (result[1][0] + result[1][1]) / (result[2][0] + result[2][1])
    print(f"  speed-up 2 vs 1 workers: {speed:.2f}x (target >= 1.7x: {'met' if speed >= 1.7 else 'NOT met'}); "
          f"counting start-up: {cold:.2f}x")


def kgrid(repeats: int) -> None:
    from pirl_sim.engine.worker import run_cell, run_cells, single_threaded

    specs = [c.spec() for c in _config(KGRID).cells]
    print(f"PIRL-kNN k-grid ({len(specs)} cells, passage, rolling), in this process, medians of {repeats}:")
    with single_threaded():
        run_cell(specs[0])  # the data set, cached for both
        alone, together = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            a = [run_cell(s) for s in specs]
            alone.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            b = run_cells(specs)
            together.append(time.perf_counter() - t0)
            assert [r["scores"] for r in a] == [r["scores"] for r in b], "the k-grid task changed a cell's scores"
    one, grid = statistics.median(alone), statistics.median(together)
    print(f"  each cell on its own: {one:6.1f} s; as one task (one fit): {grid:6.1f} s -> {one / grid:.1f}x "
          "(scores identical)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--default-grid", action="store_true", help="also time the embedded default sweep (minutes)")
    ap.add_argument("--part", choices=("all", "overhead", "throughput", "kgrid", "none"), default="all",
                    help="what to measure besides --default-grid (default: all)")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{os.cpu_count()} cores, load average {load:.2f} at the start (other processes compete for the cores)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.part in ("all", "overhead"):
            overhead(args.repeats, tmp)
        if args.part in ("all", "throughput"):
            throughput(_config(THROUGHPUT_GRID), args.repeats, tmp, "throughput on a small roundabout grid")
        if args.part in ("all", "kgrid"):
            kgrid(args.repeats)
        if args.default_grid:
            throughput(default_config(), 1, tmp, "throughput on the default grid")


if __name__ == "__main__":
    main()
