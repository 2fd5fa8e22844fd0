"""Thread policy: single-process commands on a quiet and on a loaded machine, one run.

    python benchmarks/bench_threads.py [--repeats 1] [--commands simulate,replay,reproduce]

Each command runs as ``python -m pirl_sim --blas-threads T COMMAND ...`` in a fresh process, with

- T = ``auto`` (the baseline: numpy/scipy's own BLAS threads, 2 on a 2-core machine: the commands without the
  policy) and T = 1 (the policy's default);
- quiet (no load of ours) and loaded (one busy process ``python -c 'while True: pass'`` started by this script
  for the duration of the run and killed after it, by its pid).

The commands (small versions of the real ones, each a few seconds):

- ``simulate``:  ``simulate sumo --n-vehicles 40 --seed 0`` (SUMO roundabout, every driver re-planning every 0.1 s);
- ``replay``:    ``replay`` of that recording with ``--seeds 1 --selection free --learners tirl,pirl-knn``;
- ``reproduce``: ``reproduce synthetic --n-trajectories 1000 --n-train 900``.

Prints the median wall time [s] of ``--repeats`` runs per command and condition (conditions interleaved per
repeat), the ratios loaded / quiet per setting (target: <= 1.3 for ``replay`` and ``simulate`` with
the policy) and auto / 1 per load, and whether both settings wrote the same results (timing columns,
``run.json`` and figures aside). OPENBLAS_NUM_THREADS and
friends are removed from the children's environment, so ``auto`` really is the libraries' default. The machine
is shared: "quiet" means no load of this script's, and the load average at the start is printed.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SETTINGS = ("auto", "1")
LOADS = ("quiet", "loaded")
COMMANDS = ("simulate", "replay", "reproduce")


def command_args(name: str, work: Path, out: Path) -> list[str]:
    """The pirl-sim arguments of one benchmarked command writing to ``out``."""
    if name == "simulate":
        return ["simulate", "sumo", "--n-vehicles", "40", "--seed", "0", "--quiet", "--out", str(out)]
    if name == "replay":
        rec = work / "recording"
        return ["replay", "--tracks", str(rec), "--map", str(rec / "map.osm"), "--seeds", "1", "--selection", "free",
                "--learners", "tirl,pirl-knn", "--quiet", "--out", str(out)]
    if name == "reproduce":
        return ["reproduce", "synthetic", "--n-trajectories", "1000", "--n-train", "900", "--quiet", "--out", str(out)]
    raise ValueError(f"unknown command {name!r}; valid: {', '.join(COMMANDS)}")


def child_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "PIRL_SIM_BLAS_THREADS")}
    env.setdefault("PYTHONWARNINGS", "ignore")
    return env


def run_once(setting: str, args: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pirl_sim", "--blas-threads", setting, *args], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=child_env())
    return time.perf_counter() - t0


def same_outputs(a: Path, b: Path) -> bool:
    """True when both directories hold the same files with the same contents, timings and figures aside: CSV
    files are compared without their timing columns (names ending in ``_s``); ``run.json`` (wall times), PNG
    figures and the sweep engine's bookkeeping of the replay (``cells/`` and ``sweep.json``: the same numbers
    as ``rows.csv``, with each cell's wall and CPU time) are skipped."""
    import pandas as pd

    def files(root: Path) -> list[Path]:
        return sorted(p.relative_to(root) for p in root.rglob("*")
                      if p.is_file() and p.name not in ("run.json", "sweep.json") and p.suffix != ".png"
                      and "cells" not in p.relative_to(root).parts)

    fa, fb = files(a), files(b)
    if fa != fb:
        return False
    for f in fa:
        if f.suffix == ".csv":
            da, db = pd.read_csv(a / f), pd.read_csv(b / f)
            keep = [c for c in da.columns if not str(c).endswith("_s")]
            if list(da.columns) != list(db.columns) or not da[keep].equals(db[keep]):
                return False
        elif not filecmp.cmp(a / f, b / f, shallow=False):
            return False
    return True


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=1, help="runs per command and condition (median printed)")
    ap.add_argument("--commands", default=",".join(COMMANDS), help=f"comma-separated subset of {', '.join(COMMANDS)}")
    args = ap.parse_args(argv)
    names = [c.strip() for c in args.commands.split(",") if c.strip()]
    for n in names:
        if n not in COMMANDS:
            raise ValueError(f"--commands: unknown command {n!r}; valid: {', '.join(COMMANDS)}")
    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")

    work = Path(tempfile.mkdtemp(prefix="bench_threads_"))
    try:
        if "replay" in names:  # the recording replay reads, made once outside the timings
            subprocess.run([sys.executable, "-m", "pirl_sim", "simulate", "sumo", "--n-vehicles", "40", "--seed", "0",
                            "--quiet", "--out", str(work / "recording")], check=True, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL, env=child_env())
        print(f"load average at start: {os.getloadavg()[0]:.2f} (2-core machine, shared); "
              f"{args.repeats} repeat(s), conditions interleaved")
        times = {(n, s, ld): [] for n in names for s in SETTINGS for ld in LOADS}
        for rep in range(args.repeats):
            for load in LOADS:
                busy = None
                if load == "loaded":
                    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    time.sleep(0.5)
                try:
                    for n in names:
                        for s in SETTINGS:
                            out = work / f"{n}_{s}_{load}_{rep}"
                            times[(n, s, load)].append(run_once(s, command_args(n, work, out)))
                finally:
                    if busy is not None:
                        busy.kill()
                        busy.wait()
        print(f"{'command':<10} {'threads':<8} {'quiet [s]':>10} {'loaded [s]':>11} {'loaded/quiet':>13}")
        med = {k: statistics.median(v) for k, v in times.items()}
        for n in names:
            for s in SETTINGS:
                q, ld = med[(n, s, "quiet")], med[(n, s, "loaded")]
                tag = "  (baseline: libraries' default)" if s == "auto" else "  (policy default)"
                print(f"{n:<10} {s:<8} {q:10.2f} {ld:11.2f} {ld / q:12.2f}x{tag}")
        print("speed-up of the policy (auto / 1):")
        for n in names:
            q = med[(n, "auto", "quiet")] / med[(n, "1", "quiet")]
            ld = med[(n, "auto", "loaded")] / med[(n, "1", "loaded")]
            same = same_outputs(work / f"{n}_auto_quiet_0", work / f"{n}_1_quiet_0")
            print(f"  {n:<10} quiet {q:5.2f}x, loaded {ld:5.2f}x; same results with 1 and auto threads: "
                  f"{'yes' if same else 'NO'}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
