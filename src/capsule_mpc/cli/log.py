"""``capsule-mpc log export``: a run folder converted for Foxglove (:func:`capsule_mpc.telemetry.export_run`).

Reads the folder's ``log.csv``, ``run.json`` and ``config.yaml`` (and ``joint_trajectory.csv``,
``predictions.npz`` when present) and writes the channels of a live run (docs/telemetry.md) to an
MCAP file, atomically.

Exit status: 0 when the file was written; 2 when nothing was written: RUN_DIR is not a folder, one
of its files is missing or unreadable (named), or ``--out`` cannot be written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..overwrite import refuse_overwrite
from .arguments import write_problem

__all__ = ["register", "run_export"]

#: The files of a run folder ``log export`` reads (those present), and its manifest.
RUN_FILES = (
    "log.csv",
    "run.json",
    "config.yaml",
    "joint_trajectory.csv",
    "predictions.npz",
    "events.json",
    "manifest.json",
)
#: The formats ``log export`` writes.
FORMATS = ("mcap",)


def register(sub: Any) -> None:
    """Add the ``log`` command (``log export``)."""
    p = sub.add_parser(
        "log",
        help="convert run logs (log export --format mcap)",
        description="Work with the logs of runs. 'log export' converts a run folder for Foxglove.",
        epilog=(
            "capsule-mpc log export RUN_DIR [--format mcap] [--out FILE]: convert the run folder RUN_DIR "
            "(log.csv, run.json, config.yaml; joint_trajectory.csv and predictions.npz when present) to "
            "the MCAP channels a live run writes (docs/telemetry.md), into FILE (default: RUN_DIR/run.mcap). "
            "Exit status 0 when written; 2 when nothing was written (the message names the file)."
        ),
    )
    actions = p.add_subparsers(
        dest="action", required=True, metavar="ACTION", help="export: convert a run folder to MCAP"
    )
    e = actions.add_parser(
        "export",
        help="convert a run folder to MCAP for Foxglove",
        description=(
            "Convert a run folder (log.csv, run.json, config.yaml; joint_trajectory.csv and "
            "predictions.npz when present) to the MCAP channels a live run writes: the 3D scene of "
            "the plate, the path, the capsule, the EPM and the arm, the measurements, the reference, "
            "the predicted paths, the commands, the tracking error and the run's events "
            "(docs/telemetry.md). Exit status 0 when written; 2 when nothing was written (the "
            "message names the file)."
        ),
    )
    e.add_argument("run_dir", metavar="RUN_DIR", help="the run folder (simulate --out)")
    e.add_argument("--format", choices=FORMATS, default="mcap", help="output format (default: mcap)")
    e.add_argument(
        "--out", default=None, metavar="FILE", help="the file to write (default: RUN_DIR/run.mcap)"
    )
    e.set_defaults(func=run_export)


def run_export(args: argparse.Namespace) -> int:
    """Export ``RUN_DIR`` (a bad folder or file raises ConfigError: exit 2, the file named)."""
    target = Path(args.out) if args.out is not None else Path(args.run_dir) / "run.mcap"
    run_dir = Path(args.run_dir)
    read = [run_dir / name for name in RUN_FILES]
    refuse_overwrite({"--out": (target, False)}, {"RUN_DIR": [run_dir, *read]})
    problem = write_problem(target, folder=False)
    if problem and Path(args.run_dir).is_dir():
        print(f"capsule-mpc log export: --out: {problem}", file=sys.stderr)
        return 2
    # lazy: foxglove and the simulator load when a conversion starts, not for ``--help``
    from ..telemetry.export import export_run

    written = export_run(args.run_dir, target)
    print(f"wrote {written}")
    return 0
