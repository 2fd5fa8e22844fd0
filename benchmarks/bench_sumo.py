"""SUMO roundabout speed: PIRL drivers re-planning every 0.1 s step, libsumo against TraCI in one run.

    python3 benchmarks/bench_sumo.py            # ~1-2 min

A 40-vehicle roundabout (the default population: the paper's three styles, 20 % SUMO background traffic;
the default 4-arm network), every PIRL driver re-planning with its MPC at every 0.1 s step (one batched
call per step for all of them). The process is pinned to one core (``os.sched_setaffinity``; a TraCI SUMO
server started from it inherits the pinning) and BLAS to one thread. Prints, from medians of ``REPEATS``
runs of the same seed:

- simulated seconds per wall second of the stepping (SUMO, recording, observations and the PIRL drivers;
  SUMO start-up and network building excluded, target >= 50x), with a breakdown per step;
- the same with TraCI instead of libsumo, and the libsumo / TraCI ratios (all, and SUMO's side alone: the
  stepping without the drivers' time);
- the same at twice the traffic (a vehicle every 2 s instead of 4 s) for context.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import dataclasses  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

REPEATS = 3
N_VEHICLES = 40
SEED = 0


def _pin_to_one_core() -> str:
    if hasattr(os, "sched_setaffinity"):
        core = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {core})
        return f"pinned to core {core}"
    return "not pinned (no sched_setaffinity)"


def _measure(config, backend: str) -> dict:
    from pirl_sim.scenarios.sumo import run_sumo_scenario

    runs = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        res = run_sumo_scenario(config, SEED, backend=backend)
        total = time.perf_counter() - t0
        t = res.timing
        runs.append({
            "wall": t["wall_time_s"], "control": t["control_time_s"], "plan": t["plan_time_s"],
            "sim": t["sim_time_s"], "steps": t["n_steps"], "plans": t["n_plans"], "total": total,
            "mean_vehicles": t["mean_vehicles"], "max_vehicles": t["max_vehicles"],
            "n_pirl": int(res.vehicles["is_pirl"].sum()),
        })
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    med["rtf"] = med["sim"] / med["wall"]
    med["sumo_side"] = med["wall"] - med["control"]
    return med


def _report(label: str, m: dict) -> None:
    per = 1e3 / m["steps"]
    print(f"  {label:8s}: {m['rtf']:7.1f}x real time  ({m['sim']:.1f} s simulated in {m['wall']:.2f} s of stepping; "
          f"{m['total']:.2f} s with start-up)")
    print(f"            per step: {m['wall'] * per:.3f} ms = SUMO + recording {m['sumo_side'] * per:.3f} ms"
          f" + drivers {m['control'] * per:.3f} ms (MPC {m['plan'] * per:.3f} ms);"
          f" {m['plans'] / m['wall']:.0f} re-plans per wall second")


def main() -> int:
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION
    from pirl_sim.scenarios.sumo import SumoScenarioConfig

    pinned = _pin_to_one_core()
    base = SumoScenarioConfig(population=dataclasses.replace(DEFAULT_POPULATION, n_vehicles=N_VEHICLES))
    dense = dataclasses.replace(base, population=dataclasses.replace(base.population, depart_interval=2.0))
    print(f"SUMO roundabout benchmark ({pinned}; medians of {REPEATS} runs, seed {SEED})")
    for name, cfg in (("default traffic, a vehicle every 4 s", base), ("twice the traffic, every 2 s", dense)):
        lib = _measure(cfg, "libsumo")
        print(f"{N_VEHICLES} vehicles ({lib['n_pirl']} PIRL drivers), {name}: {lib['mean_vehicles']:.1f} in the "
              f"network on average, at most {lib['max_vehicles']}")
        _report("libsumo", lib)
        if cfg is base:
            tra = _measure(cfg, "traci")
            _report("traci", tra)
            print(f"  libsumo / traci speed ratio: {tra['wall'] / lib['wall']:.2f}x over the whole stepping, "
                  f"{tra['sumo_side'] / lib['sumo_side']:.2f}x on SUMO's side (stepping minus the drivers)")
        verdict = "meets" if lib["rtf"] >= 50 else "MISSES"
        print(f"  {verdict} the >= 50x real-time target ({lib['rtf']:.1f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
