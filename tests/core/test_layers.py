"""The package's imports point one way: `pirl_sim.layers` finds no upward import and no circle."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from pirl_sim import layers

REPO = Path(__file__).resolve().parents[2]


def test_the_package_has_no_upward_import_and_no_cycle():
    graph, problems = layers.check(REPO)
    assert len(graph) > 100, "the checker saw the package"
    assert problems == [], "\n".join(map(str, problems))


def test_every_module_is_in_a_layer_and_every_layer_is_a_folder_or_module():
    graph, _ = layers.check(REPO)
    for module in graph:
        layers.layer_of(module)  # ValueError for a module no layer holds
    files = layers.module_files(REPO)
    for _, prefixes in layers.LAYERS:
        for prefix in prefixes:
            assert prefix in files, f"{prefix} is not a module or package of the checkout"


def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    for folder in ("scenarios", "learners"):
        (root / folder).mkdir(exist_ok=True)
        (root / folder / "__init__.py").touch()
    return root


def test_an_upward_import_and_a_circle_are_found(tmp_path):
    repo = _write(tmp_path, {
        "pirl_sim/__init__.py": "",
        "pirl_sim/metrics.py": "from pirl_sim.engine import run\n",
        "pirl_sim/engine/__init__.py": "",
        "pirl_sim/engine/run.py": "def go():\n    from . import store\n",
        "pirl_sim/engine/store.py": "from .run import go\n",
    })
    _, problems = layers.check(repo)
    kinds = sorted((p.kind, p.modules) for p in problems)
    assert kinds == [("cycle", ("pirl_sim.engine.run", "pirl_sim.engine.store")),
                     ("upward", ("pirl_sim.metrics", "pirl_sim.engine.run"))]
    assert layers.main([str(repo)]) == 1


def test_a_module_in_no_layer_is_named():
    with pytest.raises(ValueError, match="pirl_sim.nowhere"):
        layers.layer_of("pirl_sim.nowhere")
