"""The run table of a campaign: one row per plant draw, variant and controller (tidy data).

A row holds the draw's ``seed``, the ``variant`` (the scenario overrides the controller was run
with; :data:`NOMINAL` for the scenario as given) and the ``controller``; every entry of the run's
metrics as ``run.json`` records them, whatever they are (a metric added to the runner appears as a
column with no change here); ``window_end_s`` (the draw's common scoring window); ``error`` (the
line of a run whose controller raised, else empty); the draw's plant values as ``plant.FIELD``,
the ``--vary`` values as ``varied.FIELD`` and whatever else was recorded about the draw. Nested
entries are flattened with dotted names; lists are kept as JSON text. The table is written as CSV
(``runs.csv``), read back with the same columns and types (true/false flags as booleans, a
missing value as NaN, an empty text as one).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..atomic import write_text_atomic

__all__ = [
    "KEYS",
    "NOMINAL",
    "TABLE_FILE",
    "entry_rows",
    "flatten",
    "read_table",
    "run_label",
    "split_label",
    "table_from_entries",
    "write_table",
]

#: File name of a campaign's run table.
TABLE_FILE = "runs.csv"
#: The variant of the scenario as given (no overrides).
NOMINAL = "nominal"
#: The columns that say which run a row is.
KEYS = ("seed", "variant", "controller")
#: A missing value in the CSV (an empty cell is an empty text).
_NAN = "NaN"
#: Entries of a run kept out of the table (long text; the JSON keeps them).
_LEFT_OUT = frozenset({"traceback"})


def run_label(variant: str, controller: str) -> str:
    """The name of a run in a draw's entry: the controller, ``VARIANT:CONTROLLER`` in a variant."""
    return controller if variant == NOMINAL else f"{variant}:{controller}"


def split_label(label: str) -> tuple[str, str]:
    """``(variant, controller)`` of a :func:`run_label`."""
    variant, sep, controller = label.rpartition(":")
    return (variant, controller) if sep else (NOMINAL, label)


def flatten(value: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``value`` with nested mappings as dotted keys, lists as JSON text and None as NaN."""
    out: dict[str, Any] = {}
    for key, item in value.items():
        name = f"{prefix}{key}"
        if isinstance(item, Mapping):
            out.update(flatten(item, name + "."))
        elif isinstance(item, (list, tuple)):
            out[name] = json.dumps(item)
        else:
            out[name] = math.nan if item is None else item
    return out


def entry_rows(entry: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The rows of one draw's entry (a sweep's ``runs/seed_<S>.json``, a comparison's ``runs``):
    ``{"seed", "window_end_s", "controllers": {label: metrics, or {"error"}}}``; the entry's other
    mappings (``plant``, ``varied``, ``learning``) are the draw's columns, ``KEY.FIELD``."""
    draw = flatten({"seed": entry.get("seed"), "window_end_s": entry.get("window_end_s")})
    draw.update(flatten({k: v for k, v in entry.items() if isinstance(v, Mapping) and k != "controllers"}))
    draw.pop("plant.seed", None)
    rows = []
    for label, run in entry["controllers"].items():
        variant, controller = split_label(label)
        metrics = {k: v for k, v in run.items() if k not in _LEFT_OUT}
        metrics.setdefault("error", "")
        rows.append({**dict(zip(KEYS, (draw["seed"], variant, controller))), **draw, **flatten(metrics)})
    return rows


def table_from_entries(entries: Iterable[Mapping[str, Any]]) -> pd.DataFrame:
    """The run table of draws' entries (:func:`entry_rows`), rows in the order given."""
    rows = [row for entry in entries for row in entry_rows(entry)]
    columns = list(dict.fromkeys(key for row in rows for key in row)) or [*KEYS, "error"]
    return _typed(pd.DataFrame(rows, columns=columns))


def _typed(table: pd.DataFrame) -> pd.DataFrame:
    """Flags as booleans where every value is one (NaN in a row of a failed run stays NaN)."""
    for column in table.columns:
        values = table[column].dropna()
        if len(values) and values.map(lambda v: isinstance(v, (bool, np.bool_))).all():
            table[column] = table[column].astype("boolean")
    if "error" in table:
        table["error"] = ["" if pd.isna(e) else str(e) for e in table["error"]]
    return table


def write_table(table: pd.DataFrame, path: str | Path) -> Path:
    """Write ``table`` as CSV (atomically); the path."""
    path = Path(path)
    write_text_atomic(path, table.to_csv(index=False, na_rep=_NAN))
    return path


def read_table(path: str | Path) -> pd.DataFrame:
    """A run table written by :func:`write_table`, with its flags as booleans."""
    table = pd.read_csv(
        path, keep_default_na=False, na_values=[_NAN], dtype={"variant": str, "controller": str}
    )
    return _typed(table)
