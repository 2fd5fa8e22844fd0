"""A static type check of the whole package with mypy: ``python -m pirl_sim.typecheck`` prints mypy's report.

The package installs ``scenarios/`` and ``learners/`` as ``pirl_sim.scenarios`` and ``pirl_sim.learners``
(setuptools ``package-dir``, `pirl_sim.layers.PACKAGE_DIRS`), a layout that mypy cannot follow from a checkout.
`check` lays the package out under its installed names, as symbolic links in ``.mypy_cache/tree/`` of the
checkout, runs mypy there with the checkout's ``pyproject.toml`` (``[tool.mypy]``) and gives the report with the
paths of the checkout. mypy's cache (``.mypy_cache/``) makes a second run fast.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

from pirl_sim.layers import PACKAGE_DIRS, ROOT

__all__ = ["tree", "check", "main"]


def tree(repo: Path, where: Path) -> Path:
    """Lay the package of the checkout ``repo`` out under its installed names in ``where`` (emptied first):
    ``where/pirl_sim`` holds links to ``repo/pirl_sim``'s entries and to each `PACKAGE_DIRS` folder."""
    if where.exists():
        shutil.rmtree(where)
    package = where / ROOT
    package.mkdir(parents=True)
    sub = {name.rpartition(".")[2]: repo / folder for name, folder in PACKAGE_DIRS.items() if name != ROOT}
    for entry in sorted((repo / PACKAGE_DIRS[ROOT]).iterdir()):
        if entry.name not in sub and entry.name != "__pycache__":
            (package / entry.name).symlink_to(entry.resolve())
    for name, folder in sub.items():
        (package / name).symlink_to(folder.resolve())
    return where


def _repo_path(line: str) -> str:
    """``line`` of mypy's report with a laid-out path (``pirl_sim/scenarios/x.py``) as the checkout's
    (``scenarios/x.py``)."""
    for name, folder in sorted(PACKAGE_DIRS.items(), key=lambda kv: -len(kv[0])):
        prefix = name.replace(".", "/") + "/"
        if line.startswith(prefix):
            return re.sub("^" + re.escape(prefix), folder + "/", line)
    return line


def check(repo: Path, args: tuple[str, ...] = ()) -> tuple[int, str]:
    """Run mypy on the package of the checkout ``repo``: (mypy's exit status, its report with the checkout's paths).

    Parameters
    ----------
    repo : path   the checkout (``pyproject.toml``, ``pirl_sim/`` and the `PACKAGE_DIRS` folders)
    args : str    more mypy options
    """
    repo = repo.resolve()
    cache = repo / ".mypy_cache"
    where = tree(repo, cache / "tree")
    cmd = [sys.executable, "-m", "mypy", "--config-file", str(repo / "pyproject.toml"), "--cache-dir", str(cache),
           *args, ROOT]
    run = subprocess.run(cmd, cwd=where, capture_output=True, text=True)
    report = "".join(_repo_path(line) for line in (run.stdout + run.stderr).splitlines(keepends=True))
    return run.returncode, report


def main(argv: list[str] | None = None) -> int:
    """Print mypy's report on the package; exit status 0 when it finds no error (``argv``: more mypy options)."""
    status, report = check(Path(__file__).resolve().parents[1], tuple(argv or ()))
    print(report, end="")
    return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
