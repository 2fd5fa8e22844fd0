"""The documentation site builds with warnings as errors, covers the stable layers, and its pages' references
resolve.

The build is ``python3 -m sphinx -W --keep-going -b html docs OUT`` in a fresh process (the command of
docs/contributing.md); it needs the docs packages (sphinx, numpydoc, myst-parser, furo).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

#: top-level modules of pirl_sim with an API page (the core types and maths)
CORE = ("trajectory", "dynamics", "paths", "features", "irl", "receding", "mpc", "metrics", "population", "driving",
        "lateral", "deconvolution", "model", "recovery", "speed_fit", "joints", "simulate", "validation", "testing",
        "layers", "threads", "progress", "typecheck", "extras")
#: top-level modules of pirl_sim without one (the package's face, which re-exports core types, and ``python -m``)
CORE_UNDOCUMENTED = ("__init__", "__main__")
#: packages documented module by module: import name -> source directory
DOCUMENTED_PACKAGES = {
    "pirl_sim.io": ROOT / "pirl_sim" / "io",
    "pirl_sim.learners": ROOT / "learners",
    "pirl_sim.scenarios": ROOT / "scenarios",
    "pirl_sim.envs": ROOT / "pirl_sim" / "envs",
    "pirl_sim.viz": ROOT / "pirl_sim" / "viz",
    "pirl_sim.evaluation": ROOT / "pirl_sim" / "evaluation",
    "pirl_sim.experiments": ROOT / "pirl_sim" / "experiments",
    "pirl_sim.engine": ROOT / "pirl_sim" / "engine",
    "pirl_sim.cli": ROOT / "pirl_sim" / "cli",
}
#: packages whose ``__init__`` is empty: nothing to show on a page of its own
EMPTY_INITS = ("pirl_sim.io", "pirl_sim.scenarios")


def _api_modules() -> set[str]:
    """Modules named by an ``automodule`` directive of the API pages."""
    found = set()
    for page in (DOCS / "api").rglob("*.rst"):
        found.update(re.findall(r"^\.\. automodule:: (\S+)\s*$", page.read_text(), flags=re.MULTILINE))
    return found


def _stable_modules() -> set[str]:
    """Every module of the documented layers: CORE, and every public module of the documented packages (the
    command-line modules of the learners and scenarios, ``*cli.py``, excepted: ``pirl_sim.cli`` documents the
    command line)."""
    modules = {f"pirl_sim.{m}" for m in CORE}
    for package, directory in DOCUMENTED_PACKAGES.items():
        for path in directory.rglob("*.py"):
            parts = path.relative_to(directory).with_suffix("").parts
            if any(p.startswith("_") for p in parts[:-1]) or "__pycache__" in parts:
                continue
            name = parts[-1]
            if name.endswith("cli") or (name.startswith("_") and name != "__init__"):
                continue
            stem = parts[:-1] if name == "__init__" else parts
            if name == "__init__" and not stem and package in EMPTY_INITS:
                continue  # an empty package __init__ has nothing to show
            modules.add(".".join((package, *stem)))
    return modules


def test_every_stable_module_has_an_api_page():
    documented = _api_modules()
    missing = sorted(_stable_modules() - documented)
    assert not missing, f"modules without an API page under docs/api/: {missing}"
    unknown = sorted(m.removeprefix("pirl_sim.") for m in documented if m.count(".") == 1
                     and m.removeprefix("pirl_sim.") not in CORE and not m.startswith(tuple(DOCUMENTED_PACKAGES)))
    assert not unknown, f"API pages of modules outside the documented layers: {unknown}"


def test_new_top_level_modules_are_placed():
    """A new module directly under pirl_sim/ is either core (an API page) or listed as undocumented here."""
    top = {p.stem for p in (ROOT / "pirl_sim").glob("*.py")}
    unplaced = sorted(top - set(CORE) - set(CORE_UNDOCUMENTED))
    assert not unplaced, (f"pirl_sim/{unplaced}: add an API page (docs/api/core/) and the name to CORE, or the "
                          "name to CORE_UNDOCUMENTED")


@pytest.fixture(scope="module")
def built_site(tmp_path_factory) -> Path:
    for package in ("sphinx", "numpydoc", "myst_parser", "furo"):
        pytest.importorskip(package)
    out = tmp_path_factory.mktemp("docs_html")
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(DOCS),
                           str(out), "-d", str(out / ".doctrees")],
                          cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"the docs build failed (warnings are errors):\n{proc.stderr[-8000:]}"
    return out


@pytest.mark.slow
def test_docs_build_with_warnings_as_errors(built_site):
    assert (built_site / "index.html").is_file()
    for page in ("quickstart", "concepts/likelihoods", "api/core/pirl_sim.irl", "api/learners/pirl_sim.learners.knn",
                 "api/envs/pirl_sim.envs.roundabout"):
        assert (built_site / f"{page}.html").is_file(), page
    # the docstring conventions conf.py reads: |x| stays as written, a fitted attribute keeps its underscore
    text = (built_site / "api/core/pirl_sim.recovery.html").read_text()
    assert "|log(theta_hat / theta)|" in text
    assert "n_styles_" in (built_site / "api/learners/pirl_sim.learners.gmm.html").read_text()


@pytest.mark.slow
def test_narrative_pages_resolve_their_api_references(built_site):
    """Outside the API reference every ``{py:...}`` role must point at a documented object (Sphinx renders an
    unresolved one as plain code, without a link and without a warning)."""
    unresolved = []
    for page in built_site.rglob("*.html"):
        rel = page.relative_to(built_site).as_posix()
        if rel.startswith(("api/", "_modules/")) or rel in ("genindex.html", "py-modindex.html", "search.html"):
            continue
        for m in re.finditer(r'(<a [^>]*>)?<code class="xref py[^"]*">(.*?)</code>', page.read_text()):
            if not m.group(1):
                unresolved.append(f"{rel}: {re.sub('<[^>]+>', '', m.group(2))}")
    assert not unresolved, "references to undocumented objects:\n" + "\n".join(unresolved)
