"""Benchmark helper: time the same workload on another git revision of pirl_sim, in the same run.

A speed-up quoted from two runs on a shared machine measures the load as much as the code. The benchmarks
that use this helper export the package of a named revision (``git archive``: ``pirl_sim/``, ``scenarios/``
and ``learners/``, laid out as the installed package ``pirl_sim``, ``pirl_sim.scenarios``,
``pirl_sim.learners``) into a temporary folder, and run their workload in child processes on that code and
on the working tree alternately, so that both see the same load. The child is the benchmark script itself
with a worker option; it prints one JSON line, read here.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: the baseline revision: the code without the compiled drivers and the MPC and env speed-ups
BEFORE = "45532b2"


def export_revision(rev: str, repo: Path = REPO) -> Path:
    """A folder whose ``pirl_sim`` package is revision ``rev`` of the repository (made once per revision).

    Raises
    ------
    ValueError
        When git does not know ``rev``.
    """
    check = subprocess.run(["git", "-C", str(repo), "rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}"],
                           capture_output=True, text=True)
    if check.returncode != 0:
        raise ValueError(f"unknown git revision {rev!r} in {repo}")
    sha = check.stdout.strip()
    dest = Path(tempfile.gettempdir()) / f"pirl_sim_rev_{sha[:12]}"
    if (dest / "pirl_sim" / "__init__.py").exists():
        return dest
    archive = subprocess.run(["git", "-C", str(repo), "archive", "--format=tar", sha, "pirl_sim", "scenarios",
                              "learners"], capture_output=True, check=True).stdout
    tmp = Path(tempfile.mkdtemp(prefix=f"pirl_sim_rev_{sha[:12]}_"))
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(tmp, filter="data")
    shutil.move(str(tmp / "scenarios"), str(tmp / "pirl_sim" / "scenarios"))
    shutil.move(str(tmp / "learners"), str(tmp / "pirl_sim" / "learners"))
    try:
        tmp.rename(dest)
    except OSError:  # made meanwhile by another run
        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def run_worker(script: str, args: list[str], code: Path | None = None) -> dict:
    """Run ``python script --worker args`` and return the JSON of its last output line.

    ``code``: a folder from `export_revision` whose ``pirl_sim`` the child imports (first on its path);
    None: the working tree's (the installed editable package).
    """
    env = dict(os.environ)
    if code is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(code)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    out = subprocess.run([sys.executable, script, "--worker", *args], capture_output=True, text=True, env=env)
    if out.returncode != 0:
        raise RuntimeError(f"benchmark worker {'on ' + str(code) if code else ''} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])
