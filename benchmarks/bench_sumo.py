"""SUMO roundabout speed: PIRL drivers re-planning every 0.1 s step, how many at once, libsumo against TraCI.

    python3 benchmarks/bench_sumo.py                 # ~4 min (~8 min with --crowded-repeats 3)
    python3 benchmarks/bench_sumo.py --skip-traci --crowded-repeats 1 --baseline none   # ~1 min

Every PIRL driver re-plans with its MPC at every 0.1 s step (one batched call per step for all of them). The
process is pinned to one core (``os.sched_setaffinity``; a TraCI SUMO server started from it inherits the
pinning) and BLAS to one thread (threadpoolctl, printed). Scenarios (all with the default population: the
paper's three styles, 20 % SUMO background traffic; seed 0):

- ``default``: 40 vehicles, a vehicle every 4 s, the default single-lane 4-arm roundabout; medians of
  ``--repeats`` runs with libsumo and with TraCI, and the libsumo / TraCI ratios (all, and SUMO's side
  alone: the stepping without the drivers' time);
- ``crowded``: a two-lane roundabout with 400 m arms, 750 vehicles per hour per arm, 200 vehicles, stopped
  at 240 s when the last one has departed (target: >= 40 PIRL drivers at once on average at
  >= 50x real time, every one re-planning every 0.1 s);
- ``very crowded``: two lanes, 1 km arms, 800 vehicles per hour per arm, 400 vehicles, 450 s (target:
  >= 100 at once at >= 20x); both crowded ones with libsumo, medians of ``--crowded-repeats`` runs;
- ``interacting``: the crowded scenario with drivers who interact (`INTERACTING_POPULATION`: headway and
  yielding in their cost; target >= 40 at once at >= 30x); its baseline is 7063aa3, where these drivers plan
  with the numpy MPC.
  Their demand stays below the two-lane ring's capacity, so the drivers are in free flow and re-plan (at a
  single-lane ring's capacity queues form, and SUMO holds queued PIRL drivers at a standstill, where they
  do not plan: "planned per step" below counts the drivers the MPC actually drove).

Prints, per scenario: PIRL drivers in the network at once (mean and max over the steps of the whole run,
filling included; "planned" counts those the MPC drove, the others were held at a standstill
by SUMO), all vehicles at once, simulated seconds per wall second of the stepping (SUMO, recording,
observations and the drivers; SUMO start-up, network building and writing excluded) with a breakdown per
step and per re-plan, and whether the targets are met.

The crowded scenarios also run on a baseline revision (``--baseline``, default e4e91c3: the code without the
compiled drivers; ``none`` skips it), in child processes alternating with this code so that both see the same
load (`_baseline.py`), and the speed-up is printed.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _baseline import export_revision, run_worker  # noqa: E402

REPEATS = 3
N_VEHICLES = 40
SEED = 0
#: the default baseline revision: the code without the compiled drivers
BASELINE = "e4e91c3"
INTERACTING_BASELINE = "7063aa3"  # drivers who interact, planned by the numpy MPC (no compiled kernel for them)


def _pin_to_one_core() -> str:
    if hasattr(os, "sched_setaffinity"):
        core = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {core})
        return f"pinned to core {core}"
    return "not pinned (no sched_setaffinity)"


def _run_once(config, backend: str) -> dict:
    """One run of a scenario: its timing (see `_measure`)."""
    from pirl_sim.scenarios.sumo import run_sumo_scenario

    t0, c0 = time.perf_counter(), time.process_time()
    res = run_sumo_scenario(config, SEED, backend=backend)
    total, cpu = time.perf_counter() - t0, time.process_time() - c0
    t = res.timing
    return {
        "wall": t["wall_time_s"], "control": t["control_time_s"], "plan": t["plan_time_s"],
        "sim": t["sim_time_s"], "steps": t["n_steps"], "plans": t["n_plans"], "total": total,
        "mean_vehicles": t["mean_vehicles"], "max_vehicles": t["max_vehicles"],
        "mean_pirl": t["mean_pirl"], "max_pirl": t["max_pirl"],
        "n_pirl": int(res.vehicles["is_pirl"].sum()),
        "cpu_share": cpu / total,  # the share of a core this process got (libsumo runs in it)
    }


def _summarise(runs: list[dict]) -> dict:
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    med["rtf"] = med["sim"] / med["wall"]
    # on a shared machine the process gets only part of its core: the factor it would reach on a core of its
    # own, estimated from the CPU time of the whole run (start-up and recording included)
    med["rtf_cpu"] = med["rtf"] / min(med["cpu_share"], 1.0)
    med["sumo_side"] = med["wall"] - med["control"]
    return med


def _measure(config, backend: str, repeats: int) -> dict:
    """Medians over ``repeats`` runs in this process."""
    return _summarise([_run_once(config, backend) for _ in range(repeats)])


def _report(label: str, m: dict) -> None:
    per = 1e3 / m["steps"]
    print(f"  {label:8s}: {m['rtf']:7.1f}x real time  ({m['sim']:.1f} s simulated in {m['wall']:.2f} s of stepping; "
          f"{m['total']:.2f} s with start-up and recording); this process got {100 * m['cpu_share']:.0f} % of its "
          f"core: ~{m['rtf_cpu']:.1f}x on a core of its own")
    print(f"            per step: {m['wall'] * per:.3f} ms = SUMO + recording {m['sumo_side'] * per:.3f} ms"
          f" + drivers {m['control'] * per:.3f} ms (MPC {m['plan'] * per:.3f} ms);"
          f" {m['plans'] / m['steps']:.1f} re-plans per step, {1e3 * m['plan'] / max(m['plans'], 1):.3f} ms of MPC each")


def _crowd(m: dict) -> str:
    return (f"PIRL drivers at once: mean {m['mean_pirl']:.1f}, max {m['max_pirl']} ({m['plans'] / m['steps']:.1f} "
            f"planned per step); all vehicles at once: mean {m['mean_vehicles']:.1f}, max {m['max_vehicles']}")


def scenarios():
    """(name, config, (target PIRL drivers at once, target real-time factor) or None)."""
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION, INTERACTING_POPULATION
    from pirl_sim.scenarios.sumo import SumoScenarioConfig

    base = SumoScenarioConfig(population=dataclasses.replace(DEFAULT_POPULATION, n_vehicles=N_VEHICLES))

    def crowded(lanes, approach, demand, n, duration, population=DEFAULT_POPULATION):
        net = dataclasses.replace(base.network, lanes=lanes, approach_length=approach)
        return SumoScenarioConfig(network=net, population=dataclasses.replace(population, n_vehicles=n),
                                  demand_per_arm=demand, max_duration=duration)

    return [
        ("default: 40 vehicles, one every 4 s, one lane", base, None),
        ("crowded: two lanes, 400 m arms, 750 veh/h per arm, 200 vehicles, 240 s",
         crowded(2, 400.0, 750.0, 200, 240.0), (40, 50.0)),
        ("very crowded: two lanes, 1 km arms, 800 veh/h per arm, 400 vehicles, 450 s",
         crowded(2, 1000.0, 800.0, 400, 450.0), (100, 20.0)),
        ("interacting: the crowded scenario with drivers who weigh headway and yielding",
         crowded(2, 400.0, 750.0, 200, 240.0, INTERACTING_POPULATION), (40, 30.0)),
    ]


def _worker(index: int) -> None:
    """Child process (``--worker``): one libsumo run of scenario ``index`` on whichever pirl_sim is imported."""
    from pirl_sim.threads import apply_thread_policy

    apply_thread_policy(1)
    _, cfg, _ = scenarios()[index]
    print(json.dumps(_run_once(cfg, "libsumo")))


def _compare(index: int, repeats: int, baseline: str) -> tuple[dict, dict]:
    """Runs of scenario ``index`` in child processes on this code and on revision ``baseline``, alternating
    (both see the same load); medians of each."""
    here = os.path.abspath(__file__)
    base_code = export_revision(baseline)
    ours, base = [], []
    for _ in range(repeats):
        ours.append(run_worker(here, [str(index)]))
        base.append(run_worker(here, [str(index)], base_code))
    return _summarise(ours), _summarise(base)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=REPEATS, help=f"runs of the default scenario (default {REPEATS})")
    ap.add_argument("--crowded-repeats", type=int, default=1, help="runs of each crowded scenario (default 1)")
    ap.add_argument("--skip-traci", action="store_true", help="no TraCI runs")
    ap.add_argument("--only", default=None, help="run only the scenarios whose name starts with this")
    ap.add_argument("--baseline", default=BASELINE,
                    help=f"git revision whose code the crowded scenarios are also run on, alternating with this "
                         f"code (default {BASELINE}: before the compiled drivers; the interacting scenario: "
                         f"{INTERACTING_BASELINE}, its drivers on the numpy MPC); 'none' skips both")
    ap.add_argument("--worker", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    from pirl_sim.threads import apply_thread_policy, current_blas_threads

    apply_thread_policy(1)
    pinned = _pin_to_one_core()  # before any child starts: the children inherit the pinning
    if args.worker is not None:
        _worker(args.worker)
        return 0
    threads = ", ".join(f"{k} {v}" for k, v in current_blas_threads().items())
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    print(f"SUMO roundabout benchmark ({pinned}; BLAS threads: {threads}; seed {SEED}; load average "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at the start)")
    for index, (name, cfg, target) in enumerate(scenarios()):
        if args.only and not name.startswith(args.only):
            continue
        if target is None:
            repeats = args.repeats
            lib = _measure(cfg, "libsumo", repeats)
            print(f"{name} (medians of {repeats}):")
            print(f"  {_crowd(lib)}")
            _report("libsumo", lib)
            if not args.skip_traci:
                tra = _measure(cfg, "traci", repeats)
                _report("traci", tra)
                print(f"  libsumo / traci speed ratio: {tra['wall'] / lib['wall']:.2f}x over the whole stepping, "
                      f"{tra['sumo_side'] / lib['sumo_side']:.2f}x on SUMO's side (stepping minus the drivers)")
            verdict = "meets" if lib["rtf"] >= 50 else "MISSES"
            print(f"  {verdict} the >= 50x real-time target ({lib['rtf']:.1f}x)")
            continue
        repeats = args.crowded_repeats
        interacting = name.startswith("interacting")
        baseline = INTERACTING_BASELINE if interacting else args.baseline
        if args.baseline.lower() == "none":
            lib, base = _measure(cfg, "libsumo", repeats), None
        else:
            lib, base = _compare(index, repeats, baseline)
        print(f"{name} (medians of {repeats}{', alternating with ' + baseline if base else ''}):")
        print(f"  {_crowd(lib)}")
        _report("libsumo", lib)
        n_at_once, rtf = target
        ok = lib["mean_pirl"] >= n_at_once and lib["rtf"] >= rtf
        print(f"  {'meets' if ok else 'MISSES'} the target of >= {n_at_once} PIRL drivers at once at >= {rtf:.0f}x "
              f"real time ({lib['mean_pirl']:.1f} at {lib['rtf']:.1f}x; ~{lib['rtf_cpu']:.1f}x on a core of its own)")
        if base is not None:
            what = "these drivers on the numpy MPC" if interacting else "the code before the compiled drivers"
            print(f"  {baseline} ({what}), same scenario:")
            print(f"  {_crowd(base)}")
            _report("libsumo", base)
            print(f"  speed-up over {baseline}: {base['wall'] / lib['wall']:.2f}x over the stepping "
                  f"({lib['wall'] * 1e3 / lib['steps']:.3f} against {base['wall'] * 1e3 / base['steps']:.3f} ms per step), "
                  f"{base['control'] / lib['control']:.2f}x on the drivers' side, "
                  f"{base['sumo_side'] / lib['sumo_side']:.2f}x on SUMO's and the recording's")
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    print(f"load average at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
