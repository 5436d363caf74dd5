"""The package's layers, read from its imports: lower layers never import higher ones, no module
imports itself back through others, and imports inside functions load only heavy dependencies.

The layers, bottom to top (a module may import its own layer and those below):

0. errors, atomic, interrupt, cache, plan_options -- no package imports but each other;
1. config -- the scenario and its validation;
2. budget, friction, magnetics, paths, safety, estimation, metrics, outputs, overwrite, previous_run
   -- physics and tools (the outputs' rules: no overwritten input, the previous run kept);
3. dynamics, steady, path_reach, interfaces -- the model and the loop's interfaces;
4. baselines, planner -- controllers that plan offline or not at all;
5. mpc -- the receding-horizon controller (uses the planner's plan as feed-forward);
6. sim, arm -- the simulated rig and the robot arm (the arm never imports the simulator);
7. learning, plots, envs, experiments, telemetry, nodes -- what runs the rig (in process, as
   Gymnasium environments or as nodes) and draws, learns from or logs it;
8. cli -- the command line.
"""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

import capsule_mpc

ROOT = Path(capsule_mpc.__file__).parent
#: The repository: its benchmark scripts and notebooks use the library and the experiments, never
#: the command line's modules.
REPO = Path(__file__).resolve().parents[1]
LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors", "atomic", "interrupt", "cache", "plan_options"),
    ("config",),
    (
        "budget",
        "friction",
        "magnetics",
        "paths",
        "safety",
        "estimation",
        "metrics",
        "outputs",
        "overwrite",
        "previous_run",
    ),
    ("dynamics", "steady", "path_reach", "interfaces"),
    ("baselines", "planner"),
    ("mpc",),
    ("sim", "arm"),
    ("learning", "plots", "envs", "experiments", "telemetry", "nodes"),
    ("cli",),
)
LAYER_OF = {part: i for i, parts in enumerate(LAYERS) for part in parts}
#: Third-party modules heavy enough to load only when used (inside the function that uses them).
HEAVY = ("matplotlib", "scipy.spatial", "distributed", "dask")
#: Package modules that load a heavy dependency (the arm loads Pinocchio; so does the telemetry's
#: view of the arm).
HEAVY_OWN = ("capsule_mpc.arm", "capsule_mpc.telemetry.robot")


def _modules() -> dict[str, Path]:
    out = {}
    for path in ROOT.rglob("*.py"):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _package_of(name: str, path: Path) -> str:
    return name if path.name == "__init__.py" else name.rsplit(".", 1)[0]


def _imports(name: str, path: Path) -> list[tuple[str, bool, int]]:
    """(imported module, inside a function, line) for every runtime import of ``name``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    typing_only = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            typing_only |= {id(n) for n in ast.walk(node)}
    top = {id(n) for n in tree.body}
    pkg = _package_of(name, path)
    found = []
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        inner = id(node) not in top
        if isinstance(node, ast.Import):
            found += [(alias.name, inner, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append((target, inner, node.lineno))
            found += [
                (f"{target}.{alias.name}", inner, node.lineno)
                for alias in node.names
                if f"{target}.{alias.name}" in MODULES
            ]
    return found


def _own(target: str) -> str | None:
    """The package module ``target`` names (or its closest package), None if not ours."""
    if target != "capsule_mpc" and not target.startswith("capsule_mpc."):
        return None
    while target not in MODULES and "." in target:
        target = target.rsplit(".", 1)[0]
    return target


def _layer(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1:
        return LAYER_OF["config"]  # the package itself exports the config API
    return LAYER_OF[parts[1]]


GRAPH = {
    name: {own for target, _inner, _line in _imports(name, path) if (own := _own(target)) and own != name}
    for name, path in MODULES.items()
}


def test_every_module_has_a_layer():
    missing = sorted({name.split(".")[1] for name in MODULES if "." in name} - set(LAYER_OF))
    assert missing == []


def test_no_module_imports_a_higher_layer():
    upward = [
        f"{name} -> {dep}" for name, deps in GRAPH.items() for dep in deps if _layer(dep) > _layer(name)
    ]
    assert upward == []


def test_no_import_cycles():
    # Tarjan's strongly connected components over the module graph (runtime imports, including
    # those inside functions): a component of more than one module is a cycle.
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    assert cycles == []


@pytest.mark.parametrize("name", sorted(n for n in MODULES if not n.startswith("capsule_mpc.cli")))
def test_library_imports_inside_functions_load_only_heavy_dependencies(name):
    # The command line may defer any import (``capsule-mpc --help`` starts without CasADi); the
    # library imports at the top but for heavy dependencies loaded when first used.
    inner = [
        f"line {line}: {target}"
        for target, is_inner, line in _imports(name, MODULES[name])
        if is_inner and not target.startswith(HEAVY + HEAVY_OWN)
    ]
    assert inner == []


def test_the_graph_is_read_from_the_imports():
    # the reader sees known edges, including one inside a function
    assert "capsule_mpc.config" in GRAPH["capsule_mpc.interfaces"]
    assert "capsule_mpc.safety" in GRAPH["capsule_mpc.mpc.controller"]
    assert "capsule_mpc.arm" in GRAPH["capsule_mpc.sim.loop"]
    assert not any(dep.startswith("capsule_mpc.sim") for dep in GRAPH["capsule_mpc.arm.export"])


def _cli_imports(source: str) -> list[str]:
    """The imports of ``capsule_mpc.cli`` (or a module in it) in Python ``source``, with their lines."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            names = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
        else:
            continue
        found += [
            f"line {node.lineno}: {n}"
            for n in names
            if n == "capsule_mpc.cli" or n.startswith("capsule_mpc.cli.")
        ]
    return found


def _scripts() -> dict[str, str]:
    """The source of every script in benchmarks/ and the code cells of every notebook, by file."""
    out = {p.name: p.read_text(encoding="utf-8") for p in sorted((REPO / "benchmarks").glob("*.py"))}
    for notebook in sorted((REPO / "notebooks").glob("*.ipynb")):
        cells = json.loads(notebook.read_text(encoding="utf-8"))["cells"]
        out[notebook.name] = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
    return out


def test_benchmarks_and_notebooks_do_not_import_the_command_line():
    scripts = _scripts()
    assert "mpc_bench.py" in scripts and "05_mpc.ipynb" in scripts  # both folders are read
    found = {name: lines for name, source in scripts.items() if (lines := _cli_imports(source))}
    assert found == {}


def test_the_command_line_imports_are_found():
    source = (
        "import capsule_mpc.cli\nfrom capsule_mpc.cli.bench import run\nfrom capsule_mpc import cli, sim\n"
    )
    assert _cli_imports(source) == [
        "line 1: capsule_mpc.cli",
        "line 2: capsule_mpc.cli.bench",
        "line 2: capsule_mpc.cli.bench.run",
        "line 3: capsule_mpc.cli",
    ]
    assert _cli_imports("from capsule_mpc.experiments.bench import run_benchmark\n") == []
