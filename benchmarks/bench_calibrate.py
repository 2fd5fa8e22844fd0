"""The calibration loop on one roundabout: calibrate, simulate three seeds, score; against SUMO's own drivers.

    python benchmarks/bench_calibrate.py --tracks DIR --map MAP.osm --reference FILE.csv [--interaction]
                                         [--seeds 3] [--repeats 1]

``DIR`` holds the track files the population is calibrated on and ``FILE.csv`` the recorded file it is scored
against (a local copy of real recordings; they may not be redistributed). Each repeat runs, each in a fresh process
with its output in a temporary folder (nothing resumed):

1. ``pirl-sim calibrate --tracks DIR --map MAP --out cal.toml [--interaction]``;
2. ``pirl-sim realism --reference FILE --map MAP --scenario calibrated=cal.toml --seeds S``: S SUMO runs of the
   calibrated population on the recording's roundabout and demand, and the realism score;
3. the named baseline: the same ``realism`` command on ``cal.toml`` with ``background_share = 1.0``, SUMO's own
   drivers on the same roundabout and demand, which needs no calibration.

Printed: the median wall time of each step, the loop's (1 + 2) and its ratio to the baseline (3), the summed
length of the calibration's track files and the loop's ratio to it, and the target: the whole loop under
15 minutes. The children inherit this process's environment (its ``OPENBLAS_NUM_THREADS`` is printed; the commands
use one BLAS thread by default); the load average at the start is printed too.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_S = 15 * 60.0  #: the whole loop (calibrate, simulate the seeds, score) for one roundabout


def wall_time(args: list[str]) -> float:
    """Wall time [s] of ``python3 -m pirl_sim ARGS`` in a fresh process (output discarded; a failure raises)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pirl_sim", *args], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def recorded_minutes(toml: Path) -> float:
    """The calibration's recorded time [min], from the comment `pirl-sim calibrate` writes."""
    found = re.search(r"([0-9.]+) min recorded", toml.read_text())
    return float(found.group(1)) if found else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tracks", type=Path, required=True, help="folder of the track files to calibrate on")
    ap.add_argument("--map", type=Path, required=True, help="the recording's Lanelet2 map")
    ap.add_argument("--reference", type=Path, required=True, help="the recorded track file scored")
    ap.add_argument("--interaction", action="store_true", help="calibrate the interaction weights too")
    ap.add_argument("--seeds", type=int, default=3, help="simulated seeds (default 3)")
    ap.add_argument("--repeats", type=int, default=1, help="runs of the whole loop (default 1)")
    args = ap.parse_args(argv)
    for name in ("tracks", "map", "reference"):
        if not getattr(args, name).exists():
            ap.error(f"--{name} {str(getattr(args, name))!r}: no such file or folder")
    if args.seeds < 1 or args.repeats < 1:
        ap.error("--seeds and --repeats must be >= 1")
    load = os.getloadavg()[0]
    steps: dict[str, list[float]] = {"calibrate": [], "simulate and score": [], "baseline: SUMO's drivers": []}
    minutes = float("nan")
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="bench_calibrate_") as tmp:
            out = Path(tmp)
            cal = out / "cal.toml"
            steps["calibrate"].append(wall_time(["calibrate", "--tracks", str(args.tracks), "--map", str(args.map),
                                                 "--out", str(cal), "--quiet"]
                                                + (["--interaction"] if args.interaction else [])))
            minutes = recorded_minutes(cal)
            own = out / "own.toml"
            own.write_text(re.sub(r"(?m)^background_share = .*$", "background_share = 1.0", cal.read_text()))
            score = ["realism", "--reference", str(args.reference), "--map", str(args.map), "--seeds",
                     str(args.seeds)]
            steps["simulate and score"].append(wall_time([*score, "--scenario", f"calibrated={cal}", "--out",
                                                          str(out / "realism")]))
            steps["baseline: SUMO's drivers"].append(wall_time([*score, "--scenario", f"own={own}", "--out",
                                                                str(out / "baseline")]))
    med = {k: statistics.median(v) for k, v in steps.items()}
    loop, base = med["calibrate"] + med["simulate and score"], med["baseline: SUMO's drivers"]
    print(f"calibration loop on {args.tracks} ({minutes:.1f} min recorded), {args.seeds} seeds, median of "
          f"{args.repeats} run(s) (load average {load:.1f} at the start, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}"
          f"{', --interaction' if args.interaction else ''}):")
    for name, t in med.items():
        print(f"  {name:28s} {t:8.1f} s")
    print(f"  {'the loop (1 + 2)':28s} {loop:8.1f} s  ({loop / base:.1f}x the baseline, "
          f"{loop / (60.0 * minutes):.2f}x the recorded time)")
    print(f"target: the loop under {TARGET_S / 60:.0f} min: {'met' if loop < TARGET_S else 'NOT met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
