"""Measures two habits of the source tree: imports of cab's own modules made inside functions, and long functions.

    python scripts/code_habits.py local-imports [PATH ...]   # default: cab_core plugins examples hydra_plugins
    python scripts/code_habits.py long-functions [--over N] [PATH ...]   # default: cab_core, N = 80

A function-local import is an ``import cab_*`` or ``from cab_* import`` statement anywhere inside a function
body (nested functions and classes included), or a relative import (``from . import``, ``from ..x import``)
there, which always names a module of the same package. Imports under ``if TYPE_CHECKING:`` at module level
are not inside a function and are not counted. A function's length is its number of source lines, from its
``def`` line (decorators excluded) to its last line. Each listing ends with a ``total`` line.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef)


def python_files(paths: list[str]) -> list[Path]:
    """The ``.py`` files under ``paths`` (files or folders, relative to the repository root), sorted."""
    files: list[Path] = []
    for name in paths:
        path = ROOT / name
        files.extend([path] if path.is_file() else sorted(path.rglob("*.py")))
    return [f for f in files if ".venv" not in f.parts and "build" not in f.parts]


def is_cab_import(node: ast.AST) -> bool:
    """Whether ``node`` imports a module of cab's own (``cab_*``) or of the importing package (relative)."""
    if isinstance(node, ast.Import):
        return any(alias.name.split(".")[0].startswith("cab_") for alias in node.names)
    if isinstance(node, ast.ImportFrom):
        return node.level > 0 or (node.module or "").split(".")[0].startswith("cab_")
    return False


def local_imports(tree: ast.Module) -> Iterator[tuple[int, str]]:
    """Line and text of each import of a cab module inside a function of ``tree``, in line order."""
    found: dict[int, str] = {}
    for func in ast.walk(tree):
        if isinstance(func, FUNCTIONS):
            for node in ast.walk(func):
                if isinstance(node, (ast.Import, ast.ImportFrom)) and is_cab_import(node):
                    found[node.lineno] = ast.unparse(node)
    yield from sorted(found.items())


def long_functions(tree: ast.Module, over: int) -> Iterator[tuple[int, str, int]]:
    """Line, qualified name and length of each function of ``tree`` longer than ``over`` lines."""

    def visit(node: ast.AST, prefix: str) -> Iterator[tuple[int, str, int]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (*FUNCTIONS, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if isinstance(child, FUNCTIONS):
                    length = (child.end_lineno or child.lineno) - child.lineno + 1
                    if length > over:
                        yield child.lineno, name, length
                yield from visit(child, name + ".")
            else:
                yield from visit(child, prefix)

    yield from visit(tree, "")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("measure", choices=["local-imports", "long-functions"])
    parser.add_argument("paths", nargs="*")
    parser.add_argument("--over", type=int, default=80, help="long-functions: the length not to exceed")
    args = parser.parse_args(argv)
    default = ["cab_core", "plugins", "examples", "hydra_plugins"] if args.measure == "local-imports" else ["cab_core"]
    total = 0
    for path in python_files(args.paths or default):
        tree = ast.parse(path.read_text(), filename=str(path))
        rel = path.relative_to(ROOT)
        if args.measure == "local-imports":
            rows = [f"  {line}: {text}" for line, text in local_imports(tree)]
        else:
            rows = [f"  {line}: {name} ({length} lines)" for line, name, length in long_functions(tree, args.over)]
        if rows:
            print(f"{rel}: {len(rows)}")
            print("\n".join(rows))
            total += len(rows)
    print(f"total: {total}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
