"""Speed of ``pirl_sim/Roundabout-v0`` with 20 PIRL drivers, against bare highway-env in the same run.

    python benchmarks/bench_highway.py [--steps 150] [--repeats 5]

Workloads (all at highway-env's roundabout defaults of 1 agent step per second, with 10 simulation frames
of 0.1 s per step — the PIRL env's fixed 10 Hz — so that one env step is the same simulated time in all):

- **PIRL**: ``pirl_sim/Roundabout-v0``, the paper's three styles only (no background traffic), 20 PIRL
  drivers on the road at reset and one arrival every 1.5 s (about 20 on the road throughout; the mean is
  printed), each re-planning with its MPC every frame (one batched call per frame), plus the ego.
- **PIRL on SUMO**: the same env with ``backend = "sumo"`` (SUMO's roundabout, the same population after a
  30 s warm-up; SUMO's Krauss model for no one: background share 0), for reference.
- **baseline, 20 IDM**: highway-env's ``roundabout-generic-v0`` with ``vehicles_count = 20`` and one ring
  lane: the same road with 20 of highway-env's IDM drivers (plus the ego): the like-for-like baseline.
- **baseline, roundabout-v0**: highway-env's ``roundabout-v0`` as shipped (4 IDM drivers plus the ego) but
  at the PIRL env's 10 frames per second (shipped: 15, which would make each of its steps 1.5x dearer):
  the named baseline.

The ego keeps its speed (PIRL: action 0; highway-env: IDLE). Only ``env.step`` is timed; episodes that end
(the ego crashes into traffic it does not yield to, or time runs out) are reset outside the timed region.
Steps/s are medians of ``--repeats`` rounds, each round measuring every workload once (interleaved, so
that other load on the machine hits all of them alike). Targets: the PIRL env no more than 1.5x slower than
the bare ``roundabout-v0`` (the baseline named in the output), nor than the 20-IDM one. The load
average is printed before and after.
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import numpy as np

TARGET_SLOWDOWN = 1.5  # <= 1.5x the bare roundabout-v0


def timed_steps(env, action, n_steps: int, seed: int) -> tuple[float, float]:
    """(steps per second over n_steps env.step calls, mean vehicles on the road)."""
    env.reset(seed=seed)
    spent, counts = 0.0, []
    k = 0
    while k < n_steps:
        t0 = time.perf_counter()
        _, _, terminated, truncated, info = env.step(action)
        spent += time.perf_counter() - t0
        counts.append(info["n_vehicles"] if "n_vehicles" in info else len(env.unwrapped.road.vehicles))
        k += 1
        if terminated or truncated:
            env.reset()
    return n_steps / spent, float(np.mean(counts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=150, help="env steps per measurement (default 150)")
    ap.add_argument("--repeats", type=int, default=5, help="measurements per workload (default 5)")
    args = ap.parse_args()
    import os

    load0 = os.getloadavg()[0]

    import gymnasium as gym
    import highway_env  # noqa: F401  (registers highway-env's envs)

    import pirl_sim.envs  # noqa: F401  (registers pirl_sim/Roundabout-v0)
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, population_from_dict

    population = population_from_dict({**DEFAULT_POPULATION.to_dict(), "background_share": 0.0,
                                       "n_vehicles": 400, "depart_interval": 1.5})
    workloads = {
        "PIRL env, 20 PIRL drivers": (
            lambda: gym.make("pirl_sim/Roundabout-v0", config={
                "population": population, "initial_vehicles": 20, "policy_frequency": 1, "duration": 1e6}),
            np.zeros(1, dtype=np.float32)),
        "PIRL env on SUMO, ~20 PIRL drivers": (
            lambda: gym.make("pirl_sim/Roundabout-v0", config={
                "backend": "sumo", "population": population, "warmup": 30.0, "policy_frequency": 1,
                "duration": 1e6}),
            np.zeros(1, dtype=np.float32)),
        "baseline: roundabout-generic-v0, 20 IDM": (
            lambda: gym.make("roundabout-generic-v0", config={
                "vehicles_count": 20, "roundabout_lanes": 1, "simulation_frequency": 10, "policy_frequency": 1,
                "duration": 1e6}),
            1),
        "baseline: roundabout-v0 (4 IDM)": (
            lambda: gym.make("roundabout-v0", config={"simulation_frequency": 10, "policy_frequency": 1}),
            1),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # highway-env's "out of date: use v1" deprecation notices
        envs = {name: make() for name, (make, _) in workloads.items()}
        rates: dict[str, list[float]] = {name: [] for name in workloads}
        counts: dict[str, list[float]] = {name: [] for name in workloads}
        for r in range(args.repeats):  # workloads interleaved, so that load on the machine hits all alike
            for name, (_, action) in workloads.items():
                rate, count = timed_steps(envs[name], action, args.steps, seed=r)
                rates[name].append(rate)
                counts[name].append(count)
    results = {}
    for name, env in envs.items():
        results[name] = (statistics.median(rates[name]), float(np.mean(counts[name])))
        extra = ""
        ctrl = getattr(getattr(env.unwrapped, "road", None), "controller", None) or getattr(
            getattr(env.unwrapped, "_controller", None), "drivers", None)
        if ctrl is not None:
            extra = f"   (last episode: MPC {1e3 * ctrl.plan_time_s / max(ctrl.n_calls, 1):.2f} ms per batched call)"
        env.close()
        rate, count = results[name]
        print(f"{name:42s}: {rate:7.2f} steps/s  {1e3 / rate:7.1f} ms/step  {count:5.1f} vehicles on the road{extra}")
    print(f"load average {load0:.2f} before, {os.getloadavg()[0]:.2f} after ({os.cpu_count()} cores)")
    pirl = results["PIRL env, 20 PIRL drivers"][0]
    like = results["baseline: roundabout-generic-v0, 20 IDM"][0]
    ref = results["baseline: roundabout-v0 (4 IDM)"][0]
    for label, base in (("bare roundabout-v0 (its 4 IDM drivers; the issue's baseline)", ref),
                        ("20 IDM drivers (same road, same count)", like)):
        slow = base / pirl
        print(f"slowdown vs {label}: {slow:.2f}x (target <= {TARGET_SLOWDOWN:g}x: "
              f"{'met' if slow <= TARGET_SLOWDOWN else 'NOT met'})")

if __name__ == "__main__":
    main()
