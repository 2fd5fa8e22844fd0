"""Receding-horizon IRL on the default SUMO run (seed 0): our batched fit against a per-track scipy loop.

    OPENBLAS_NUM_THREADS=1 python3 benchmarks/bench_receding.py [--repeats 3] [--baseline-tracks 8] [--run DIR]

Workload: every PIRL track of `pirl-sim simulate sumo --seed 0` (80 vehicles, default population) with at
least 10 usable steps (``selection="steps"``), one weight vector per track, every usable step scored
(stride 1). Target: < 10 s.

Baseline: per track, ``scipy.optimize.least_squares`` (trf, box [-20, 20] on the free log weights, Cauchy
loss with the scale our fit starts from, 2-point finite-difference Jacobian) on the same residuals,
``u_t - RecedingPolicy(model, H).solve(x_t, theta(w), init_t).first`` over the track's usable steps
(every step of the track solved in one batched call per residual evaluation), from the same start (the
same grid over the free log weights scored by the sum of |residual| on 12 steps of the track). The loop is
run on every ``n/baseline-tracks``-th track and its time scaled to all tracks. Target: >= 20x. A second
variant solves each residual evaluation's MPCs step by step (a Python loop of one-start solves, as without a
batched solver), on ``--per-step-tracks`` tracks, scaled by steps.

``--interacting``: the default run of drivers who interact (`INTERACTING_POPULATION`, seed 0: headway and
yielding weights fitted too), our fit with its Hessians from tabulated stage outer products against the same fit
assembling them by `FeatureSet.expansion` (the baseline: factored per-residual products), alternating. Target:
< 20 s.

Times of our fit are medians over ``--repeats``; the machine is shared, so read the ratio. The BLAS thread
setting is printed; run it with OPENBLAS_NUM_THREADS=1 and without.
"""

from __future__ import annotations

import argparse
import itertools
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.optimize

from pirl_sim.receding import RecedingPolicy, fit_receding, receding_steps

RUN = Path("results/recovery/runs/sumo-seed0")
_GRID = (-2.0, 0.0, 2.0)  # as pirl_sim.receding's start grid
_GRID_STEPS = 12
_CAUCHY_C, _MAD_SIGMA, _FLOOR = 2.3849, 1.4826, 0.01


def _blas() -> str:
    try:
        from threadpoolctl import threadpool_info

        pools = [f"{p['internal_api']} {p['num_threads']} thread(s)" for p in threadpool_info()
                 if p.get("user_api") == "blas"]
    except ImportError:  # pragma: no cover
        pools = []
    return f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}" + (
        f" ({', '.join(pools)})" if pools else "")


def _load_run(path: Path | None, interacting: bool = False):
    from pirl_sim.scenarios.sumo.scenario import load_sumo_run, run_sumo_scenario, scenario_from_dict

    if path is not None and (path / "run.json").is_file():
        return load_sumo_run(path), None
    tmp = tempfile.TemporaryDirectory(prefix="bench_receding_")
    config = None
    if interacting:
        from pirl_sim.scenarios.population_config import INTERACTING_POPULATION

        config = scenario_from_dict({}, population=INTERACTING_POPULATION)
    run_sumo_scenario(config, 0, out_dir=tmp.name)
    return load_sumo_run(tmp.name), tmp


class _StagewisePolicy(RecedingPolicy):
    """The baseline of ``--interacting``: Hessians by `FeatureSet.expansion`."""

    def _outer(self, H):
        return None


def _interacting(args) -> None:
    import pirl_sim.receding as receding

    run, tmp = _load_run(args.run, interacting=True)
    demos = run.demonstrations(selection="steps", non_interacting=False, min_steps=10)
    model, H = run.model, run.horizon
    n_steps = sum(int(d.metadata["step_mask"].sum()) for d in demos)
    print(f"receding-horizon IRL, drivers who interact, SUMO run seed 0: {len(demos)} PIRL tracks, {n_steps} usable "
          f"steps, features {', '.join(model.features.names)}, H = {H}; {_blas()}")
    ours, base = [], []
    try:
        for _ in range(args.repeats):
            for policy, times in ((RecedingPolicy, ours), (_StagewisePolicy, base)):
                receding.RecedingPolicy = policy  # type: ignore[misc]  (fit_receding builds its policy by name)
                t0 = time.perf_counter()
                res = fit_receding(model, demos, horizon=H)
                times.append(time.perf_counter() - t0)
    finally:
        receding.RecedingPolicy = RecedingPolicy  # type: ignore[misc]
    m_ours, m_base = statistics.median(ours), statistics.median(base)
    print(f"  fit_receding, outer products      : {m_ours:8.2f} s (median of {args.repeats}) target < 20 s; converged "
          f"{int(res.converged.sum())}/{len(demos)}")
    print(f"  fit_receding, FeatureSet.expansion: {m_base:8.2f} s (median of {args.repeats})")
    print(f"  speed-up vs FeatureSet.expansion: {m_base / m_ours:6.2f}x")
    if tmp is not None:
        tmp.cleanup()


