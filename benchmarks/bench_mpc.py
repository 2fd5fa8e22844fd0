"""Speed of the roundabout MPC, measured in one run against casadi Opti + IPOPT.

    python benchmarks/bench_mpc.py [--starts 500] [--ipopt-solves 20]

Problem: the paper's longitudinal model on the roundabout passage path (`pirl_sim.scenarios.passage`), N = 40
steps of 0.2 s, weights (speed_dev 3, acc_sq 0.3, jerk_sq 1), bounds 0 <= v <= 30 m/s, -4 <= a <= 3 m/s^2,
|j| <= 8 m/s^3. Workloads:
- cold: independent starts (s in [0, 100] m, v in [2, 12] m/s, a ~ N(0, 0.5) m/s^2), no warm start;
- warm: 50 receding-horizon drivers re-planning every step for 100 steps, each plan warm-started from the
  previous one shifted by a step (how drivers use it in the simulators).
Baseline: the same optimal-control problem written with casadi Opti (multiple shooting, the curvature as a
casadi B-spline of the same table, the same smooth desired-speed formula) solved by IPOPT from the same starts.
Target: >= 2,000 predictions/s and >= 10x faster than the baseline. Medians of --repeats.

Cold starts are timed in child processes, alternately on the working tree and on a baseline revision of the
package (``--baseline``, default `_baseline.BEFORE`, the named baseline revision; the
package is exported with ``git archive``), ``--repeats`` times each, so that both see the same load; the
medians and their ratio are printed, with the largest difference between the two codes' plans. In-process
figures (warm receding horizon, IPOPT) follow. BLAS threads: ``--blas-threads`` (default 1, through
threadpoolctl and the thread variables of the children; printed), and the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np

from pirl_sim.scenarios.passage import PassageConfig
from pirl_sim.threads import blas_threads, current_blas_threads, parse_blas_threads
from pirl_sim.simulate import simulate_receding_horizon

from _baseline import BEFORE, export_revision, run_worker

THETA = np.array([3.0, 0.3, 1.0])
N = 40


def opti_solver(model):
    import casadi as ca

    path = model.path
    prof = model.features.features[0]  # speed_dev
    kappa_fn = ca.interpolant("kappa", "bspline", [path.s.tolist()], path.kappa.tolist())
    a_lat, v_max = 1.8, 13.9
    dyn = model.dynamics
    opti = ca.Opti()
    X = opti.variable(3, N + 1)
    U = opti.variable(1, N)
    x0 = opti.parameter(3)
    opti.subject_to(X[:, 0] == x0)
    cost = 0
    for k in range(N):
        opti.subject_to(X[:, k + 1] == ca.DM(dyn.A) @ X[:, k] + ca.DM(dyn.B) @ U[:, k])
        s = ca.fmin(ca.fmax(X[0, k + 1], float(path.s[0])), float(path.s[-1]))
        q = (kappa_fn(s) ** 2 / a_lat**2) ** 2 + v_max**-8.0
        v_des = q ** (-1.0 / 8.0)
        cost += THETA[0] * (X[1, k + 1] - v_des) ** 2 + THETA[1] * X[2, k + 1] ** 2 + THETA[2] * U[0, k] ** 2
    opti.minimize(cost / N)
    opti.subject_to(opti.bounded(0.0, X[1, 1:], 30.0))
    opti.subject_to(opti.bounded(-4.0, X[2, 1:], 3.0))
    opti.subject_to(opti.bounded(-8.0, U, 8.0))
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes"})
    del prof

    def solve(start):
        opti.set_value(x0, start)
        opti.set_initial(X, np.tile(start[:, None], (1, N + 1)))
        opti.set_initial(U, 0.0)
        sol = opti.solve()
        return np.asarray(sol.value(X)).T

    return solve


def cold_starts(M: int) -> np.ndarray:
    """The cold-start workload: M starts (s [m], v [m/s], a [m/s^2]), seeded."""
    rng = np.random.default_rng(0)
    return np.column_stack([rng.uniform(0, 100, M), rng.uniform(2, 12, M), np.clip(rng.normal(0, 0.5, M), -3.9, 2.9)])


def worker(M: int, rounds: int, plans: str | None) -> None:
    """Child process: time ``rounds`` cold batches of M starts on the pirl_sim it imports; one JSON line out."""
    model = PassageConfig().model()
    x0 = cold_starts(M)
    model.predict_states(x0[:5], THETA, N)  # build the solvers once
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        states = model.predict_states(x0, THETA, N)
        times.append(time.perf_counter() - t0)
    if plans:
        np.save(plans, states)
    print(json.dumps({"times": times}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--starts", type=int, default=500)
    ap.add_argument("--ipopt-solves", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=5, help="child processes per code, alternating (default 5)")
    ap.add_argument("--rounds", type=int, default=3, help="timed cold batches per child (default 3)")
    ap.add_argument("--baseline", default=BEFORE, help=f"git revision to compare with (default {BEFORE})")
    ap.add_argument("--blas-threads", default="1", help="BLAS threads (a positive integer or 'auto'; default 1)")
    ap.add_argument("--cold-only", action="store_true", help="skip the warm and IPOPT workloads")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--plans", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    for name in ("starts", "repeats", "rounds", "ipopt_solves"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    threads = parse_blas_threads(args.blas_threads, "--blas-threads")
    if threads is not None:
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = str(threads)
    with blas_threads(threads):
        if args.worker:
            worker(args.starts, args.rounds, args.plans)
        else:
            run(args)


def run(args):
    M = args.starts
    base_code = export_revision(args.baseline)
    wargs = ["--starts", str(M), "--rounds", str(args.rounds), "--blas-threads", args.blas_threads]
    here = os.path.abspath(__file__)
    ours_t, base_t = [], []
    plans = {name: os.path.join(str(base_code), f"plans_{name}_{os.getpid()}.npy") for name in ("ours", "base")}
    load0 = os.getloadavg()
    for r in range(args.repeats):  # alternating children: both codes see the same load
        last = ["--plans", plans["base"]] if r == 0 else []
        base_t += run_worker(here, wargs + last, base_code)["times"]
        last = ["--plans", plans["ours"]] if r == 0 else []
        ours_t += run_worker(here, wargs + last)["times"]
    load1 = os.getloadavg()
    ours_plans, base_plans = np.load(plans["ours"]), np.load(plans["base"])
    for path in plans.values():
        os.remove(path)
    t_cold = statistics.median(ours_t) / M
    t_base = statistics.median(base_t) / M

    threads = ", ".join(f"{k} {v}" for k, v in current_blas_threads().items())
    print(f"roundabout MPC, N={N}, bounds on v, a, j; {M} cold starts; BLAS threads: {threads}; load average "
          f"{load0[0]:.2f} before, {load1[0]:.2f} after the cold runs ({os.cpu_count()} cores)")
    print(f"  cold starts          : {1 / t_cold:8.0f} predictions/s  ({t_cold * 1e3:.3f} ms each; median of "
          f"{len(ours_t)} batches in {args.repeats} processes), target >= 2,000/s: "
          f"{'met' if 1 / t_cold >= 2000 else 'NOT met'}")
    print(f"  cold, baseline {args.baseline} (same run, alternating): {1 / t_base:8.0f} predictions/s "
          f"({t_base * 1e3:.3f} ms each); speed-up {t_base / t_cold:.2f}x; max |state difference| "
          f"{np.abs(base_plans - ours_plans).max():.1e}")
    if args.cold_only:
        return

    model = PassageConfig().model()
    rng = np.random.default_rng(0)
    x0 = cold_starts(M)
    ours = ours_plans
    drivers, steps = 50, 100
    starts = np.column_stack([rng.uniform(0, 20, drivers), rng.uniform(8, 12, drivers), np.zeros(drivers)])
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        simulate_receding_horizon(model, starts, THETA, steps, N, rng=np.random.default_rng(1), control_noise=0.3)
        times.append(time.perf_counter() - t0)
    t_warm = statistics.median(times) / (drivers * steps)

    solve = opti_solver(model)
    k = min(args.ipopt_solves, M)
    t0 = time.perf_counter()
    ref = np.stack([solve(x0[i]) for i in range(k)])
    t_ipopt = (time.perf_counter() - t0) / k
    gap = np.abs(ref[:, :, 0] - ours[:k, :, 0]).max()

    print(f"  warm, receding horizon: {1 / t_warm:8.0f} predictions/s  ({t_warm * 1e3:.2f} ms each, median of "
          f"{args.repeats}, in this process)")
    print(f"  casadi Opti + IPOPT  : {1 / t_ipopt:8.0f} predictions/s  ({t_ipopt * 1e3:.2f} ms each, {k} solves)")
    print(f"  speed-up vs IPOPT    : cold {t_ipopt / t_cold:6.1f}x, warm {t_ipopt / t_warm:6.1f}x (target >= 10x)")
    print(f"  max |s_ours - s_ipopt| over the {k} compared plans: {gap:.2e} m")


if __name__ == "__main__":
    main()
