"""Every notebook in notebooks/ runs top to bottom without error (examples are tests).

A notebook whose metadata has ``{"capsule_mpc": {"slow": true}}`` is marked ``slow``
(run by ``make test-slow``). Notebooks execute in their own folder, as in Jupyter.
"""

from __future__ import annotations

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
