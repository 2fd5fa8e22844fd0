"""Code lines of Python files: lines that hold code, not blank lines, comments or docstrings.

    python benchmarks/code_lines.py PATH [PATH ...] [--revision REV]

A line counts when a token other than a comment, a newline or an indentation change touches it, and it is not
part of a module, class or function docstring; so reformatting a docstring or a comment changes nothing, and a
statement split over three lines counts three. Folders are searched for ``*.py`` recursively. Prints one row per
file (largest first) and the total. ``--revision REV`` counts the same paths in a git revision instead (its files
as ``git archive`` gives them, in a temporary folder). The top layer's size: ``python benchmarks/code_lines.py pirl_sim/cli
pirl_sim/engine pirl_sim/experiments pirl_sim/evaluation``.
"""

from __future__ import annotations

import argparse
import ast
import io
import subprocess
import sys
import tarfile
import tempfile
import tokenize
from pathlib import Path

_NOT_CODE = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
             tokenize.ENDMARKER}


def code_lines(source: str) -> int:
    """Lines of ``source`` that hold code (module doc)."""
    docs: set[int] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                docs.update(range(first.lineno, (first.end_lineno or first.lineno) + 1))
    lines = {n for tok in tokenize.generate_tokens(io.StringIO(source).readline) if tok.type not in _NOT_CODE
             for n in range(tok.start[0], tok.end[0] + 1)}
    return len(lines - docs)


def count(paths: list[Path], root: Path) -> list[tuple[int, str]]:
    """(code lines, path relative to ``root``) of every ``*.py`` file under ``paths``, largest first."""
    rows = []
    for p in paths:
        files = sorted(p.rglob("*.py")) if p.is_dir() else [p]
        if not files or not p.exists():
            raise SystemExit(f"code_lines: no Python file at {p}")
        rows += [(code_lines(f.read_text(encoding="utf-8")), str(f.relative_to(root))) for f in files]
    return sorted(rows, reverse=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+", help="files or folders, relative to the repository root")
    parser.add_argument("--revision", help="count a git revision's files instead of the working tree's")
    args = parser.parse_args(argv)
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory(prefix="code_lines_") as tmp:
        if args.revision:
            archive = subprocess.run(["git", "-C", str(root), "archive", "--format=tar", args.revision],
                                     capture_output=True)
            if archive.returncode != 0:
                raise SystemExit(f"code_lines: git cannot export {args.revision!r}: {archive.stderr.decode().strip()}")
            with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
                tar.extractall(tmp, filter="data")
            root = Path(tmp)
        rows = count([root / p for p in args.paths], root)
    for n, name in rows:
        print(f"{n:6d} {name}")
    print(f"{sum(n for n, _ in rows):6d} total")
    return 0


if __name__ == "__main__":
    sys.exit(main())
