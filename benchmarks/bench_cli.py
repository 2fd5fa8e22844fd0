"""Start-up of the command line: wall time of ``python3 -m pirl_sim --help``, against ``python3 -c pass``.

    python benchmarks/bench_cli.py [--repeats 5] [--revision REV]

Each command runs in a fresh process, ``--repeats`` times, the commands alternating so that all see the same
load; the medians are printed with the ratio to the baseline ``python3 -c pass`` (the interpreter's own
start-up). ``import pirl_sim`` is timed beside them: the package root (core types, env registration), which every
command imports before its parser is built. ``--revision REV`` also times ``--help`` of a git revision of the
package, exported with `_baseline.export_revision`. Target: ``--help`` under 1 s. The children inherit this
process's environment (its ``OPENBLAS_NUM_THREADS`` is printed); the load average at the start is printed too.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

from _baseline import export_revision

BASELINE = [sys.executable, "-c", "pass"]  #: the named baseline: the interpreter starting and stopping
HELP = [sys.executable, "-m", "pirl_sim", "--help"]
ROOT = [sys.executable, "-c", "import pirl_sim"]


def wall_time(cmd: list[str], env: dict | None = None) -> float:
    """Wall time [s] of ``cmd`` in a fresh process (its output discarded; a failure raises)."""
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5, help="runs of each command, alternating (default 5)")
    ap.add_argument("--revision", default=None, metavar="REV",
                    help="also time --help of this git revision of the package (default: none)")
    args = ap.parse_args(argv)
    runs = {"python3 -c pass (baseline)": (BASELINE, None), "python3 -m pirl_sim --help": (HELP, None),
            "python3 -c 'import pirl_sim'": (ROOT, None)}
    if args.revision is not None:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            [str(export_revision(args.revision)), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))])}
        runs[f"python3 -m pirl_sim --help at {args.revision}"] = (HELP, env)
    times = {name: [] for name in runs}
    load = os.getloadavg()[0]
    for name, (cmd, env) in runs.items():  # once untimed: files in the page cache, bytecode compiled
        wall_time(cmd, env)
    for _ in range(args.repeats):
        for name, (cmd, env) in runs.items():
            times[name].append(wall_time(cmd, env))
    base = statistics.median(times["python3 -c pass (baseline)"])
    print(f"command-line start-up, median of {args.repeats} fresh processes each (load average {load:.1f} at the "
          f"start, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}):")
    for name, t in times.items():
        med = statistics.median(t)
        print(f"  {name:45s} {med:6.3f} s  ({med / base:5.1f}x the baseline)")
    helped = statistics.median(times["python3 -m pirl_sim --help"])
    print(f"  --help target < 1 s: {'met' if helped < 1.0 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