def _baseline_track(model, horizon, traj, free, ref, K, per_step=False):
    """One track: grid start, then least_squares with a finite-difference Jacobian; normalised weights.

    ``per_step``: every residual evaluation solves the MPC step by step (a loop of one-start solves of the
    same solver) instead of one batched call over the track's steps."""
    steps = receding_steps([traj], horizon)
    policy = RecedingPolicy(model, horizon)

    def theta_of(wf):
        w = np.zeros(K)
        w[free] = wf
        return np.exp(w)

    def resid(wf, rows=slice(None)):
        if per_step:
            idx = np.arange(steps.n_steps)[rows]
            first = np.concatenate([policy.solve(steps.x[i:i + 1], theta_of(wf), steps.init[i:i + 1]).first
                                    for i in idx])
            return (steps.u[rows] - first).ravel()
        sol = policy.solve(steps.x[rows], theta_of(wf), steps.init[rows])
        return (steps.u[rows] - sol.first).ravel()

    sub = np.unique(np.linspace(0, steps.n_steps - 1, min(_GRID_STEPS, steps.n_steps)).round().astype(int))
    best, w0 = np.inf, None
    for point in itertools.product(_GRID, repeat=len(free)):
        score = np.sum(np.abs(resid(np.array(point), sub)))
        if score < best:
            best, w0 = score, np.array(point)
    r0 = resid(w0)
    scale = max(_CAUCHY_C * _MAD_SIGMA * np.median(np.abs(r0)), _FLOOR * np.sqrt(np.mean(steps.u**2)))
    res = scipy.optimize.least_squares(resid, w0, jac="2-point", bounds=(-20.0, 20.0), method="trf",
                                       loss="cauchy", f_scale=scale, xtol=1e-6, ftol=1e-10, max_nfev=200)
    return theta_of(res.x), res.nfev


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="runs of our fit (median), default 3")
    ap.add_argument("--baseline-tracks", type=int, default=8, help="tracks the scipy loop runs on (default 8)")
    ap.add_argument("--per-step-tracks", type=int, default=2,
                    help="tracks the per-step variant of the scipy loop runs on (default 2)")
    ap.add_argument("--run", type=Path, default=RUN,
                    help="a recorded default SUMO run, seed 0 (simulated into a temporary directory if missing)")
    ap.add_argument("--interacting", action="store_true",
                    help="drivers who interact: our fit against Hessians by FeatureSet.expansion (module doc)")
    args = ap.parse_args(argv)
    if args.interacting:
        if args.run == RUN:
            args.run = None
        _interacting(args)
        return

    run, tmp = _load_run(args.run)
    demos = run.demonstrations(selection="steps", non_interacting=False, min_steps=10)
    model, H = run.model, run.horizon
    feats = model.features
    K, ref = feats.n_features, feats.reference_index
    free = np.array([k for k in range(K) if k != ref])
    n_steps = sum(int(d.metadata["step_mask"].sum()) for d in demos)
    print(f"receding-horizon IRL, default SUMO run seed 0: {len(demos)} PIRL tracks, {n_steps} usable steps, "
          f"H = {H}; {_blas()}")

    times, res = [], None
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        res = fit_receding(model, demos, horizon=H)
        times.append(time.perf_counter() - t0)
    ours = statistics.median(times)
    truth = np.array([d.metadata["theta"] for d in demos])
    err = np.abs(np.log(res.normalized[:, free] / truth[:, free]))
    print(f"  fit_receding, all tracks          : {ours:8.2f} s (median of {args.repeats}: "
          f"{', '.join(f'{t:.2f}' for t in times)})  target < 10 s; converged {int(res.converged.sum())}/"
          f"{len(demos)}, median |log err| {np.median(err):.4f}")

    pick = np.unique(np.linspace(0, len(demos) - 1, min(args.baseline_tracks, len(demos))).round().astype(int))
    t0 = time.perf_counter()
    base, nfev = [], 0
    for i in pick:
        th, n = _baseline_track(model, H, demos[i], free, ref, K)
        base.append(feats.normalize(th))
        nfev += n
    t_sub = time.perf_counter() - t0
    base = np.array(base)
    scaled = t_sub * len(demos) / len(pick)
    diff = np.abs(np.log(base[:, free] / res.normalized[pick][:, free]))
    berr = np.abs(np.log(base[:, free] / truth[pick][:, free]))
    print(f"  scipy least_squares loop, FD jac  : {t_sub:8.2f} s on {len(pick)} tracks ({nfev} residual "
          f"evaluations) -> {scaled:.1f} s scaled to {len(demos)} tracks; median |log err| {np.median(berr):.4f}")
    worst = int(np.argmax(diff.max(axis=1)))
    ours_err = np.abs(np.log(res.normalized[pick[worst]][free] / truth[pick[worst]][free]))
    print(f"  max |log(ours / baseline)| on those tracks: {diff.max():.2e} (median {np.median(diff):.1e}); on that "
          f"track |log err| ours {ours_err.max():.1e}, baseline {berr[worst].max():.1e}")
    print(f"  speed-up vs baseline (residuals batched per track): {scaled / ours:6.1f}x (target >= 20x)")
    pick2 = pick[:: max(1, len(pick) // max(args.per_step_tracks, 1))][: args.per_step_tracks]
    t0 = time.perf_counter()
    nfev2 = 0
    for i in pick2:
        _, n = _baseline_track(model, H, demos[i], free, ref, K, per_step=True)
        nfev2 += n
    t_step = time.perf_counter() - t0
    steps_picked = sum(int(demos[i].metadata["step_mask"].sum()) for i in pick2)
    scaled2 = t_step * n_steps / max(steps_picked, 1)
    print(f"  same loop, MPC solved step by step: {t_step:8.2f} s on {len(pick2)} tracks ({steps_picked} steps, "
          f"{nfev2} residual evaluations) -> {scaled2:.1f} s scaled to {n_steps} steps")
    print(f"  speed-up vs baseline (residuals step by step)     : {scaled2 / ours:6.1f}x (target >= 20x)")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
