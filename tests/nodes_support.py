"""Helpers of the nodes' tests: free loopback endpoints, short paths, the command line as a
subprocess (reaped by the ``procs`` fixture), and the comparison of two run logs."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import numpy as np

from capsule_mpc.sim.log import LOG_COLUMNS

DATA = Path(__file__).parent / "data"
QUICK = DATA / "rectangle_quick.yaml"
#: Columns of the controller's report of its step (wall-clock timings, status, phase): on a frame
#: whose command did not come in time the rig reports its own (no phase).
REPORT_COLUMNS = ("solve_ms", "controller_ms", "solver_status", "solver_failed", "phase")
#: The command line as a subprocess.
CLI = [sys.executable, "-c", "import sys; from capsule_mpc.cli import main; sys.exit(main())"]


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def waypoints(tmp_path: Path, points, name="path.csv") -> Path:
    file = tmp_path / name
    file.write_text("x_m,y_m\n" + "".join(f"{x},{y}\n" for x, y in points))
    return file


def same_physics(log: dict, ref: dict) -> list[str]:
    """The columns in which two logs differ: every column but the wall-clock timings, and the
    controller's status and phase on the frames the rig had its command for."""
    differ = [
        c
        for c in LOG_COLUMNS
        if c not in REPORT_COLUMNS and not np.array_equal(log[c], ref[c], equal_nan=log[c].dtype.kind == "f")
    ]
    if len(log["t_s"]) == len(ref["t_s"]):
        answered = ~np.char.startswith(log["solver_status"].astype(str), "late:")
        for c in ("solver_status", "solver_failed", "phase"):
            if not np.array_equal(log[c][answered], ref[c][answered]):
                differ.append(c)
    return differ


def start(args, **kw) -> subprocess.Popen:
    """``capsule-mpc ARGS`` as a subprocess, its output in pipes (text)."""
    return subprocess.Popen([*CLI, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)
