"""The ``pirl-sim`` command line as a whole (pirl_sim/cli/__init__.py): every subcommand reachable, a light
parser, bad input exits 2, ``--version``, and the logging of every command and of ``--verbose``."""

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

from pirl_sim.cli import COMMANDS, build_parser, main


CLI_DIR = Path(__file__).resolve().parents[2] / "pirl_sim" / "cli"
EXPECTED = {"reproduce", "simulate", "show", "sweep", "report", "recover", "replay", "fit-model", "predict",
            "realism", "calibrate", "agents", "policy-recovery", "weight-space"}
#: libraries that building the parser must not import (a command imports them when it runs)
HEAVY = ("numpy", "pandas", "scipy", "sklearn", "matplotlib", "torch", "gymnasium", "highway_env",
         "stable_baselines3", "pyarrow", "libsumo", "traci", "dask", "distributed", "tqdm")


def _subcommands(parser) -> dict:
    (action,) = [a for a in parser._actions if a.dest == "command"]
    return action.choices


def test_the_subcommands_are_the_expected_ones():
    assert set(COMMANDS) == EXPECTED
    assert set(_subcommands(build_parser())) == EXPECTED
    for name, module in COMMANDS.items():
        assert callable(module.add_parser) and callable(module.run), name


@pytest.mark.parametrize("argv", [[name] for name in sorted(EXPECTED)] + [["simulate", "sumo"],
                                                                          ["simulate", "highway"]])
