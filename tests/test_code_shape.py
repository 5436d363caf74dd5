"""The package's functions stay short enough to read in one screen: at most 80 lines of code
(the docstring not counted) in every function and method under ``src/capsule_mpc``."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "capsule_mpc"
MAX_LINES = 80


def _code_lines(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines of ``node`` without its docstring."""
    first = node.body[0]
    is_doc = isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
    doc = first.end_lineno - first.lineno + 1 if is_doc and isinstance(first.value.value, str) else 0  # type: ignore[attr-defined,operator]
    return node.end_lineno - node.lineno + 1 - doc  # type: ignore[operator]


def _functions() -> list[tuple[str, int]]:
    found = []
    for path in sorted(SRC.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                found.append((f"{path.relative_to(SRC)}:{node.lineno} {node.name}", _code_lines(node)))
    return found


def test_the_scan_finds_the_package_functions():
    names = {name.split()[-1] for name, _ in _functions()}
    assert {"simulate", "build_ocp", "smooth_waypoints", "main"} <= names


def test_no_function_is_longer_than_80_lines_of_code():
    long = sorted(((n, lines) for n, lines in _functions() if lines > MAX_LINES), key=lambda item: -item[1])
    assert long == [], f"functions over {MAX_LINES} lines of code: {long}"
