"""The static type check (`pirl_sim.typecheck`): the package under its installed names passes mypy."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import pytest

from pirl_sim import layers, typecheck

REPO = Path(__file__).resolve().parents[2]

pytest.importorskip("mypy")


def test_the_layout_links_the_package_folders_under_their_installed_names(tmp_path):
    where = typecheck.tree(REPO, tmp_path / "tree")
    package = where / "pirl_sim"
    assert (package / "scenarios" / "__init__.py").resolve() == REPO / "scenarios" / "__init__.py"
    assert (package / "learners" / "__init__.py").resolve() == REPO / "learners" / "__init__.py"
    assert (package / "layers.py").resolve() == REPO / "pirl_sim" / "layers.py"
    laid_out = [f for _, _, names in os.walk(package, followlinks=True) for f in names if f.endswith(".py")]
    assert len(laid_out) == len(layers.module_files(REPO))


def test_a_type_error_is_reported_with_the_checkouts_path(tmp_path):
    files = {
        "pyproject.toml": '[tool.mypy]\npython_version = "3.11"\n',
        "pirl_sim/__init__.py": "",
        "pirl_sim/core.py": "def half(x: float) -> float:\n    return x / 2\n",
        "scenarios/__init__.py": "",
        "scenarios/bad.py": """\
            from pirl_sim.core import half
            from pirl_sim.learners.fine import ok

            y: int = half(ok)
        """,
        "learners/__init__.py": "",
        "learners/fine.py": "ok = 1.0\n",
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(textwrap.dedent(text))
    status, report = typecheck.check(tmp_path)
    assert status == 1, report
    assert report.startswith("scenarios/bad.py:4: error: Incompatible types in assignment"), report
    assert "Found 1 error in 1 file (checked 6 source files)" in report


@pytest.mark.slow
def test_the_whole_package_passes_the_type_check():
    status, report = typecheck.check(REPO)
    assert status == 0, report
    assert f"no issues found in {len(layers.module_files(REPO))} source files" in report, report
