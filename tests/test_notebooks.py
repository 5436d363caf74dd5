"""Every notebook in notebooks/ runs top to bottom without error (examples are tests).

A notebook whose metadata has ``{"capsule_mpc": {"slow": true}}`` is marked ``slow``
(run by ``make test-slow``). Notebooks execute in their own folder, as in Jupyter. Every
notebook, slow or not, is also checked in the default suite without running it: a valid
notebook whose code cells are valid Python and whose ``capsule_mpc`` imports all exist.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import json
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
#: Per-cell timeout, s.
CELL_TIMEOUT_S = 600


def _params() -> list:
    params = []
    for nb_path in sorted(NOTEBOOKS.glob("*.ipynb")):
        meta = json.loads(nb_path.read_text()).get("metadata", {}).get("capsule_mpc", {})
        marks = [pytest.mark.slow] if meta.get("slow") else []
        params.append(pytest.param(nb_path, id=nb_path.name, marks=marks))
    return params


@pytest.mark.parametrize("nb_path", _params())
def test_notebook_runs(nb_path: Path) -> None:
    nb = nbformat.read(nb_path, as_version=4)
    client = NotebookClient(
        nb,
        timeout=CELL_TIMEOUT_S,
        kernel_name="python3",
        resources={"metadata": {"path": str(nb_path.parent)}},
    )
    client.execute()
    errors = [
        o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"
    ]
    assert not errors


def _imported(tree: ast.AST) -> list[tuple[str, str | None]]:
    """The (module, name) pairs a cell imports from ``capsule_mpc`` (name None: the module itself)."""
    found: list[tuple[str, str | None]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "capsule_mpc":
            found += [(node.module, alias.name) for alias in node.names]
        elif isinstance(node, ast.Import):
            found += [(alias.name, None) for alias in node.names if alias.name.split(".")[0] == "capsule_mpc"]
    return found


@pytest.mark.parametrize("nb_path", sorted(NOTEBOOKS.glob("*.ipynb")), ids=lambda p: p.name)
def test_notebook_is_valid_and_its_capsule_mpc_imports_exist(nb_path: Path) -> None:
    nb = nbformat.read(nb_path, as_version=4)
    nbformat.validate(nb)
    imports = []
    for k, cell in enumerate(c for c in nb.cells if c.cell_type == "code"):
        imports += _imported(ast.parse(cell.source, filename=f"{nb_path.name}, code cell {k + 1}"))
    assert imports  # every notebook uses the package
    for module_name, name in imports:
        module = importlib.import_module(module_name)
        if name is not None:  # a name the module defines, or a submodule of it
            assert hasattr(module, name) or importlib.util.find_spec(f"{module_name}.{name}"), (
                f"{nb_path.name}: from {module_name} import {name}"
            )
