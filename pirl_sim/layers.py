"""The package's layers and a check of its imports: ``python -m pirl_sim.layers`` prints both.

Each layer imports only itself and the layers below it; no two modules import each other, directly or
around a circle. The package root (``pirl_sim/__init__.py``) re-exports core types and registers the
gymnasium env: it is the package's face, and importing it is allowed everywhere.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

__all__ = ["LAYERS", "Violation", "module_files", "imports", "layer_of", "check", "main"]

#: bottom to top: (layer name, module prefixes)
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("core", ("pirl_sim.trajectory", "pirl_sim.dynamics", "pirl_sim.paths", "pirl_sim.features", "pirl_sim.model",
              "pirl_sim.population", "pirl_sim.driving", "pirl_sim.irl", "pirl_sim.receding", "pirl_sim.mpc",
              "pirl_sim.metrics", "pirl_sim.deconvolution", "pirl_sim.validation", "pirl_sim.recovery",
              "pirl_sim.lateral", "pirl_sim.simulate", "pirl_sim.speed_fit", "pirl_sim.joints", "pirl_sim.threads",
              "pirl_sim.progress", "pirl_sim.testing", "pirl_sim.layers", "pirl_sim.typecheck", "pirl_sim.extras",
              "pirl_sim.io")),
    ("learners", ("pirl_sim.learners",)),
    ("scenarios", ("pirl_sim.scenarios",)),
    ("viz", ("pirl_sim.viz",)),
    ("envs", ("pirl_sim.envs",)),
    ("evaluation", ("pirl_sim.evaluation",)),
    ("experiments", ("pirl_sim.experiments",)),
    ("engine", ("pirl_sim.engine",)),
    ("cli", ("pirl_sim.cli", "pirl_sim.__main__")),
)
ROOT = "pirl_sim"
#: where the source of each installed package lives, relative to the repository (setuptools ``package-dir``)
PACKAGE_DIRS = {"pirl_sim": "pirl_sim", "pirl_sim.scenarios": "scenarios", "pirl_sim.learners": "learners"}


@dataclass(frozen=True)
class Violation:
    """An import that points up the layers, or a circle of imports."""

    kind: str  # "upward" or "cycle"
    modules: tuple[str, ...]
    detail: str

    def __str__(self) -> str:
        return f"{self.kind}: {' -> '.join(self.modules)} ({self.detail})"


def module_files(repo: Path) -> dict[str, Path]:
    """{module name: source file} of every module of the package in a checkout ``repo``."""
    out: dict[str, Path] = {}
    for package, folder in PACKAGE_DIRS.items():
        root = repo / folder
        for f in sorted(root.rglob("*.py")):
            rel = f.relative_to(root).with_suffix("").parts
            if any(p in PACKAGE_DIRS.values() for p in rel[:1]) and package == "pirl_sim":
                continue  # scenarios/ and learners/ are their own packages
            parts = rel[:-1] if rel[-1] == "__init__" else rel
            name = ".".join((package, *parts))
            out[name] = f
    return out


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, node.module] if node.module else base)


def imports(name: str, path: Path, known: set[str]) -> Iterator[str]:
    """The package's modules that module ``name`` imports anywhere in its file (functions included)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(name, is_package, node)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        else:
            continue
        for target in targets:
            while target and target not in known:  # pirl_sim.a.b.func -> pirl_sim.a.b
                target = target.rpartition(".")[0]
            if target and target != name:
                yield target


def layer_of(module: str) -> int:
    """Index of ``module``'s layer in `LAYERS` (ValueError for a module no layer holds)."""
    for i, (_, prefixes) in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return i
    raise ValueError(f"module {module!r} is in no layer of pirl_sim.layers.LAYERS: add it to one")


def _cycles(graph: dict[str, set[str]]) -> list[tuple[str, ...]]:
    """One circle per strongly connected component of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[tuple[str, ...]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(tuple(sorted(comp)))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def check(repo: Path) -> tuple[dict[str, set[str]], list[Violation]]:
    """The import graph of the checkout ``repo`` (the package root left out) and what breaks the layers."""
    files = module_files(repo)
    known = set(files)
    graph: dict[str, set[str]] = {m: set() for m in files if m != ROOT}
    for name, path in files.items():
        if name == ROOT:
            continue
        graph[name] = {t for t in imports(name, path, known) if t != ROOT}
    problems = []
    for name, targets in sorted(graph.items()):
        for t in sorted(targets):
            if layer_of(t) > layer_of(name):
                problems.append(Violation("upward", (name, t), f"{LAYERS[layer_of(name)][0]} imports "
                                          f"{LAYERS[layer_of(t)][0]}"))
    problems += [Violation("cycle", c, "these modules import each other") for c in _cycles(graph)]
    return graph, problems


def main(argv: list[str] | None = None) -> int:
    """Print the layers with their modules and every violation; exit status 1 when there is one."""
    repo = Path(argv[0]) if argv else Path(__file__).resolve().parents[1]
    graph, problems = check(repo)
    for i, (layer, _) in enumerate(LAYERS):
        members = sorted(m for m in graph if layer_of(m) == i)
        print(f"{i} {layer}: {len(members)} modules")
    for p in problems:
        print(p)
    print(f"{len(problems)} violations")
    return 1 if problems else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