def test_every_subcommand_help_exits_0(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([*argv, "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: pirl-sim {' '.join(argv)}")
    assert "--blas-threads" in out  # the global option reaches every command


def test_help_in_a_fresh_process_lists_every_subcommand():
    out = subprocess.run([sys.executable, "-m", "pirl_sim", "--help"], capture_output=True, text=True, check=True)
    for name in EXPECTED:
        assert f"    {name}" in out.stdout, name


_PROBE = """
import json, sys
import pirl_sim  # the package root (core types, env registration) comes first for every command
before = set(sys.modules)
from pirl_sim.cli import build_parser
parser = build_parser()
for argv in (["--help"], ["replay", "--help"], ["agents", "--help"]):
    try:
        parser.parse_args(argv)
    except SystemExit:
        pass
print(json.dumps(sorted(set(sys.modules) - before)))
"""


def test_building_the_parser_imports_no_heavy_module():
    proc = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True)
    new = json.loads(proc.stdout.strip().splitlines()[-1])
    assert not [m for m in new if m.split(".")[0] in HEAVY], new
    ours = [m for m in new if m.startswith("pirl_sim.")]
    assert all(m.startswith("pirl_sim.cli") or m in ("pirl_sim.threads", "pirl_sim.validation", "pirl_sim.extras")
               for m in ours), ours


def test_cli_modules_import_no_heavy_module_at_their_top():
    """The package root loads numpy already, so the probe above cannot see a module-level numpy import: the
    source can."""
    for path in sorted(CLI_DIR.glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in tree.body:
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            heavy = [n for n in names if n.split(".")[0] in HEAVY or n.startswith(
                ("pirl_sim.engine", "pirl_sim.experiments", "pirl_sim.evaluation", "pirl_sim.scenarios",
                 "pirl_sim.learners", "pirl_sim.envs", "pirl_sim.io"))]
            assert not heavy, f"{path.name} imports {heavy} at module level: import it inside run()"


def test_parallelism_is_workers_in_every_command():
    parser = build_parser()
    for name, sub in _subcommands(parser).items():
        options = {o for a in sub._actions for o in a.option_strings}
        assert "--jobs" not in options, name
    for name in ("reproduce", "sweep", "recover", "replay", "agents"):
        options = {o for a in _subcommands(parser)[name]._actions for o in a.option_strings}
        assert "--workers" in options, name


def test_names_the_parser_spells_out_agree_with_their_modules():
    from pirl_sim.cli import agents as cli_agents
    from pirl_sim.cli import policy_recovery as cli_policy
    from pirl_sim.cli import recover as cli_recover
    from pirl_sim.experiments.policy_recovery import PpoRecoveryConfig
    from pirl_sim.experiments.recovery import SIMULATORS

    assert cli_recover.SIMULATORS == SIMULATORS
    d = PpoRecoveryConfig()
    assert cli_policy.DEFAULTS == {"steps": d.steps, "seeds": d.seeds, "eval_seeds": d.eval_seeds,
                                   "n_steps": d.n_steps, "n_vehicles": d.n_vehicles,
                                   "initial_vehicles": d.initial_vehicles, **d.theta_map}
    pytest.importorskip("gymnasium")
    from pirl_sim.experiments import agents, agents_study

    assert (cli_agents.MODES, cli_agents.ACTIONS) == (agents.MODES, agents.ACTIONS)
    assert cli_agents.BASELINES == agents_study.BASELINE_POLICIES
    assert cli_agents.DEFAULT_SCALES == agents_study.DEFAULT_SCALES
    c = agents_study.AgentsConfig
    fields = {k: getattr(c, k) for k in cli_agents.DEFAULTS if hasattr(c, k)}
    assert fields == {k: v for k, v in cli_agents.DEFAULTS.items() if k in fields}
    assert (cli_agents.DEFAULTS["episodes"], cli_agents.DEFAULTS["eval_seed"]) == (len(c.eval_seeds), c.eval_seeds[0])


def test_bad_input_is_an_argparse_error_or_a_pirl_sim_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["weight-space", "--seed", "-1"])
    assert exit_info.value.code == 2
    assert "the seed must be in [0, 2**31)" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["no-such-command"])
    assert exit_info.value.code == 2
    assert "argument COMMAND: invalid choice: 'no-such-command'" in capsys.readouterr().err
    assert main(["policy-recovery", "--seeds", "1000", "--eval-seeds", "1000", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("pirl-sim: error: training seeds and evaluation seeds must differ")
    assert main(["replay", "--out", str(tmp_path)]) == 2
    assert "pirl-sim: error: replay needs --tracks and --map" in capsys.readouterr().err


def test_version_flag_prints_the_package_metadata_version(capsys):
    from importlib.metadata import version

    from pirl_sim.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"pirl-sim {version('pirl_sim')}"


def test_cli_logging_shows_library_warnings_and_leaves_no_handler(tmp_path, capsys):
    import logging

    from pirl_sim.cli import main
    from pirl_sim.engine.config import load_config
    from pirl_sim.engine.store import code_version

    from sweep_configs import TINY_LOG

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_LOG)
    out = tmp_path / "out"
    (out / "cells").mkdir(parents=True)
    key = load_config(cfg).cells[0].key(code_version())
    (out / "cells" / f"{key}.json").write_text("{not json")  # a damaged cell: the store logs a warning
    handlers = list(logging.getLogger("pirl_sim").handlers)
    assert main(["sweep", str(cfg), "--out", str(out), "--dry-run"]) == 0
    captured = capsys.readouterr()
    assert "0 already in" in captured.out  # the result, on stdout as before
    assert "ignoring unreadable result" in captured.err or "ignoring malformed result" in captured.err
    assert logging.getLogger("pirl_sim").handlers == handlers  # the command's handler is gone


def test_verbose_flag_shows_info_messages(capsys):
    import logging

    from pirl_sim.cli import cli_logging

    log = logging.getLogger("pirl_sim.test_leftovers")
    with cli_logging(verbose=False):
        log.info("quiet detail")
        log.warning("a warning")
    with cli_logging(verbose=True):
        log.info("loud detail")
    err = capsys.readouterr().err
    assert "quiet detail" not in err and "a warning" in err and "loud detail" in err


@pytest.mark.parametrize("fault, status, message", [
    (KeyboardInterrupt(), 130, "pirl-sim simulate: interrupted"),
    (OSError(28, "No space left on device", "/tmp/full/run/tracks.csv"), 2,
     "pirl-sim: error: [Errno 28] No space left on device: '/tmp/full/run/tracks.csv'"),
])
def test_ctrl_c_and_file_system_errors_end_a_command_in_one_line(monkeypatch, capsys, fault, status, message):
    from pirl_sim import cli

    def run(args):
        raise fault

    monkeypatch.setattr(cli.COMMANDS["simulate"], "run", run)
    assert cli.main(["simulate", "sumo", "--out", "x"]) == status
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_a_missing_optional_module_names_its_extra(monkeypatch, tmp_path, capsys):
    """`simulate sumo` without the sumo extra (sumolib absent: what `import sumolib` meets then) ends in one line
    that names the extra; a missing module of no extra stays an error of the code, with its traceback."""
    import sys

    from pirl_sim import cli

    monkeypatch.setitem(sys.modules, "sumolib", None)
    assert cli.main(["simulate", "sumo", "--out", str(tmp_path / "run"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "sumolib is not installed; pirl-sim simulate needs it: install the 'sumo' extra: pip install 'pirl_sim[sumo]'" in err

    def run(args):
        raise ModuleNotFoundError("No module named 'not_an_extra'", name="not_an_extra")

    monkeypatch.setattr(cli.COMMANDS["report"], "run", run)
    with pytest.raises(ModuleNotFoundError):
        cli.main(["report", str(tmp_path)])
