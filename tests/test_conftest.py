"""The suite's conftest.py: under CI (CI=true) a missing optional extra fails instead of skipping."""

import os
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.parametrize("ci, outcome", [("true", "failed"), ("", "skipped")])
def test_under_ci_a_missing_extra_fails_instead_of_skipping(tmp_path, ci, outcome):
    (tmp_path / "conftest.py").write_text((Path(__file__).parent / "conftest.py").read_text())
    (tmp_path / "test_extra.py").write_text(
        "import pytest\n"
        "pytest.importorskip('pirl_sim_no_such_extra')\n\n"
        "def test_something():\n    pass\n")
    env = {**os.environ, "CI": ci}
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
                         capture_output=True, text=True, cwd=tmp_path, env=env)
    summary = out.stdout.strip().splitlines()[-1]
    if outcome == "failed":
        assert out.returncode != 0 and "skipped" not in summary, out.stdout
        assert "pirl_sim_no_such_extra" in out.stdout
    else:
        assert out.returncode in (0, 5) and "1 skipped" in summary, out.stdout  # 5: no test ran
