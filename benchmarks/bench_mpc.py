"""Speed of the roundabout MPC (issue 3), measured in one run against casadi Opti + IPOPT.

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

Cold starts are also timed with the Newton model assembled stage-wise through `FeatureSet.derivatives`
(``SequentialMPC(assembly="stagewise")``, the path before issue 16), interleaved with the default
(``assembly="outer"``), and the ratio printed; both plans are compared. BLAS threads: ``--blas-threads``
(default 1, through threadpoolctl; printed).

Last runs (issue 16, 2026-12-01, this 2-core machine shared with other sessions, one BLAS thread): cold starts
2,326/s with the machine lightly loaded, 1,659/s and 1,440/s while other sessions kept both cores busy (load
average ~4); the stage-wise model measured in the same runs: 1.5-1.6x slower (1,025/s in the 1,659/s run).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from pirl_sim.mpc import SequentialMPC
from pirl_sim.scenarios.passage import PassageConfig
from pirl_sim.threads import blas_threads, current_blas_threads, parse_blas_threads
from pirl_sim.simulate import simulate_receding_horizon

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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--starts", type=int, default=500)
    ap.add_argument("--ipopt-solves", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--blas-threads", default="1", help="BLAS threads (a positive integer or 'auto'; default 1)")
    args = ap.parse_args(argv)
    with blas_threads(parse_blas_threads(args.blas_threads, "--blas-threads")):
        run(args)


def run(args):

    model = PassageConfig().model()
    rng = np.random.default_rng(0)
    M = args.starts
    x0 = np.column_stack([rng.uniform(0, 100, M), rng.uniform(2, 12, M), np.clip(rng.normal(0, 0.5, M), -3.9, 2.9)])
    predictor = model.predictor()
    predictor.controls(x0[:5], THETA, N)  # build the QP solver once

    stagewise = SequentialMPC(predictor.dynamics, predictor.features, predictor.bounds, n_iter=predictor.n_iter,
                              n_qp_iter=predictor.n_qp_iter, tol=predictor.tol, qp_tol=predictor.qp_tol,
                              assembly="stagewise")
    stagewise.controls(x0[:5], THETA, N)

    def cold():
        return model.predict_states(x0, THETA, N)

    times, times_base = [], []
    for _ in range(args.repeats):  # interleaved: the default, then the stage-wise baseline
        predictor.n_qp = 0
        t0 = time.perf_counter()
        ours = cold()
        times.append(time.perf_counter() - t0)
        n_qp = predictor.n_qp
        t0 = time.perf_counter()
        base = stagewise.predict(x0, THETA, N)
        times_base.append(time.perf_counter() - t0)
    t_cold = statistics.median(times) / M
    t_base = statistics.median(times_base) / M
    plan_gap = np.abs(base - ours).max()

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

    threads = ", ".join(f"{k} {v}" for k, v in current_blas_threads().items())
    print(f"roundabout MPC, N={N}, bounds on v, a, j; {M} cold starts ({n_qp} bounded QPs needed); BLAS threads: "
          f"{threads}; medians of {args.repeats}:")
    print(f"  cold starts          : {1 / t_cold:8.0f} predictions/s  ({t_cold * 1e3:.2f} ms each), target >= 2,000/s")
    print(f"  cold, stage-wise model (before): {1 / t_base:8.0f} predictions/s; speed-up {t_base / t_cold:.2f}x; "
          f"max |state difference| {plan_gap:.1e}")
    print(f"  warm, receding horizon: {1 / t_warm:8.0f} predictions/s  ({t_warm * 1e3:.2f} ms each), target >= 2,000/s")
    print(f"  casadi Opti + IPOPT  : {1 / t_ipopt:8.0f} predictions/s  ({t_ipopt * 1e3:.2f} ms each, {k} solves)")
    print(f"  speed-up vs IPOPT    : cold {t_ipopt / t_cold:6.1f}x, warm {t_ipopt / t_warm:6.1f}x (target >= 10x)")
    print(f"  max |s_ours - s_ipopt| over the {k} compared plans: {gap:.2e} m")


if __name__ == "__main__":
    main()
