"""Run logs: one CSV row per camera frame, written atomically, and read back with validation.

A run directory holds ``log.csv`` (the columns below), ``config.yaml`` (the
scenario actually used, from :func:`capsule_mpc.dump_config`) and ``run.json``
(seed, controller, path, metrics, failure flags, limit counts, timing, real-time
pacing). A controller that predicts (the MPC) also leaves ``predictions.npz``:
``t_s`` (F,) the frame times and ``capsule_xy_m`` (F, N, 2) the capsule path it
predicted at each frame (NaN where it predicted nothing). Every file is written
to a temporary name and renamed into place, so an interrupted run leaves no half
file.

Two columns are wall-clock timings (``solve_ms``, ``controller_ms``); every other
column is a deterministic function of the scenario, controller and seed.

Columns (true states are sampled at the frame time; the EPM "z" is its height
above the capsule plane, i.e. the vertical EPM-IPM centre distance; the capsule
z is 0, the plane itself):

========================  =====================================================
``t_s``                   frame time, s (negative during the settle phase)
``epm_{x,y,z}_m``         EPM position, m
``epm_v{x,y,z}_mps``      EPM velocity, m/s
``capsule_{x,y,z}_m``     true capsule position, m
``capsule_v{x,y}_mps``    true capsule velocity, m/s
``meas_{x,y}_m``          measurement delivered at this frame, m (NaN: dropped / none yet)
``meas_capture_t_s``      when that measurement was captured, s (NaN: none yet)
``ref_{x,y}_m``           reference position at ``t_s``, m
``cmd_v{x,y,z}_mps``      EPM velocity command applied from this frame on, m/s
``force_{x,y}_n``         true lateral magnetic force on the capsule (at the last plant step), N
``force_att_n``           true attraction toward the EPM (at the last plant step), N
``normal_force_n``        true normal force F_N (at the last plant step), N
``plant_mu``              the plant's rate-and-state mu at the last step (NaN while stuck)
``stuck``                 1 if the capsule is at rest (static friction), else 0
``progress_m``            the capsule's arc-length progress along the path, m
``solve_ms``              the controller's reported solve time, ms (NaN if none)
``solver_status``         the controller's status text
``solver_failed``         1 if the controller reported a failed solve, else 0
``controller_ms``         wall time of the controller's step call, ms
``phase``                 the controller's phase at the frame (``settle``, ``break_loose``,
                          ``slide``, ``place``, ``hold``, ``failed``; the baselines: ``slide``
                          while the path runs, ``hold`` after; empty: none, or the frame the
                          plant failed on)
========================  =====================================================
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path, json_ready, write_text_atomic
from ..config import dump_config
from ..metrics import stack_predictions
from .columns import INT_COLUMNS, LOG_COLUMNS, REQUIRED_COLUMNS, STR_COLUMNS
from .runner import RunResult

__all__ = [
    "INT_COLUMNS",
    "LOG_COLUMNS",
    "PREDICTIONS_FILE",
    "REQUIRED_COLUMNS",
    "STR_COLUMNS",
    "read_log",
    "read_predictions",
    "write_log",
    "write_run",
]

#: File of a run's per-frame predicted capsule paths (only for controllers that predict).
PREDICTIONS_FILE = "predictions.npz"


def _cell(value: Any) -> str:
    if isinstance(value, (float, np.floating)):
        return repr(float(value))  # shortest text that reads back to the same float
    return str(value)


def write_log(log: Mapping[str, np.ndarray], path: str | Path) -> None:
    """Write a run log (column name -> array, one entry per frame) as CSV, atomically.

    Columns are written in :data:`LOG_COLUMNS` order, then any extra ones.
    """
    missing = [c for c in REQUIRED_COLUMNS if c not in log]
    if missing:
        raise ValueError(f"log: missing columns {missing}")
    names = [c for c in LOG_COLUMNS if c in log] + [c for c in log if c not in LOG_COLUMNS]
    n = len(log["t_s"])
    for name in names:
        if len(log[name]) != n:
            raise ValueError(f"log column {name!r}: {len(log[name])} rows, expected {n}")
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(names)
    cols = [log[name].tolist() for name in names]
    for row in zip(*cols):
        writer.writerow([_cell(v) for v in row])
    write_text_atomic(Path(path), buf.getvalue())


def read_log(path: str | Path) -> dict[str, np.ndarray]:
    """Read a run log written by :func:`write_log`.

    Returns
    -------
    dict of str to numpy.ndarray
        One array per column: float for measurements, int for ``stuck`` / ``solver_failed``, str for
        ``solver_status`` and ``phase`` (and for any extra column that is not numeric).

    Raises
    ------
    ValueError
        If a required column is missing, a row has the wrong number of cells, or a numeric cell is
        not a number (the message names the line and column).
    """
    path = Path(path)
    with path.open(encoding="utf-8", newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ValueError(f"{path}: empty log (no header)")
    header = rows[0]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: missing required columns {missing}")
    body = rows[1:]
    for line, row in enumerate(body, start=2):
        if len(row) != len(header):
            raise ValueError(f"{path}: line {line}: {len(row)} cells, header has {len(header)}")
    out: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        cells = [row[j] for row in body]
        if name in STR_COLUMNS:
            out[name] = np.array(cells, dtype=str)
            continue
        try:
            values = np.array([float(c) for c in cells], dtype=float)
        except ValueError:
            if name in REQUIRED_COLUMNS:
                bad = next(i for i, c in enumerate(cells) if not _is_float(c))
                raise ValueError(
                    f"{path}: line {bad + 2}: column {name!r}: not a number: {cells[bad]!r}"
                ) from None
            out[name] = np.array(cells, dtype=str)
            continue
        out[name] = values.astype(int) if name in INT_COLUMNS else values
    return out


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def write_run(result: RunResult, out_dir: str | Path) -> Path:
    """Write ``log.csv``, ``config.yaml`` and ``run.json`` of a run into ``out_dir`` (created).

    Non-finite numbers are written to JSON as null.

    Returns
    -------
    Path
        The run directory.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_log(result.log, out / "log.csv")
    write_text_atomic(out / "config.yaml", dump_config(result.scenario))
    write_text_atomic(out / "run.json", json.dumps(json_ready(result.summary()), indent=2) + "\n")
    stacked = stack_predictions(result.predictions)
    if stacked is not None:
        with atomic_path(out / PREDICTIONS_FILE) as tmp:
            np.savez_compressed(tmp, t_s=np.asarray(result.log["t_s"], dtype=float), capsule_xy_m=stacked)
    return out


def read_predictions(run_dir: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Frame times (F,) and predicted capsule paths (F, N, 2) from a run folder's ``predictions.npz``.

    Raises
    ------
    FileNotFoundError
        The run has no predictions (its controller does not predict).
    """
    with np.load(Path(run_dir) / PREDICTIONS_FILE) as data:
        return np.asarray(data["t_s"]), np.asarray(data["capsule_xy_m"])
