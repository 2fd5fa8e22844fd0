"""The cell key's code version covers exactly the code that computes a cell.

- every source file whose code runs while cells of every registered scenario compute (traced in a fresh
  process, under a profiler) is one of the hashed files, and so is every module those cells import;
- the report, the command lines, figures, the replay's report template and the envs are not hashed (the
  replay's cells, scenario ``recorded``, are: `pirl_sim.experiments.recorded` and what it runs); the envs are the
  ``agents`` scenario's own code, hashed into its cells' keys only;
- the committed ``results/sweep`` matches the code: ``pirl-sim sweep --dry-run`` over it has nothing to run.
"""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from pirl_sim.engine import ResultStore
from pirl_sim.engine.store import NAME_ONLY_CODE, NOT_CELL_CODE, code_version, source_files


REPO = Path(__file__).resolve().parents[2]

#: one tiny experiment per registered scenario, every learner and protocol kind, both likelihoods
TRACE_CONFIG = """
seeds = [0]

[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 40, n_train = 30, n_steps = 20 }
protocols = ["paper", { kind = "online", history_steps = 5 }]
learners = ["tirl", { name = "pirl-gmm", params = { n_components = 2 } }, "pirl-dpgmm",
            { name = "pirl-knn", params = { n_neighbors = 2 } }]

[[experiments]]
scenario = "passage"
params = { n_trajectories = 24, n_train = 18, n_steps = 20 }
protocols = [{ kind = "rolling", history_steps = 5, horizon = 5, stride = 5 }]
learners = ["tirl", { name = "tirl", label = "TIRL receding", params = { likelihood = "receding", horizon = 10 } },
            { name = "pirl-knn", params = { n_neighbors = 2, prior = "population" } }]

[[experiments]]
scenario = "sumo"
params = { n_vehicles = 8, depart_interval = 3.0 }
protocols = ["paper", { kind = "rolling", history_steps = 10, horizon = 10, stride = 20 }]
learners = ["cv", "ca", { name = "tirl", params = { likelihood = "receding", step_stride = 4 } },
            { name = "pirl-knn", params = { n_neighbors = 1, likelihood = "receding", step_stride = 4 } }]

[[experiments]]
scenario = "highway"
params = { n_vehicles = 8, depart_interval = 3.0, selection = "tracks" }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 20 }]
learners = ["cv", { name = "tirl", params = { likelihood = "receding", step_stride = 4 } }]

[[experiments]]
scenario = "replay"
params = { tracks = "scene", map = "scene/map.osm" }
protocols = [{ kind = "rolling", history_steps = 5, horizon = 5, stride = 5 }]
learners = ["tirl"]

[[experiments]]
scenario = "recorded"
params = { tracks = "scene", map = "scene/map.osm", replay = { fde_steps = [5], lateral = "neighbours", desired_speed = "fit", n_futures = 2 } }
protocols = [{ kind = "rolling", history_steps = 5, horizon = 5, stride = 5 }]
learners = [
    "cv", "ca", "tirl", { name = "pirl-knn", params = { n_neighbors = 2 } }, "hindsight", "cv-xy",
    { name = "pirl-knn", label = "next", params = { n_neighbors = 2, target = "next", target_steps = 5, state_features = [1, 2], state_lags = [0, 2], lookup_features = false, aggregate = "futures" } },
]

[[experiments]]
scenario = "recovery"
params = { simulator = "highway", n_vehicles = 6 }
learners = [{ name = "receding-irl", params = { stride = 4 } }]

[[experiments]]
scenario = "agents"
params = { eval_episodes = 1, initial_vehicles = 4 }
protocols = ["paper"]
learners = ["hold-speed", "idm", "mpc",
            { name = "ppo", params = { steps = 64, n_steps = 32, batch_size = 32, action = "shielded-residual-idm" } },
            { name = "ppo", label = "inferred", params = { steps = 32, n_steps = 32, batch_size = 32, style_observation = "inferred" } }]

[[experiments]]
scenario = "recorded"
label = "recorded, closed loop"
params = { tracks = "scene", map = "scene/map.osm", replay = { fde_steps = [5], rollout = "closed", mpc_horizon = 5 } }
protocols = [{ kind = "rolling", history_steps = 5, horizon = 5, stride = 5 }]
learners = ["tirl"]

[[experiments]]
scenario = "horizon-scan"
params = { tracks = "scene", map = "scene/map.osm", replay = { fde_steps = [5], desired_speed = "fit" } }
protocols = [{ kind = "rolling", history_steps = 5, horizon = 5, stride = 5 }]
learners = [{ name = "mpc-horizon", params = { step_stride = 4 }, grid = { horizon = [3, 5] } }]

[[experiments]]
scenario = "policy-recovery"
params = { n_vehicles = 1, initial_vehicles = 0, duration = 4.0 }
learners = [{ name = "ppo-theta", params = { eval_seeds = [1000], steps = 32, n_steps = 32, batch_size = 32, n_epochs = 1 } },
            { name = "mpc-theta", params = { eval_seeds = [1000] } }]

[[experiments]]
scenario = "weight-space"
params = { experiment = "lq-receding" }
protocols = ["paper", { kind = "online", history_steps = 10 }]
learners = [{ name = "pirl-gmm", params = { n_components = 3, space = "weights", likelihood = "receding", horizon = 15 } }]
"""

