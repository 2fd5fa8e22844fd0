"""The thread policy of single-process commands (pirl_sim/threads.py): one BLAS thread unless told otherwise."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from pirl_sim.cli import build_parser, main
from pirl_sim.threads import (
    DEFAULT_THREADS,
    ENV_VAR,
    blas_threads,
    current_blas_threads,
    parse_blas_threads,
    resolve_blas_threads,
)


def test_parse_values():
    assert parse_blas_threads("1") == 1
    assert parse_blas_threads(" 3 ") == 3
    assert parse_blas_threads(2) == 2
    assert parse_blas_threads("auto") is None
    assert parse_blas_threads("AUTO") is None


@pytest.mark.parametrize("bad", ["0", "-2", "two", "", "1.5", 0, True, 1.0])
def test_bad_values_are_named(bad):
    with pytest.raises(ValueError, match=f"{ENV_VAR} must be a positive integer or 'auto'"):
        parse_blas_threads(bad)


def test_resolution_order():
    assert resolve_blas_threads(None, environ={}) == DEFAULT_THREADS == 1
    assert resolve_blas_threads(None, environ={ENV_VAR: "4"}) == 4
    assert resolve_blas_threads(None, environ={ENV_VAR: "auto"}) is None
    assert resolve_blas_threads("2", environ={ENV_VAR: "4"}) == 2  # the option wins
    assert resolve_blas_threads("auto", environ={ENV_VAR: "4"}) is None
    with pytest.raises(ValueError, match="--blas-threads must be a positive integer"):
        resolve_blas_threads("none", environ={})


def test_option_before_or_after_the_command():
    parser = build_parser()
    assert parser.parse_args(["--blas-threads", "2", "reproduce", "synthetic"]).blas_threads == "2"
    assert parser.parse_args(["reproduce", "synthetic", "--blas-threads", "auto"]).blas_threads == "auto"
    assert parser.parse_args(["simulate", "sumo", "--blas-threads", "3"]).blas_threads == "3"
    assert not hasattr(parser.parse_args(["reproduce", "synthetic"]), "blas_threads")
    with pytest.raises(SystemExit):
        parser.parse_args(["replay", "--blas-threads", "0"])


def test_bad_environment_value_stops_the_command_before_work(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv(ENV_VAR, "many")
    out = tmp_path / "never"
    assert main(["reproduce", "synthetic", "--out", str(out)]) == 2
    assert f"{ENV_VAR} must be a positive integer or 'auto', got 'many'" in capsys.readouterr().err
    assert not out.exists()


def test_context_manager_limits_and_restores():
    import scipy.linalg  # noqa: F401  (the runtimes the policy limits are loaded)
    import sklearn.utils  # noqa: F401

    before = current_blas_threads()
    with blas_threads(1):
        assert current_blas_threads()["openblas"] == 1
    assert current_blas_threads() == before
    with pytest.raises(ValueError, match="n must be a positive integer"):
        with blas_threads(0):
            pass


def test_main_restores_the_calling_process(tmp_path, monkeypatch):
    """pirl_sim.cli.main called from Python limits threads while the command runs and restores them after."""
    import scipy.linalg  # noqa: F401
    import sklearn.utils  # noqa: F401

    from pirl_sim import cli

    before, env_before = current_blas_threads(), os.environ.get("OPENBLAS_NUM_THREADS")
    seen = {}

    def spy(args):
        seen["threads"], seen["env"] = current_blas_threads(), os.environ.get("OPENBLAS_NUM_THREADS")
        return 0

    monkeypatch.setattr(cli.COMMANDS["reproduce"], "run", spy)
    assert main(["reproduce", "synthetic", "--out", str(tmp_path / "x")]) == 0
    assert set(seen["threads"].values()) == {1} and seen["env"] == "1"
    assert current_blas_threads() == before and os.environ.get("OPENBLAS_NUM_THREADS") == env_before


_PROBE = """
import json, os, sys
from pirl_sim.threads import apply_thread_policy, current_blas_threads
n = apply_thread_policy(sys.argv[1] if len(sys.argv) > 1 else None)
import sklearn.utils  # its OpenMP runtime loads after the policy: it reads the variables the policy set
print(json.dumps({"n": n, "threads": current_blas_threads(), "env": os.environ.get("OPENBLAS_NUM_THREADS")}))
"""


def _probe(*args: str, env_value: str | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in (ENV_VAR, "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    if env_value is not None:
        env[ENV_VAR] = env_value
    out = subprocess.run([sys.executable, "-c", _PROBE, *args], check=True, capture_output=True, text=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_policy_in_a_fresh_process():
    """Default: every loaded BLAS/OpenMP runtime at 1 thread (also one loaded after the policy), and the variables
    set for child processes;
    'auto' leaves both alone; the environment variable is read when no option is given."""
    default = _probe()
    assert default["n"] == 1 and set(default["threads"].values()) == {1} and default["env"] == "1"
    auto = _probe("auto")
    assert auto["n"] is None and auto["env"] is None
    assert _probe(env_value="2")["threads"]["openblas"] == 2
