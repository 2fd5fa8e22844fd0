"""``pirl-sim recover``: weight recovery of the receding-horizon IRL on simulated runs
(`pirl_sim.experiments.recovery`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from pirl_sim.validation import list_arg, positive_int_arg, seed_arg

from .common import add_study_options, finish, run_study, subcommand, table_text

__all__ = ["add_parser", "run", "DEFAULT_OUT", "SIMULATORS"]

DEFAULT_OUT = Path("results") / "recovery"
#: `pirl_sim.experiments.recovery.SIMULATORS`, named here so that the parser does not import the study
SIMULATORS = ("sumo", "highway")


@subcommand("recover", help="weight recovery of the receding-horizon IRL on simulated runs (table of errors per seed)",
            description="Simulate each seed (or reuse its run under OUT/simulations), fit the receding-horizon IRL "
            "to every PIRL track with enough usable steps and TIRL per style, and write table.csv/.md, styles.csv, "
            "tracks.csv, selection.csv, times.csv, README.md (and noise.csv/.md with --control-noise) and "
            "scene_<simulator>_weights.png / _errors.png (the first seed's tracks on the road, coloured by the fitted "
            "weight and its error) to --out.")
def add_parser(p) -> None:
    """The options of ``recover``."""
    p.add_argument("--simulator", choices=[*SIMULATORS, "both"], default="sumo",
                   help="sumo (default), highway, or both")
    p.add_argument("--seeds", type=seed_arg, nargs="+", default=[0, 1, 2, 3], help="seeds (default 0 1 2 3)")
    p.add_argument("--population", type=Path, metavar="CONFIG", help="population TOML (default: the embedded one)")
    p.add_argument("--scenario", type=Path, metavar="CONFIG",
                   help="scenario TOML, e.g. from pirl-sim calibrate: its road, demand and drivers, and its "
                        "population unless --population is given (for each --simulator)")
    p.add_argument("--n-vehicles", type=positive_int_arg, help="override the population's number of vehicles")
    p.add_argument("--stride", type=positive_int_arg, default=1, help="score every STRIDE-th step (default 1)")
    p.add_argument("--min-steps", type=positive_int_arg, default=10,
                   help="usable steps a PIRL track needs to be fitted (default 10)")
    p.add_argument("--control-noise", type=list_arg(float, low=0), default=[], metavar="LEVELS", help="noise study: "
                   "comma-separated control-noise levels [m/s^3], e.g. 0,0.1,0.3,1 (written to noise.csv/.md)")
    p.add_argument("--noise-seeds", type=seed_arg, nargs="+", help="seeds of the noise study (default: --seeds)")
    add_study_options(p, "runs simulated and fitted", count="runs still to do")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")


def run(args) -> int:
    """``pirl-sim recover``: 0 on success, 1 when runs failed (the others are kept), 2 for a bad configuration,
    130 when interrupted (finished runs are kept)."""
    from pirl_sim.engine.store import ResultStore, SIMULATION_RECORD, simulation_key
    from pirl_sim.experiments.recovery import (SPEC, check_targets, compact_table, recovery_jobs, recovery_result,
                                               write_recovery)
    from pirl_sim.experiments.recovery_scenes import write_recovery_scenes
    from pirl_sim.io import toml_text

    sims = list(SIMULATORS) if args.simulator == "both" else [args.simulator]
    command = "pirl-sim " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["recover"] else "pirl-sim recover"

    def make_config():
        scenario: dict = {}
        if args.scenario is not None:  # a relative map as simulate reads it: beside the file
            from pirl_sim.scenarios.scenario_config import resolve_lanelet_map

            scenario = resolve_lanelet_map(toml_text.load(args.scenario, "scenario config")[0], args.scenario)
        population = scenario.pop("population", {})
        if args.population is not None:
            population = toml_text.load(args.population, "population config")[0]
        jobs = recovery_jobs(sims, args.seeds, population=population, n_vehicles=args.n_vehicles,
                             control_noise=args.control_noise, noise_seeds=args.noise_seeds,
                             min_steps=args.min_steps, stride=args.stride, scenario=scenario)
        return {"name": "recovery", "experiments": [j.experiment() for j in jobs]}, jobs

    def report(result, config, jobs) -> int:
        store, simulated, sim_time, run_dirs = ResultStore(args.out), [], [], []
        for cell in config.cells:
            sk = simulation_key("recovery", SPEC.simulation(dict(cell.scenario_params)),  # type: ignore[misc]
                                cell.seed, result.code_version)
            run_dirs.append(store.simulation_dir(sk))
            record = run_dirs[-1] / SIMULATION_RECORD
            simulated.append(sk in result.simulated)
            sim_time.append(float(json.loads(record.read_text("utf-8"))["timings"]["simulate_s"]) if record.is_file()
                            else 0.0)
        records = [result.records[k]["result"] for k in result.keys]
        study = recovery_result(jobs, records, simulated=simulated, sim_time_s=sim_time, workers=max(args.workers, 1))
        write_recovery(study, args.out, command)
        write_recovery_scenes(study, run_dirs, args.out)
        table = study.table()
        print(table_text(compact_table(table)))
        for sim in sims:
            row = table[table["simulator"] == sim].iloc[-1].to_dict()
            missed = [f"{c} = {v:.3g} (target {op} {lim:g})" for c, op, lim, v, ok in check_targets(row, sim) if not ok]
            print(f"{sim} (seed {row['seed']}): " + (f"NOT met: {'; '.join(missed)}" if missed else "every target met"))
        return finish(f"{args.out}/")

    return run_study("recovery", make_config, report, args, command, "simulations/\ncells/\nerrors/\nsweep.json\n",
                     source=str(args.scenario or args.population or "pirl-sim recover"))
