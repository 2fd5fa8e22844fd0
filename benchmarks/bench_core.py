"""Speed targets of the core (IRL, MPC, learners), measured in one run and printed as ratios against named baselines.

    python benchmarks/bench_core.py [--repeats 5] [--baseline-demos 1800]

1. Per-demonstration IRL for the 1,800 synthetic training demos (PIRL-kNN's offline fit, features and
   derivatives included). Target: < 2 s, and >= 20x faster than the baseline "one scipy.optimize.minimize
   (L-BFGS-B, same bounds, same Laplace likelihood and exact gradient) per demonstration in a Python loop".
   The batched generic (dense Hessian) path is printed too, to show what the eigenbasis path buys.
2. Closed-form LQ prediction, N = 50: predictions per second for 20,000 starts, each with its own weights
   (the kNN case) and with shared weights (TIRL/GMM case). Target: >= 20,000 predictions/s.
Times are medians over --repeats runs; the machine is shared, so read ratios rather than absolute numbers.
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import numpy as np
import scipy.optimize

from pirl_sim.irl import LaplaceBlock, fit_weights, laplace_nll
from pirl_sim.learners import PIRLKNN
from pirl_sim.mpc import LQPredictor
from pirl_sim.scenarios.synthetic import SyntheticConfig, generate


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _scipy_loop(model, demos, log_bounds=(-20.0, 20.0)):
    """The baseline: one L-BFGS-B per demonstration on the same likelihood (dense Laplace terms)."""
    fs = model.features
    K, ref = fs.n_features, fs.reference_index
    P = np.eye(K)
    P[:, ref] = 1.0
    out = np.empty((len(demos), K))
    for i, d in enumerate(demos):
        der = fs.derivatives(model.dynamics, d.states[None], d.controls[None])
        block = LaplaceBlock(der.grad, der.hess, None)

        def f(w):
            theta = np.exp(P @ w)[None]
            nll, g, *_ = laplace_nll(theta, block, order=1)
            return float(nll[0]), (theta[0] * g[0]) @ P

        res = scipy.optimize.minimize(f, np.zeros(K), jac=True, method="L-BFGS-B", bounds=[log_bounds] * K)
        out[i] = np.exp(P @ res.x)
    return fs.normalize(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--baseline-demos", type=int, default=1800, help="demos in the scipy baseline (scaled to 1,800)")
    args = ap.parse_args(argv)

    data = generate(SyntheticConfig())
    model, train = data.model, data.train
    true = np.stack([t.metadata["theta"] for t in train])

    t_batched = _median_time(lambda: PIRLKNN(model).fit(train), args.repeats)
    knn = PIRLKNN(model).fit(train)

    states = np.stack([t.states for t in train])
    controls = np.stack([t.controls for t in train])

    def dense_fit():
        der = model.features.derivatives(model.dynamics, states, controls)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return fit_weights(LaplaceBlock(der.grad, der.hess, None), None, model.features)

    t_dense = _median_time(dense_fit, max(1, args.repeats // 2))
    n_base = min(args.baseline_demos, len(train))
    t0 = time.perf_counter()
    base_theta = _scipy_loop(model, train[:n_base])
    t_base = (time.perf_counter() - t0) * len(train) / n_base

    err_batched = np.max(np.abs(np.log(knn.demo_theta_[:, 0] / true[:, 0])))
    err_base = np.max(np.abs(np.log(base_theta[:, 0] / true[:n_base, 0])))
    print(f"per-demo IRL, {len(train)} synthetic demos (N=50), medians of {args.repeats}:")
    print(f"  batched, eigenbasis path (PIRLKNN.fit) : {t_batched:8.3f} s   max |log err| {err_batched:.1e}  target < 2 s")
    print(f"  batched, dense generic path            : {t_dense:8.3f} s")
    print(f"  baseline scipy L-BFGS-B loop {'' if n_base == len(train) else f' (x{len(train)/n_base:.1f} from {n_base})'}       : {t_base:8.3f} s   max |log err| {err_base:.1e}")
    print(f"  speed-up vs baseline: eigenbasis {t_base / t_batched:6.1f}x (target >= 20x), dense {t_base / t_dense:6.1f}x")

    pred = LQPredictor(model.dynamics, model.features)
    rng = np.random.default_rng(0)
    M, N = 20000, 50
    x0 = np.column_stack([rng.uniform(-5, 5, M), rng.uniform(-2, 2, M)])
    theta = np.column_stack([rng.uniform(0.1, 6, M), np.ones(M)])
    pred.controls(x0[:10], theta[:10], N)  # build the cached quadratic form once
    t_each = _median_time(lambda: pred.predict(x0, theta, N), args.repeats)
    t_shared = _median_time(lambda: pred.predict(x0, theta[0], N), args.repeats)
    print(f"closed-form LQ prediction, N={N}, {M} starts:")
    print(f"  own weights per start : {M / t_each:10.0f} predictions/s  ({M / t_each / 20000:.1f}x the 20,000/s target)")
    print(f"  shared weights        : {M / t_shared:10.0f} predictions/s  ({M / t_shared / 20000:.1f}x the 20,000/s target)")


if __name__ == "__main__":
    main()
