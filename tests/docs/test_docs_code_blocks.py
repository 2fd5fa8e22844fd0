"""Every code block marked runnable in the docs pages and in README.md runs.

The marker is the fence's info string ``python runnable`` (it renders as a plain Python block, on GitHub and in
Sphinx/MyST)::

    ```python runnable
    from pirl_sim.trajectory import Trajectory
    ```

The runnable blocks of one page run in order, in one namespace, in a fresh temporary working directory (a block
may use what an earlier block of its page defined, and may write files). A block that needs a missing optional
extra skips the page (``pytest.importorskip``; under ``CI=true`` that fails, see tests/conftest.py). Blocks
marked plain ``python`` are never run.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: modules of optional extras: a page whose block needs a missing one is skipped, not failed
OPTIONAL = {"gymnasium", "highway_env", "libsumo", "traci", "sumolib", "numba", "lanelet2", "dask", "torch",
            "stable_baselines3", "pygame"}
_FENCE = re.compile(r"^(?P<indent> {0,3})(?P<fence>`{3,}|~{3,})(?P<info>.*)$")


@dataclass(frozen=True)
class Block:
    path: Path
    line: int  # 1-based line of the block's first code line
    code: str


def runnable_blocks(path: Path) -> list[Block]:
    """The ``python runnable`` fenced blocks of a Markdown file, in order (nested fences respected: a longer
    fence containing a marked example is one block of its own kind, not a runnable one)."""
    blocks, lines = [], path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m or (m["fence"][0] == "`" and "`" in m["info"]):
            i += 1
            continue
        fence, indent, info = m["fence"], len(m["indent"]), m["info"].split()
        body, j = [], i + 1
        while j < len(lines):
            close = _FENCE.match(lines[j])
            if close and close["fence"][0] == fence[0] and len(close["fence"]) >= len(fence) \
                    and not close["info"].strip():
                break
            body.append(lines[j] if not indent else lines[j][indent:] if lines[j][:indent].isspace()
                        else lines[j].lstrip())
            j += 1
        if info[:1] == ["python"] and "runnable" in info[1:]:
            blocks.append(Block(path, i + 2, "\n".join(body) + "\n"))
        i = j + 1
    return blocks


def pages() -> list[Path]:
    return sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]


PAGES_WITH_BLOCKS = [p for p in pages() if p.is_file() and runnable_blocks(p)]


def test_the_marker_is_found():
    """The collector sees the docs' runnable blocks (guards the parser: a test over nothing passes silently)."""
    found = [b for p in PAGES_WITH_BLOCKS for b in runnable_blocks(p)]
    assert len(found) >= 3, [f"{b.path.relative_to(ROOT)}:{b.line}" for b in found]
    example = ROOT / "docs" / "contributing.md"
    assert not runnable_blocks(example), "the marker shown inside a longer fence must not run"


@pytest.mark.parametrize("page", PAGES_WITH_BLOCKS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_runnable_blocks(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    namespace = {"__name__": "__main__"}
    for block in runnable_blocks(page):
        where = f"{page.relative_to(ROOT)}:{block.line}"
        try:
            exec(compile(block.code, where, "exec"), namespace)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.split(".")[0] in OPTIONAL:
                pytest.importorskip(exc.name, reason=f"{where} needs the optional module {exc.name}")
            raise