TRACER = textwrap.dedent("""
    import json, sys
    from pirl_sim.engine.worker import run_cell, warm_up, _worker_version
    from pirl_sim.engine.config import load_config

    config = load_config(sys.argv[1])
    warm_up()
    _worker_version()  # the version check hashes files: bookkeeping, not the cell's computation
    specs = [cell.spec() for cell in config.cells]
    before = set(sys.modules)
    files = set()

    def profile(frame, event, arg):
        if event == "call":
            files.add(frame.f_code.co_filename)

    sys.setprofile(profile)
    try:
        for spec in specs:
            run_cell(spec)
    finally:
        sys.setprofile(None)
    print(json.dumps({"files": sorted(files), "imported": sorted(set(sys.modules) - before)}))
""")


def _source_roots() -> list[Path]:
    import pirl_sim
    import pirl_sim.learners
    import pirl_sim.scenarios

    return [Path(m.__file__).resolve().parent for m in (pirl_sim, pirl_sim.learners, pirl_sim.scenarios)]


@pytest.mark.slow
def test_every_module_a_cell_runs_is_in_the_code_version(tmp_path):
    from pirl_sim.scenarios.passage import PassageConfig, generate, write_scene

    write_scene(generate(PassageConfig(n_trajectories=30, n_train=20, n_steps=20, seed=3)), tmp_path / "scene")
    cfg = tmp_path / "trace.toml"
    cfg.write_text(TRACE_CONFIG)
    script = tmp_path / "trace.py"
    script.write_text(TRACER)
    proc = subprocess.run([sys.executable, str(script), str(cfg)], capture_output=True, text=True, timeout=600,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    traced = json.loads(proc.stdout.strip().splitlines()[-1])
    from pirl_sim.experiments.registry import SCENARIOS

    assert set(SCENARIOS) <= set(re.findall(r'scenario = "([^"]+)"', TRACE_CONFIG)), "a scenario is not traced"
    extra = tuple(e for spec in SCENARIOS.values() for e in spec.code)  # scenarios' own code (agents: the envs)
    hashed = dict(source_files(extra))
    hashed_paths = {p.resolve() for p in hashed.values()}
    roots = _source_roots()
    ran = {Path(f).resolve() for f in traced["files"] if not f.startswith("<")}
    ours = {f for f in ran if any(f.is_relative_to(r) for r in roots)}
    assert len(ours) > 20, "the profiler saw the cells' code"
    name_only = {Path(importlib.util.find_spec(m).origin).resolve() for m in NAME_ONLY_CODE}
    assert ours - name_only <= hashed_paths, f"cells ran code outside CELL_CODE: {sorted(map(str, ours - hashed_paths))}"
    imported = {m for m in traced["imported"] if m.startswith("pirl_sim")} - set(NAME_ONLY_CODE)
    assert imported <= set(hashed), f"cells imported modules outside CELL_CODE: {sorted(imported - set(hashed))}"


def test_report_cli_figures_replay_template_and_envs_are_not_in_the_code_version():
    """...of the learners' cells: the envs are the agents scenario's own code, in its cells' keys only."""
    from pirl_sim.engine.config import parse_config
    from pirl_sim.engine.run import cell_keys
    from pirl_sim.experiments.registry import scenario_spec

    names = {name for name, _ in source_files()}
    for outside in ("pirl_sim.experiments.sweep_report", "pirl_sim.cli.sweep", "pirl_sim.engine.run", "pirl_sim.engine.config",
                    "pirl_sim.cli", "pirl_sim.evaluation.figures", "pirl_sim.experiments.replay_report",
                    "pirl_sim.cli.replay", "pirl_sim.experiments.reproduce", "pirl_sim.envs",
                    "pirl_sim.envs.roundabout", "pirl_sim.threads", "pirl_sim.testing",
                    *NOT_CELL_CODE):
        assert outside not in names, outside
    for inside in ("pirl_sim.evaluation.baselines", "pirl_sim.irl", "pirl_sim.receding", "pirl_sim.learners.tirl", "pirl_sim.scenarios.passage",
                   "pirl_sim.scenarios.sumo.runner", "pirl_sim.evaluation.protocols", "pirl_sim.engine.worker",
                   "pirl_sim.experiments.spec", "pirl_sim.experiments.recorded", "pirl_sim.lateral", "pirl_sim.speed_fit"):
        assert inside in names, inside
    assert code_version() == code_version()
    agents = {name for name, _ in source_files(scenario_spec("agents").code)}
    assert {"pirl_sim.envs.roundabout", "pirl_sim.envs.baselines", "pirl_sim.experiments.agents"} <= agents - names
    config = parse_config({"seeds": [0], "experiments": [
        {"scenario": "agents", "protocols": ["paper"], "learners": ["idm"]},
        {"scenario": "synthetic", "protocols": ["paper"], "learners": ["tirl"]}]})
    agents_key, synthetic_key = cell_keys(config, code_version())
    assert synthetic_key == config.cells[1].key(code_version())
    assert agents_key == config.cells[0].key(code_version(scenario_spec("agents").code)) != config.cells[0].key(
        code_version())


def test_committed_sweep_results_match_the_code(capsys):
    """Fails after a change to the cell code until ``python3 -m pirl_sim sweep --report`` is rerun and
    committed (that is the point: the committed results are made by the code)."""
    from pirl_sim.cli import main

    results = REPO / "results" / "sweep"
    assert main(["sweep", "--dry-run", "--out", str(results)]) == 0
    out = capsys.readouterr().out
    assert out.rstrip().endswith(f"0 to run (code {code_version()})"), out


def test_docstrings_comments_and_layout_do_not_change_the_code_version_and_code_does(tmp_path):
    from pirl_sim.engine.store import code_text

    base = 'def f(x):\n    """Twice x."""\n    return 2 * x  # doubled\n'
    variants = {
        "doc.py": 'def f(x):\n    """Twice x, in other words."""\n    return 2 * x\n',
        "layout.py": '"""A module."""\n\n\ndef f(x):\n    # the doubling\n    return (2 *\n            x)\n',
        "only_doc.py": 'def f(x):\n    """Twice x."""\n    return 2 * x\n',
    }
    (tmp_path / "base.py").write_text(base)
    for name, text in variants.items():
        (tmp_path / name).write_text(text)
        assert code_text(tmp_path / name) == code_text(tmp_path / "base.py"), name
    for name, text in {"const.py": base.replace("2 *", "3 *"), "name.py": base.replace("def f", "def g"),
                       "string.py": base.replace("return 2 * x", "return '2' * x")}.items():
        (tmp_path / name).write_text(text)
        assert code_text(tmp_path / name) != code_text(tmp_path / "base.py"), name
    empty = tmp_path / "empty_body.py"
    empty.write_text('class C:\n    """Only a docstring."""\n')
    assert code_text(empty) == code_text(empty)  # a body left empty gets `pass`, and still parses


def test_store_ignores_foreign_files(tmp_path):
    store = ResultStore(tmp_path)
    (tmp_path / "cells").mkdir()
    (tmp_path / "cells" / ".abc.json.123.tmp").write_text("half")
    (tmp_path / "cells" / "abc.json").write_text("[1, 2]")
    assert store.finished() == {"abc"}
    assert store.load("abc") is None and store.load("nothing") is None
