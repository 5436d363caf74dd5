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


#: The controller's modules (its estimator, supervisor, phases, sliding MPC and safety filter): a
#: stricter bound on their functions, and on the state a class carries.
CONTROLLER = [*sorted((SRC / "mpc").glob("*.py")), SRC / "estimation.py", SRC / "safety.py"]
MAX_CONTROLLER_LINES = 60
MAX_ATTRIBUTES = 12


def _attributes(node: ast.ClassDef) -> set[str]:
    """The instance attributes of a class: names assigned on ``self`` anywhere in it, and its
    annotated fields (a dataclass's), ``ClassVar`` ones not counted."""
    names = set()
    for sub in ast.walk(node):
        targets = (
            sub.targets
            if isinstance(sub, ast.Assign)
            else [sub.target]
            if isinstance(sub, ast.AnnAssign)
            else []
        )
        for target in targets:
            for leaf in ast.walk(target):
                if (
                    isinstance(leaf, ast.Attribute)
                    and isinstance(leaf.value, ast.Name)
                    and leaf.value.id == "self"
                ):
                    names.add(leaf.attr)
    for item in node.body:
        if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
            if "ClassVar" not in ast.unparse(item.annotation):
                names.add(item.target.id)
    return names


def test_the_controller_modules_keep_functions_short_and_classes_small():
    long, big = [], []
    for path in CONTROLLER:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            where = f"{path.relative_to(SRC)}:{getattr(node, 'lineno', 0)}"
            if (
                isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
                and _code_lines(node) > MAX_CONTROLLER_LINES
            ):
                long.append((f"{where} {node.name}", _code_lines(node)))
            if isinstance(node, ast.ClassDef) and len(_attributes(node)) > MAX_ATTRIBUTES:
                big.append((f"{where} {node.name}", sorted(_attributes(node))))
    assert long == [], f"functions over {MAX_CONTROLLER_LINES} lines of code: {long}"
    assert big == [], f"classes with more than {MAX_ATTRIBUTES} attributes: {big}"


def test_the_attribute_count_sees_assignments_fields_and_not_class_vars():
    tree = ast.parse(
        "class A:\n    n: ClassVar[int] = 1\n    x: int = 0\n"
        "    def f(self):\n        self.a, self.b = 1, 2\n        self.c: int = 3\n        self.a += 1\n"
    )
    node = tree.body[0]
    assert isinstance(node, ast.ClassDef)
    assert _attributes(node) == {"x", "a", "b", "c"}
