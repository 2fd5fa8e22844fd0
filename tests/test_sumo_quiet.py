"""Importing libsumo through the runner prints nothing (issue 15 item 15) and leaves traci the socket client."""

import subprocess
import sys

import pytest

pytest.importorskip("libsumo")


def test_simulate_sumo_prints_no_pyarrow_warning(tmp_path):
    code = ("import sys, traci; from pirl_sim.cli import main; "
            f"rc = main(['simulate', 'sumo', '--n-vehicles', '2', '--quiet', '--out', {str(tmp_path / 'run')!r}]); "
            "import os; assert 'LIBSUMO_AS_TRACI' not in os.environ; assert hasattr(traci, 'connect'); sys.exit(rc)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "pyarrow" not in out.stdout and "pyarrow" not in out.stderr
